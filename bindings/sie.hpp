/*
 * sie.hpp: header-only C++17 wrapper over the C ABI of libsie (sie.h).
 *
 *   sie::Context ctx;                                   // SIE cost, point-to-plane, no threshold
 *   sie::Transform T = ctx.align({src, n_src, 16}, {tgt, n_tgt, 16});   // row-major T_target_source
 *   sie::Summary s = ctx.summary();                     // iterations, stop reason, sigma, ...
 *   if (s.verdict != sie::Verdict::Good) { ... }        // how far the data support the pose
 *
 * - sie::Context owns a sie_context: move-only, freed in the destructor.
 * - Every failing call throws sie::Error carrying the sie::Status and the library's message.
 * - Inputs are strided views (sie::PointsView: pointer, count, byte stride), never copied here.
 * - Noise and progress callbacks are std::functions; exceptions they throw never reach the
 *   library: a noexcept trampoline catches them, and align() rethrows them once the library has
 *   returned.
 * - A cancelled registration (cancel() or a progress callback returning false) is not an error:
 *   align() returns the transform reached and summary().stop_reason is StopReason::Cancelled.
 *
 * - sie::Target (Context::prepare_target) holds a target's kd-tree and normals for many align()
 *   calls; copies share it, and Contexts on several threads may align onto it at once.
 *
 * Thread safety is the C library's: a Context is used by one thread at a time; distinct
 * Contexts are independent.
 */
#ifndef SIE_HPP
#define SIE_HPP

#include "sie.h"

#include <array>
#include <cstddef>
#include <cstdint>
#include <exception>
#include <functional>
#include <memory>
#include <new>
#include <stdexcept>
#include <string>
#include <type_traits>
#include <utility>
#include <vector>

#if __cplusplus >= 202002L && defined(__has_include)
#if __has_include(<span>)
#include <span>
#define SIE_HPP_HAS_SPAN 1
#endif
#endif

namespace sie {

/** Status of a call (sie_status); Ok is never thrown. */
enum class Status : std::uint32_t {
    Ok = SIE_STATUS_OK,
    NullArgument = SIE_STATUS_NULL_ARGUMENT,
    InvalidArgument = SIE_STATUS_INVALID_ARGUMENT,
    NonFiniteInput = SIE_STATUS_NON_FINITE_INPUT,
    TooFewPoints = SIE_STATUS_TOO_FEW_POINTS,
    CallbackFailed = SIE_STATUS_CALLBACK_FAILED,
    NoResult = SIE_STATUS_NO_RESULT,
    BufferTooSmall = SIE_STATUS_BUFFER_TOO_SMALL,
    Busy = SIE_STATUS_BUSY,
    Cancelled = SIE_STATUS_CANCELLED, // not thrown by align(): the result is kept (StopReason::Cancelled)
    OutOfMemory = SIE_STATUS_OUT_OF_MEMORY,
    Panic = SIE_STATUS_PANIC,
};

enum class CostFunction : std::uint32_t {
    Sie = SIE_COST_FUNCTION_SIE,
    L2 = SIE_COST_FUNCTION_L2,
    TruncatedL2 = SIE_COST_FUNCTION_TRUNCATED_L2,
    Lp = SIE_COST_FUNCTION_LP,
    StudentT = SIE_COST_FUNCTION_STUDENT_T,
    Huber = SIE_COST_FUNCTION_HUBER,
    Cauchy = SIE_COST_FUNCTION_CAUCHY,
    GemanMcClure = SIE_COST_FUNCTION_GEMAN_MCCLURE,
    Tukey = SIE_COST_FUNCTION_TUKEY,
};

enum class Metric : std::uint32_t {
    PointToPoint = SIE_METRIC_POINT_TO_POINT,
    PointToPlane = SIE_METRIC_POINT_TO_PLANE,
};

enum class NoiseModel : std::uint32_t {
    Constant = SIE_NOISE_MODEL_CONSTANT,
    QuadraticDepth = SIE_NOISE_MODEL_QUADRATIC_DEPTH,
};

enum class HistogramMode : std::uint32_t {
    Pooled = SIE_HISTOGRAM_MODE_POOLED,
    PerColumn = SIE_HISTOGRAM_MODE_PER_COLUMN,
};

/** Where SIE starts (sie_starts; Context::set_starts). */
enum class Starts : std::uint32_t {
    /** Several starts, the most significant result is kept (the default). */
    Automatic = SIE_STARTS_AUTOMATIC,
    /** One run from the initial guess (the paper's method). */
    InitialGuess = SIE_STARTS_INITIAL_GUESS,
    /** No guess needed: FPFH descriptor matches propose the starts (costs the descriptors and
     *  up to 5 runs; clouds too small or flat are refused with Status::TooFewPoints). */
    Global = SIE_STARTS_GLOBAL,
};

/** How far to trust a registration (sie_verdict; Summary::verdict). */
enum class Verdict : std::uint32_t {
    /** No result. */
    None = SIE_VERDICT_NONE,
    /** The evidence supports the pose: use it. */
    Good = SIE_VERDICT_GOOD,
    /** Registered, but some evidence is weak: check it, or retry from another guess. */
    Doubtful = SIE_VERDICT_DOUBTFUL,
    /** No inlier cluster stands out from the background: reject the pose. */
    Unsupported = SIE_VERDICT_UNSUPPORTED,
};

/** Which start the returned transform came from (sie_start_kind; Summary::start). */
enum class StartKind : std::uint32_t {
    InitialGuess = SIE_START_KIND_INITIAL_GUESS,
    NarrowBeta = SIE_START_KIND_NARROW_BETA,
    ScaleFreeLead = SIE_START_KIND_SCALE_FREE_LEAD,
    Hypothesis = SIE_START_KIND_HYPOTHESIS,
    WarmStart = SIE_START_KIND_WARM_START,
    HalfTurn = SIE_START_KIND_HALF_TURN,
    PeriodShift = SIE_START_KIND_PERIOD_SHIFT,
    FeatureMatch = SIE_START_KIND_FEATURE_MATCH,
    QuarterTurn = SIE_START_KIND_QUARTER_TURN,
};

/** What became of a frame given to Context::register_frame. A frame refused as input throws
 * instead (Error with its status); the odometry is then unchanged. */
enum class FrameStatus : std::uint32_t {
    First = SIE_FRAME_STATUS_FIRST,
    Accepted = SIE_FRAME_STATUS_ACCEPTED,
    Repeated = SIE_FRAME_STATUS_REPEATED,
    NotGood = SIE_FRAME_STATUS_NOT_GOOD,
    Jumped = SIE_FRAME_STATUS_JUMPED,
    Loose = SIE_FRAME_STATUS_LOOSE,
};

enum class StopReason : std::uint32_t {
    None = SIE_STOP_REASON_NONE,
    Converged = SIE_STOP_REASON_CONVERGED,
    IterationLimit = SIE_STOP_REASON_ITERATION_LIMIT,
    Degenerate = SIE_STOP_REASON_DEGENERATE,
    Cancelled = SIE_STOP_REASON_CANCELLED,
};

enum class Cloud : std::uint32_t {
    Source = SIE_CLOUD_SOURCE,
    Target = SIE_CLOUD_TARGET,
};

/** The library's static description of a status ("unknown status" for other values). */
inline const char *to_string(Status status) noexcept {
    return sie_status_str(static_cast<std::uint32_t>(status));
}

inline const char *to_string(StopReason reason) noexcept {
    switch (reason) {
    case StopReason::None:
        return "none";
    case StopReason::Converged:
        return "converged";
    case StopReason::IterationLimit:
        return "iteration limit";
    case StopReason::Degenerate:
        return "degenerate";
    case StopReason::Cancelled:
        return "cancelled";
    }
    return "unknown";
}

inline const char *to_string(Verdict verdict) noexcept {
    switch (verdict) {
    case Verdict::None:
        return "none";
    case Verdict::Good:
        return "good";
    case Verdict::Doubtful:
        return "doubtful";
    case Verdict::Unsupported:
        return "unsupported";
    }
    return "unknown";
}

inline const char *to_string(StartKind start) noexcept {
    switch (start) {
    case StartKind::InitialGuess:
        return "initial guess";
    case StartKind::NarrowBeta:
        return "narrow beta";
    case StartKind::ScaleFreeLead:
        return "scale-free lead";
    case StartKind::Hypothesis:
        return "hypothesis";
    case StartKind::WarmStart:
        return "warm start";
    case StartKind::HalfTurn:
        return "half turn";
    case StartKind::PeriodShift:
        return "period shift";
    case StartKind::FeatureMatch:
        return "feature match";
    case StartKind::QuarterTurn:
        return "quarter turn";
    }
    return "unknown";
}

/** A failed call: the status and the library's detail message (sie_context_last_error). */
class Error : public std::runtime_error {
  public:
    Error(Status status, const std::string &detail)
        : std::runtime_error(std::string("sie: ") + to_string(status) + (detail.empty() ? "" : ": ") + detail),
          status_(status), detail_(detail) {}

    Status status() const noexcept { return status_; }
    /** The message of sie_context_last_error at the time of the failure. */
    const std::string &detail() const noexcept { return detail_; }

  private:
    Status status_;
    std::string detail_;
};

/** The loaded libsie has another major.minor version than this header (a stale library). */
class VersionMismatch : public std::runtime_error {
  public:
    using std::runtime_error::runtime_error;
};

/** A rigid transform, 16 doubles in ROW-major order (T[4*row + col]), as in the C API. */
using Transform = std::array<double, 16>;

inline constexpr Transform identity_transform() noexcept {
    return {1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0};
}

/**
 * A read-only view of `count` points of three Scalars each; point i starts `i * stride_bytes`
 * bytes after `xyz` (0 = packed). Nothing is copied: the memory must outlive the call using it.
 */
template <typename Scalar> struct PointsView {
    static_assert(std::is_same<Scalar, float>::value || std::is_same<Scalar, double>::value,
                  "sie takes float or double coordinates");

    const Scalar *xyz = nullptr;
    std::size_t count = 0;
    std::size_t stride_bytes = 0;

    constexpr PointsView() noexcept = default;
    constexpr PointsView(const Scalar *xyz_, std::size_t count_, std::size_t stride_bytes_ = 0) noexcept
        : xyz(xyz_), count(count_), stride_bytes(stride_bytes_) {}
    /** Packed triples, e.g. std::vector<std::array<float, 3>>. */
    PointsView(const std::vector<std::array<Scalar, 3>> &points) noexcept // NOLINT: implicit on purpose
        : xyz(points.empty() ? nullptr : points.front().data()), count(points.size()), stride_bytes(sizeof(points[0])) {
    }
#ifdef SIE_HPP_HAS_SPAN
    PointsView(std::span<const std::array<Scalar, 3>> points) noexcept // NOLINT: implicit on purpose
        : xyz(points.empty() ? nullptr : points.front().data()), count(points.size()), stride_bytes(sizeof(points[0])) {
    }
#endif
};

using Points = PointsView<float>;
using PointsD = PointsView<double>;

/** Summary of the last registration (sie_summary with a typed stop reason, verdict and start;
 * the field documentation is in sie.h). */
struct Summary {
    std::array<double, 3> sigma{};
    std::array<double, 3> beta{};
    double penalty = 0.0;
    double noise_shape = 0.0;
    double inlier_fraction = 0.0;
    double rmse = 0.0;
    /** How much the initial guess was corrected to be exactly rigid (sie_summary). */
    double init_correction = 0.0;
    std::uint64_t source_count = 0;
    std::uint64_t correspondence_count = 0;
    std::uint32_t iterations = 0;
    StopReason stop_reason = StopReason::None;
    std::uint32_t histogram_count = 0;
    bool converged = false;
    /** How far to trust the pose; the next four fields are its evidence. */
    Verdict verdict = Verdict::None;
    /** Significance of the inlier cluster (nats; 0: nothing beyond chance). */
    double significance = 0.0;
    /** How well the inliers constrain the pose, 0..1. */
    double conditioning = 0.0;
    /** Fitted sigma over the target points' spacing (clouds; 0 for correspondences). */
    double sigma_to_spacing = 0.0;
    /** significance / runner_up_significance; 0 when no start ended elsewhere. */
    double margin = 0.0;
    /** Which start the transform came from. */
    StartKind start = StartKind::InitialGuess;
    std::uint32_t starts_run = 0;
    std::uint32_t agreeing_starts = 0;
    /** Minimal samples of the hypothesis search (correspondences, or Starts::Global on descriptor
     *  matches; 0 when none ran). */
    std::uint32_t hypotheses = 0;
    /** The largest significance among starts that ended at another pose (0: none did). */
    double runner_up_significance = 0.0;
};

/**
 * The uncertainty of the last registration's pose (sie_context_get_pose_uncertainty): 6x6
 * matrices in ROW-major order (M[6*row + col]), for the left perturbation
 * T = Exp(d) * T_hat of the returned T_target_source with d = (w, v): the rotation vector w
 * (radians, rows/columns 0..2) first, then the translation v (3..5), both in the target frame
 * and in the input's units. Directions the inliers leave free have a far larger variance and a
 * far smaller information (sie.h). All zeros when the result had too few weighted residuals.
 */
struct PoseUncertainty {
    /** Cov(d): rad^2, rad*length, length^2. */
    std::array<double, 36> covariance{};
    /** Its inverse where the data constrain the pose (near 0 in free directions). */
    std::array<double, 36> information{};
};

/** One fitted SIE histogram and its per-bin arrays (sie_context_get_histogram). */
struct Histogram {
    sie_model model{};
    std::vector<double> counts;
    std::vector<double> smoothed;
    std::vector<double> model_values;
    std::vector<double> probability;
};

using TraceEntry = sie_trace_entry;

/** Result of Context::estimate_inliers: P(inlier) per row and one model per histogram. */
struct InlierEstimate {
    std::vector<double> probabilities;
    std::vector<sie_model> models;
};

/**
 * Per-point noise: fill sigma[i] (finite, > 0; pre-filled with 1) for the n points in xyz
 * (3*n doubles, in that cloud's own frame). Called once per cloud per registration, on the
 * thread calling align(). Throw to abort the registration: align() rethrows the exception.
 */
using NoiseFunction = std::function<void(Cloud cloud, const double *xyz, std::size_t n, double *sigma)>;

/**
 * Per-iteration progress: receives the iteration's trace entry (valid during the call; its
 * `transform` is the row-major T_target_source the update reached) on the thread calling
 * align(). Return false to cancel the registration (it then stops with the
 * transform reached); throw to cancel it and have align() rethrow the exception.
 */
using ProgressFunction = std::function<bool(const TraceEntry &entry)>;

/**
 * A prepared target cloud (sie_target): kd-tree and normals built once, for many registrations
 * (odometry onto the previous frame, scan-to-map). Made by Context::prepare_target, used by
 * Context::align(source, target). Copies share one immutable target (shared ownership; it is
 * freed with the last copy), and any number of Contexts on any threads may align onto it at the
 * same time. A default-constructed Target is empty (aligning onto it throws NullArgument).
 */
class Target {
  public:
    Target() noexcept = default;

    explicit operator bool() const noexcept { return static_cast<bool>(target_); }
    /** Points the target was made from (0 when empty). */
    std::size_t size() const noexcept { return sie_target_point_count(target_.get()); }
    /** Estimates all normals not estimated yet, on `threads` threads (0 = one per core), so
     * that no later align() pays for them (e.g. a map prepared in the background). */
    void estimate_normals(std::uint32_t threads = 0) const {
        const sie_status status = sie_target_estimate_normals(target_.get(), threads);
        if (status != SIE_STATUS_OK) {
            throw Error(static_cast<Status>(status), target_ ? "threads must be <= 1024" : "the target is empty");
        }
    }
    const sie_target *get() const noexcept { return target_.get(); }

  private:
    friend class Context;
    explicit Target(sie_target *target) : target_(target, [](const sie_target *t) {
        sie_target_free(const_cast<sie_target *>(t));
    }) {}

    std::shared_ptr<const sie_target> target_;
};

/** Frame-to-frame odometry (Context::odometry): each frame registers onto the last accepted
 * frame from a constant-velocity guess, and only a GOOD registration moves the trajectory. Frames
 * go through Context::register_frame; one call at a time per odometry. Move-only. */
class Odometry {
  public:
    Odometry() noexcept = default;

    explicit operator bool() const noexcept { return static_cast<bool>(odometry_); }
    /** T_world_sensor of the last accepted frame (the identity before the first). */
    Transform pose() const {
        Transform out = identity_transform();
        if (odometry_) {
            (void)sie_odometry_pose(odometry_.get(), out.data());
        }
        return out;
    }
    /** A frame the driver dropped: the next frame's guess moves one frame further. */
    void skip_frame() noexcept { sie_odometry_skip_frame(odometry_.get()); }
    sie_odometry *get() noexcept { return odometry_.get(); }

  private:
    friend class Context;
    explicit Odometry(sie_odometry *odometry) : odometry_(odometry) {}

    struct Free {
        void operator()(sie_odometry *odometry) const noexcept { sie_odometry_free(odometry); }
    };
    std::unique_ptr<sie_odometry, Free> odometry_;
};

/** One frame's outcome: its status, and T_world_sensor (the frame's pose for First, Accepted
 * and Loose, the last accepted pose otherwise). */
struct Frame {
    FrameStatus status;
    Transform T_world_sensor;
};

class Context {
  public:
    /** A context with the default configuration. Throws VersionMismatch for a stale library. */
    Context() {
        // Within 0.x every minor version may change the ABI, so major.minor must match.
        if ((sie_version_number() >> 8) != (SIE_VERSION_NUMBER >> 8)) {
            throw VersionMismatch(std::string("sie.hpp is version ") + SIE_VERSION_STRING +
                                  " but the loaded libsie is " + sie_version_string());
        }
        context_.reset(sie_context_new());
        if (!context_) {
            throw std::bad_alloc();
        }
    }

    Context(Context &&) noexcept = default;
    Context &operator=(Context &&) noexcept = default;
    Context(const Context &) = delete;
    Context &operator=(const Context &) = delete;
    ~Context() = default;

    /** The C handle, for functions this wrapper does not cover (still owned here). */
    sie_context *c_api() noexcept { return context_.get(); }
    const sie_context *c_api() const noexcept { return context_.get(); }

    /** Gives up ownership; the caller frees it with sie_context_free. C++ callbacks are removed
     * first, since their holders stay with this object. */
    sie_context *release() noexcept {
        if (context_ && noise_) {
            (void)sie_context_set_noise_callback(context_.get(), nullptr, nullptr);
        }
        if (context_ && progress_) {
            (void)sie_context_set_progress_callback(context_.get(), nullptr, nullptr);
        }
        noise_.reset();
        progress_.reset();
        return context_.release();
    }

    /** Asks the running registration to stop after its current iteration (or, if none runs,
     * the next one after its first). The one member that may be called from another thread
     * while align() runs; also safe in a signal handler. */
    void cancel() const noexcept { (void)sie_context_cancel(context_.get()); }

    // ---- configuration (each returns *this, so calls chain) --------------------------------

    Context &set_cost_function(CostFunction cost, double parameter = 0.0) {
        check(sie_context_set_cost_function(get(), static_cast<std::uint32_t>(cost), parameter));
        return *this;
    }
    Context &set_metric(Metric metric) {
        check(sie_context_set_metric(get(), static_cast<std::uint32_t>(metric)));
        return *this;
    }
    /** Where SIE starts; Starts::Automatic (the default) runs several and keeps the most
     * significant result; Starts::Global needs no guess (descriptor matches propose the starts). */
    Context &set_starts(Starts starts) {
        check(sie_context_set_starts(get(), static_cast<std::uint32_t>(starts)));
        return *this;
    }

    /** Starts the following registrations from the noise model of `previous` (an earlier SIE
     * registration's summary): for sequences registered from good guesses; falls back to the
     * full search by itself when the guess was bad; a summary whose verdict is DOUBTFUL or
     * UNSUPPORTED clears it (sie_context_set_warm_start). */
    Context &set_warm_start(const Summary &previous) {
        sie_summary raw{};
        for (std::size_t i = 0; i < 3; ++i) {
            raw.sigma[i] = previous.sigma[i];
            raw.beta[i] = previous.beta[i];
        }
        raw.penalty = previous.penalty;
        raw.noise_shape = previous.noise_shape;
        raw.inlier_fraction = previous.inlier_fraction;
        raw.histogram_count = previous.histogram_count;
        raw.verdict = static_cast<std::uint32_t>(previous.verdict);
        check(sie_context_set_warm_start(get(), &raw));
        return *this;
    }

    /** Registrations start cold again (the default). */
    Context &clear_warm_start() {
        check(sie_context_set_warm_start(get(), nullptr));
        return *this;
    }
    /** Caps the updates of each start (Summary::iterations counts those of all starts). */
    Context &set_max_iterations(std::uint32_t max_iterations) {
        check(sie_context_set_max_iterations(get(), max_iterations));
        return *this;
    }
    Context &set_convergence(double translation, double rotation_radians) {
        check(sie_context_set_convergence(get(), translation, rotation_radians));
        return *this;
    }
    Context &set_noise_model(NoiseModel model) {
        check(sie_context_set_noise_model(get(), static_cast<std::uint32_t>(model)));
        return *this;
    }
    Context &set_noise_shape(double p) {
        check(sie_context_set_noise_shape(get(), p));
        return *this;
    }
    Context &set_histogram_mode(HistogramMode mode) {
        check(sie_context_set_histogram_mode(get(), static_cast<std::uint32_t>(mode)));
        return *this;
    }
    Context &set_regularizer(double initial_beta, double shrink) {
        check(sie_context_set_regularizer(get(), initial_beta, shrink));
        return *this;
    }
    Context &set_max_correspondences(std::size_t max_correspondences) {
        check(sie_context_set_max_correspondences(get(), max_correspondences));
        return *this;
    }
    Context &set_normal_neighbours(std::uint32_t neighbours) {
        check(sie_context_set_normal_neighbours(get(), neighbours));
        normal_neighbours_ = neighbours;
        return *this;
    }
    /** The normal_neighbours setting (a Target prepared with another count refuses this context). */
    std::uint32_t normal_neighbours() const noexcept { return normal_neighbours_; }
    Context &set_threads(std::uint32_t threads) {
        check(sie_context_set_threads(get(), threads));
        return *this;
    }
    Context &set_seed(std::uint64_t seed) {
        check(sie_context_set_seed(get(), seed));
        return *this;
    }
    Context &set_trace(bool enabled) {
        check(sie_context_set_trace(get(), enabled));
        return *this;
    }
    /** Drop points with a NaN/infinite coordinate instead of failing (e.g. non-dense PCL clouds);
     * they get inlier probability 0 and correspondence -1. */
    Context &set_skip_non_finite(bool enabled) {
        check(sie_context_set_skip_non_finite(get(), enabled));
        return *this;
    }
    /** Drop points at exactly 0 0 0 (how depth sensors mark invalid pixels) the same way. */
    Context &set_skip_origin(bool enabled) {
        check(sie_context_set_skip_origin(get(), enabled));
        return *this;
    }

    /** Installs a per-point noise callback (an empty function removes it). The context keeps
     * the function alive for as long as it is installed, also across moves. */
    Context &set_noise_callback(NoiseFunction function) {
        if (!function) {
            return clear_noise_callback();
        }
        auto holder = std::make_unique<Holder<NoiseFunction>>();
        holder->function = std::move(function);
        check(sie_context_set_noise_callback(get(), &noise_trampoline, holder.get()));
        // The library now points at the new holder; the old one (if any) can go.
        noise_ = std::move(holder);
        return *this;
    }

    /** Removes the noise callback; the built-in noise model applies again. */
    Context &clear_noise_callback() {
        check(sie_context_set_noise_callback(get(), nullptr, nullptr));
        noise_.reset();
        return *this;
    }

    /** Installs a per-iteration progress callback (an empty function removes it); kept alive
     * by the context like the noise callback. */
    Context &set_progress_callback(ProgressFunction function) {
        if (!function) {
            return clear_progress_callback();
        }
        auto holder = std::make_unique<Holder<ProgressFunction>>();
        holder->function = std::move(function);
        check(sie_context_set_progress_callback(get(), &progress_trampoline, holder.get()));
        progress_ = std::move(holder);
        return *this;
    }

    Context &clear_progress_callback() {
        check(sie_context_set_progress_callback(get(), nullptr, nullptr));
        progress_.reset();
        return *this;
    }

    // ---- registration: each returns T_target_source (p_target = T * p_source) ------------

    /** ICP of source onto target (float clouds). */
    Transform align(Points source, Points target, const Transform &init = identity_transform()) {
        Transform out{};
        run(sie_context_register(get(), source.xyz, source.count, source.stride_bytes, target.xyz, target.count,
                                 target.stride_bytes, init.data(), out.data()));
        return out;
    }

    /** ICP of source onto target (double clouds). */
    Transform align(PointsD source, PointsD target, const Transform &init = identity_transform()) {
        Transform out{};
        run(sie_context_register_d(get(), source.xyz, source.count, source.stride_bytes, target.xyz, target.count,
                                   target.stride_bytes, init.data(), out.data()));
        return out;
    }

    /** Prepares `target` for many align(source, target) calls, with this context's
     * normal_neighbours and skip_non_finite settings. The points are copied. */
    Target prepare_target(Points target) const { return prepare(target, Points{}); }
    Target prepare_target(PointsD target) const { return prepare(target, PointsD{}); }
    /** With one unit normal per target point (0 0 0 = none), used by point-to-plane. */
    Target prepare_target(Points target, Points normals) const {
        check_normal_count(target, normals);
        return prepare(target, normals);
    }
    Target prepare_target(PointsD target, PointsD normals) const {
        check_normal_count(target, normals);
        return prepare(target, normals);
    }

    /** ICP of source onto a prepared target: the same result as align(source, target points),
     * without rebuilding the target's kd-tree and normals. */
    Transform align(Points source, const Target &target, const Transform &init = identity_transform()) {
        Transform out{};
        run(sie_context_register_to(get(), source.xyz, source.count, source.stride_bytes, target.get(), init.data(),
                                    out.data()));
        return out;
    }

    Transform align(PointsD source, const Target &target, const Transform &init = identity_transform()) {
        Transform out{};
        run(sie_context_register_to_d(get(), source.xyz, source.count, source.stride_bytes, target.get(),
                                      init.data(), out.data()));
        return out;
    }

    /** An odometry registering with a copy of this context's settings (set skip_non_finite and
     * skip_origin first for sensor frames that mark missing returns with NaN or 0 0 0). */
    Odometry odometry() const {
        sie_odometry *out = nullptr;
        check(sie_context_odometry_new(get(), &out));
        return Odometry(out);
    }

    /** Registers the next frame (points in its sensor's frame); the frame's registration is
     * then this context's result (summary() etc.) for Accepted, Loose, NotGood and Jumped. A frame
     * refused as input throws Error and changes nothing; a cancelled one counts as NotGood. */
    Frame register_frame(Odometry &odometry, Points frame) {
        return frame_outcome(odometry, [&](double *pose, std::uint32_t *status) {
            return sie_context_odometry_register_frame(get(), odometry.get(), frame.xyz, frame.count,
                                                       frame.stride_bytes, pose, status);
        });
    }

    Frame register_frame(Odometry &odometry, PointsD frame) {
        return frame_outcome(odometry, [&](double *pose, std::uint32_t *status) {
            return sie_context_odometry_register_frame_d(get(), odometry.get(), frame.xyz, frame.count,
                                                         frame.stride_bytes, pose, status);
        });
    }

    /** ICP with one unit normal per target point (0 0 0 = none) for point-to-plane. */
    Transform align_with_normals(Points source, Points target, Points target_normals,
                                 const Transform &init = identity_transform()) {
        if (target_normals.count != target.count) {
            throw Error(Status::InvalidArgument, "target_normals has " + std::to_string(target_normals.count) +
                                                     " entries for " + std::to_string(target.count) +
                                                     " target points");
        }
        Transform out{};
        run(sie_context_register_with_normals(get(), source.xyz, source.count, source.stride_bytes, target.xyz,
                                              target.count, target.stride_bytes, target_normals.xyz,
                                              target_normals.stride_bytes, init.data(), out.data()));
        return out;
    }

    /** Matched pairs: source[i] corresponds to target[i] (point-to-point). */
    Transform align_correspondences(Points source, Points target, const Transform &init = identity_transform()) {
        check_same_count(source.count, target.count);
        Transform out{};
        run(sie_context_register_correspondences(get(), source.xyz, source.stride_bytes, target.xyz,
                                                 target.stride_bytes, source.count, init.data(), out.data()));
        return out;
    }

    Transform align_correspondences(PointsD source, PointsD target, const Transform &init = identity_transform()) {
        check_same_count(source.count, target.count);
        Transform out{};
        run(sie_context_register_correspondences_d(get(), source.xyz, source.stride_bytes, target.xyz,
                                                   target.stride_bytes, source.count, init.data(), out.data()));
        return out;
    }

    // ---- results of the last successful registration (Status::NoResult otherwise) ----------

    Summary summary() const {
        sie_summary raw{};
        check(sie_context_get_summary(get(), &raw));
        Summary s;
        for (std::size_t i = 0; i < 3; ++i) {
            s.sigma[i] = raw.sigma[i];
            s.beta[i] = raw.beta[i];
        }
        s.penalty = raw.penalty;
        s.noise_shape = raw.noise_shape;
        s.inlier_fraction = raw.inlier_fraction;
        s.rmse = raw.rmse;
        s.init_correction = raw.init_correction;
        s.source_count = raw.source_count;
        s.correspondence_count = raw.correspondence_count;
        s.iterations = raw.iterations;
        s.stop_reason = static_cast<StopReason>(raw.stop_reason);
        s.histogram_count = raw.histogram_count;
        s.converged = raw.converged;
        s.verdict = static_cast<Verdict>(raw.verdict);
        s.significance = raw.significance;
        s.conditioning = raw.conditioning;
        s.sigma_to_spacing = raw.sigma_to_spacing;
        s.margin = raw.margin;
        s.start = static_cast<StartKind>(raw.start);
        s.starts_run = raw.starts_run;
        s.agreeing_starts = raw.agreeing_starts;
        s.hypotheses = raw.hypotheses;
        s.runner_up_significance = raw.runner_up_significance;
        return s;
    }

    /** Covariance and information of the pose (see PoseUncertainty for the convention). */
    PoseUncertainty pose_uncertainty() const {
        PoseUncertainty u;
        check(sie_context_get_pose_uncertainty(get(), u.covariance.data(), u.information.data()));
        return u;
    }

    /** P(inlier) per source point (0 for unmatched points). */
    std::vector<double> inlier_probabilities() const {
        return read_array<double>(&sie_context_get_inlier_probabilities);
    }

    /** Matched target index per source point (-1 if unmatched). */
    std::vector<std::int64_t> correspondences() const {
        return read_array<std::int64_t>(&sie_context_get_correspondences);
    }

    /** Per-iteration trace (empty unless set_trace(true) was called before the registration). */
    std::vector<TraceEntry> trace() const { return read_array<TraceEntry>(&sie_context_get_trace); }

    /** SIE histogram `index` (< summary().histogram_count) with its per-bin arrays. */
    Histogram histogram(std::size_t index) const {
        Histogram h;
        check(sie_context_get_histogram(get(), index, &h.model, nullptr, nullptr, nullptr, nullptr, 0));
        const auto bins = static_cast<std::size_t>(h.model.bins);
        h.counts.resize(bins);
        h.smoothed.resize(bins);
        h.model_values.resize(bins);
        h.probability.resize(bins);
        check(sie_context_get_histogram(get(), index, &h.model, h.counts.data(), h.smoothed.data(),
                                        h.model_values.data(), h.probability.data(), bins));
        return h;
    }

    // ---- the estimator alone ---------------------------------------------------------------

    /** P(inlier) per row of a rows x cols row-major residual matrix; row_scales (nullable, rows
     * values) divides each row first. */
    InlierEstimate estimate_inliers(const double *residuals, std::size_t rows, std::size_t cols,
                                    const double *row_scales = nullptr, double beta = 0.0) {
        InlierEstimate estimate;
        estimate.probabilities.resize(rows);
        // Pooled mode fits one histogram, per-column mode one per column.
        estimate.models.resize(cols == 0 ? 1 : cols);
        std::size_t model_count = 0;
        check(sie_estimate_inliers(get(), residuals, rows, cols, row_scales, beta, estimate.probabilities.data(),
                                   estimate.models.data(), estimate.models.size(), &model_count));
        estimate.models.resize(model_count);
        return estimate;
    }

  private:
    struct Free {
        void operator()(sie_context *context) const noexcept { sie_context_free(context); }
    };

    template <typename Function> struct Holder {
        Function function;
        std::exception_ptr pending; // what the function threw during the current registration
    };

    // The trampolines run on the library's side of the boundary: nothing may propagate out.
    static std::int32_t noise_trampoline(void *user_data, std::uint32_t cloud, const double *xyz, std::size_t n,
                                         double *out_sigma) noexcept {
        auto *holder = static_cast<Holder<NoiseFunction> *>(user_data);
        try {
            holder->function(static_cast<Cloud>(cloud), xyz, n, out_sigma);
            return 0;
        } catch (...) {
            holder->pending = std::current_exception();
            return 1;
        }
    }

    static std::int32_t progress_trampoline(void *user_data, const sie_trace_entry *entry) noexcept {
        auto *holder = static_cast<Holder<ProgressFunction> *>(user_data);
        try {
            return holder->function(*entry) ? 0 : 1;
        } catch (...) {
            holder->pending = std::current_exception();
            return 1;
        }
    }

    template <typename Function> static std::exception_ptr take_pending(const std::unique_ptr<Holder<Function>> &h) {
        return h ? std::exchange(h->pending, nullptr) : nullptr;
    }

    sie_context *get() const noexcept { return context_.get(); }

    void check(sie_status status) const {
        if (status != SIE_STATUS_OK) {
            // The message lives until the next call on the context: copy it now.
            throw Error(static_cast<Status>(status), sie_context_last_error(get()));
        }
    }

    /** For registrations: rethrows what a callback threw during this call; a cancellation is
     * a result, not an error; anything else goes through check. */
    void run(sie_status status) {
        const std::exception_ptr noise_thrown = take_pending(noise_);
        const std::exception_ptr progress_thrown = take_pending(progress_);
        if (status == SIE_STATUS_CALLBACK_FAILED && noise_thrown) {
            std::rethrow_exception(noise_thrown);
        }
        if (status == SIE_STATUS_CANCELLED) {
            if (progress_thrown) {
                std::rethrow_exception(progress_thrown);
            }
            return;
        }
        check(status);
    }

    template <typename Scalar> static void check_normal_count(PointsView<Scalar> target, PointsView<Scalar> normals) {
        if (normals.count != target.count) {
            throw Error(Status::InvalidArgument, "normals has " + std::to_string(normals.count) + " entries for " +
                                                     std::to_string(target.count) + " target points");
        }
    }

    Target prepare(Points target, Points normals) const {
        sie_target *out = nullptr;
        check(sie_context_prepare_target(get(), target.xyz, target.count, target.stride_bytes, normals.xyz,
                                         normals.stride_bytes, &out));
        return Target(out);
    }

    Target prepare(PointsD target, PointsD normals) const {
        sie_target *out = nullptr;
        check(sie_context_prepare_target_d(get(), target.xyz, target.count, target.stride_bytes, normals.xyz,
                                           normals.stride_bytes, &out));
        return Target(out);
    }

    template <typename Register> Frame frame_outcome(Odometry &odometry, Register register_call) {
        Transform pose = odometry.pose();
        std::uint32_t status = SIE_FRAME_STATUS_NOT_GOOD;
        run(register_call(pose.data(), &status));
        return Frame{static_cast<FrameStatus>(status), pose};
    }

    static void check_same_count(std::size_t source_count, std::size_t target_count) {
        if (source_count != target_count) {
            throw Error(Status::InvalidArgument, "correspondences need as many source points (" +
                                                     std::to_string(source_count) + ") as target points (" +
                                                     std::to_string(target_count) + ")");
        }
    }

    template <typename T, typename Getter> std::vector<T> read_array(Getter getter) const {
        std::size_t length = 0;
        check(getter(get(), nullptr, 0, &length));
        std::vector<T> values(length);
        check(getter(get(), values.data(), values.size(), &length));
        values.resize(length);
        return values;
    }

    // Declared before context_ so that they are destroyed after it: the library points at them.
    std::unique_ptr<Holder<NoiseFunction>> noise_;
    std::unique_ptr<Holder<ProgressFunction>> progress_;
    std::unique_ptr<sie_context, Free> context_;
    std::uint32_t normal_neighbours_ = 10; // the library's default
};

} // namespace sie

#endif /* SIE_HPP */
