// Tests of the C++ wrapper bindings/sie.hpp against the real library: ownership and moves,
// errors carrying status and message, every registration entry point on synthetic data with a
// known transform, result getters, and the noise-callback shim (exceptions never cross into
// the library and come back out of align() unchanged). Run by ctest, also under valgrind.

// Included twice on purpose: the include guards must hold.
#include "sie.hpp"
#include "sie.hpp"

#include "scene.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdint>
#include <cstring>
#include <limits>
#include <stdexcept>
#include <string>
#include <thread>
#include <tuple>
#include <type_traits>
#include <utility>
#include <vector>

static_assert(!std::is_copy_constructible<sie::Context>::value, "a context owns its handle");
static_assert(std::is_nothrow_move_constructible<sie::Context>::value, "moves must not throw");
static_assert(std::is_nothrow_move_assignable<sie::Context>::value, "moves must not throw");
static_assert(sizeof(sie::Status) == sizeof(sie_status), "same representation as the C enum");
static_assert(static_cast<std::uint32_t>(sie::Verdict::Unsupported) == SIE_VERDICT_UNSUPPORTED, "the C values");
static_assert(static_cast<std::uint32_t>(sie::StartKind::Hypothesis) == SIE_START_KIND_HYPOTHESIS, "the C values");
static_assert(static_cast<std::uint32_t>(sie::StartKind::WarmStart) == SIE_START_KIND_WARM_START, "the C values");
static_assert(static_cast<std::uint32_t>(sie::Starts::InitialGuess) == SIE_STARTS_INITIAL_GUESS, "the C values");
static_assert(static_cast<std::uint32_t>(sie::FrameStatus::Jumped) == SIE_FRAME_STATUS_JUMPED, "the C values");
static_assert(static_cast<std::uint32_t>(sie::FrameStatus::Loose) == SIE_FRAME_STATUS_LOOSE, "the C values");
static_assert(!std::is_copy_constructible<sie::Odometry>::value, "an odometry owns its handle");

namespace {

int checks = 0;
int failures = 0;

void check(bool ok, const char *what, int line) {
    ++checks;
    if (!ok) {
        ++failures;
        std::fprintf(stderr, "wrapper_test.cpp:%d: check failed: %s\n", line, what);
    }
}

#define CHECK(cond) check((cond), #cond, __LINE__)

// Runs `body`, expecting sie::Error with `status`; returns its detail message.
template <typename Body> std::string expect_error(sie::Status status, Body &&body, int line) {
    try {
        body();
    } catch (const sie::Error &error) {
        check(error.status() == status, "error has the expected status", line);
        check(std::string(error.what()).find(error.detail()) != std::string::npos, "what() contains the detail",
              line);
        return error.detail();
    } catch (const std::exception &other) {
        check(false, other.what(), line);
        return {};
    }
    check(false, "no exception thrown", line);
    return {};
}

#define EXPECT_ERROR(status, ...) expect_error((status), [&] { __VA_ARGS__; }, __LINE__)

bool contains(const std::string &text, const char *needle) { return text.find(needle) != std::string::npos; }

struct Clouds {
    std::vector<std::array<float, 3>> source;
    std::vector<std::array<float, 3>> target;
    std::vector<std::array<float, 3>> target_normals;
    scene::Matrix truth; // T_target_source
};

// Two independent scans of the room corner; the source is seen from a moved sensor.
Clouds room_clouds(std::size_t count) {
    Clouds clouds;
    clouds.truth = scene::rigid(0.09, {0.3, -0.2, 1.0}, {0.08, -0.05, 0.04});
    const scene::Matrix source_from_target = scene::inverse(clouds.truth);
    for (const auto &s : scene::room_corner(count, 0.002, 11)) {
        const scene::Point p = scene::apply(source_from_target, s.position);
        clouds.source.push_back({float(p[0]), float(p[1]), float(p[2])});
    }
    for (const auto &s : scene::room_corner(count, 0.002, 12)) {
        clouds.target.push_back({float(s.position[0]), float(s.position[1]), float(s.position[2])});
        clouds.target_normals.push_back({float(s.normal[0]), float(s.normal[1]), float(s.normal[2])});
    }
    return clouds;
}

bool close_to(const sie::Transform &estimate, const scene::Matrix &truth, double degrees, double distance) {
    const scene::PoseError error = scene::pose_error(estimate, truth);
    return error.rotation_degrees < degrees && error.translation < distance;
}

// The pose's covariance and information on a well-constrained scene: row-major 6x6,
// symmetric, positive variances, and inverse to each other.
void check_pose_uncertainty(const sie::PoseUncertainty &u, int line) {
    static_assert(std::tuple_size<decltype(u.covariance)>::value == 36, "6 x 6");
    static_assert(std::tuple_size<decltype(u.information)>::value == 36, "6 x 6");
    double scale = 0.0, asymmetry = 0.0, off_identity = 0.0;
    bool positive = true;
    for (std::size_t r = 0; r < 6; ++r) {
        positive = positive && u.covariance[6 * r + r] > 0.0 && u.information[6 * r + r] > 0.0;
        for (std::size_t c = 0; c < 6; ++c) {
            scale = std::max(scale, std::abs(u.covariance[6 * r + c]));
            asymmetry = std::max(asymmetry, std::abs(u.covariance[6 * r + c] - u.covariance[6 * c + r]));
            double product = 0.0;
            for (std::size_t k = 0; k < 6; ++k) {
                product += u.covariance[6 * r + k] * u.information[6 * k + c];
            }
            off_identity = std::max(off_identity, std::abs(product - (r == c ? 1.0 : 0.0)));
        }
    }
    check(positive, "positive variances and information diagonal", line);
    // Thousands of points with mm-to-cm noise fix the pose to well under 1e-2 (rad or m): the
    // covariance is the small one of the two.
    check(u.covariance[0] < 1e-4 && u.covariance[35] < 1e-4 && u.information[0] > 1e4, "covariance, not information",
          line);
    check(std::isfinite(scale) && asymmetry <= 1e-12 * scale, "symmetric covariance", line);
    check(off_identity < 1e-9, "covariance * information = I", line);
}

void test_version_and_handle() {
    CHECK(sie_version_number() == SIE_VERSION_NUMBER);
    CHECK(std::strcmp(sie_version_string(), SIE_VERSION_STRING) == 0);
    sie::Context context;
    CHECK(context.c_api() != nullptr);
    EXPECT_ERROR(sie::Status::NoResult, context.summary());
    EXPECT_ERROR(sie::Status::NoResult, context.pose_uncertainty());

    // release() hands the handle over; the C API frees it.
    sie_context *raw = context.release();
    CHECK(raw != nullptr);
    CHECK(context.c_api() == nullptr);
    sie_context_free(raw);
    // A released (or moved-from) context reports a NULL handle instead of crashing.
    const std::string detail = EXPECT_ERROR(sie::Status::NullArgument, context.set_max_iterations(10));
    CHECK(contains(detail, "NULL"));
}

void test_settings_errors() {
    sie::Context context;
    std::string detail = EXPECT_ERROR(sie::Status::InvalidArgument, context.set_max_iterations(0));
    CHECK(!detail.empty());
    EXPECT_ERROR(sie::Status::InvalidArgument, context.set_cost_function(sie::CostFunction::TruncatedL2, -1.0));
    EXPECT_ERROR(sie::Status::InvalidArgument, context.set_cost_function(static_cast<sie::CostFunction>(99)));
    EXPECT_ERROR(sie::Status::InvalidArgument, context.set_regularizer(0.0, 1.5));
    EXPECT_ERROR(sie::Status::InvalidArgument, context.set_normal_neighbours(1));
    detail = EXPECT_ERROR(sie::Status::InvalidArgument, context.set_starts(static_cast<sie::Starts>(3)));
    CHECK(contains(detail, "starts = 3"));
    // Valid settings chain.
    context.set_metric(sie::Metric::PointToPlane).set_max_iterations(100).set_seed(7).set_threads(2);
    context.set_starts(sie::Starts::InitialGuess).set_starts(sie::Starts::Automatic);
    CHECK(std::string(sie::to_string(sie::Verdict::Doubtful)) == "doubtful");
    CHECK(std::string(sie::to_string(sie::StartKind::ScaleFreeLead)) == "scale-free lead");
    CHECK(std::string(sie::to_string(sie::Status::Busy)) == sie_status_str(SIE_STATUS_BUSY));
}

void test_cloud_registration(const Clouds &clouds) {
    sie::Context context;
    context.set_trace(true);
    const sie::Transform T = context.align(clouds.source, clouds.target);
    CHECK(close_to(T, clouds.truth, 0.2, 0.004));
    const sie::Summary summary = context.summary();
    CHECK(summary.converged);
    CHECK(summary.stop_reason == sie::StopReason::Converged);
    CHECK(summary.source_count == clouds.source.size());
    CHECK(summary.iterations > 0);
    // Point-to-plane residuals of two scans with 2 mm noise each: sigma near 2.8 mm.
    CHECK(summary.sigma[0] > 0.0015 && summary.sigma[0] < 0.006);
    CHECK(summary.inlier_fraction > 0.5 && summary.inlier_fraction <= 1.0);
    // A well-constrained scene with 2 mm noise: GOOD after the paper's start, a local correction
    // of the guess (the search ends without the other starts and without a rerun).
    CHECK(summary.verdict == sie::Verdict::Good);
    CHECK(summary.starts_run == 1 && summary.agreeing_starts == 1);
    CHECK(summary.start != sie::StartKind::Hypothesis && summary.hypotheses == 0);
    CHECK(summary.significance > 100.0);
    CHECK(summary.conditioning > 1e-3 && summary.conditioning <= 1.0);
    CHECK(summary.sigma_to_spacing > 0.0 && summary.sigma_to_spacing <= 1.0);
    CHECK(summary.margin == 0.0 ? summary.runner_up_significance == 0.0 : summary.margin >= 2.0);
    check_pose_uncertainty(context.pose_uncertainty(), __LINE__);

    const std::vector<double> probabilities = context.inlier_probabilities();
    CHECK(probabilities.size() == clouds.source.size());
    bool in_range = true;
    for (double p : probabilities) {
        in_range = in_range && p >= 0.0 && p <= 1.0;
    }
    CHECK(in_range);
    const std::vector<std::int64_t> matches = context.correspondences();
    CHECK(matches.size() == clouds.source.size());
    CHECK(matches[0] >= -1 && matches[0] < static_cast<std::int64_t>(clouds.target.size()));

    const std::vector<sie::TraceEntry> trace = context.trace();
    CHECK(trace.size() == summary.iterations);
    CHECK(summary.histogram_count >= 1);
    const sie::Histogram histogram = context.histogram(0);
    CHECK(histogram.model.bins > 0);
    CHECK(histogram.counts.size() == histogram.model.bins);
    CHECK(histogram.probability.size() == histogram.model.bins);
    CHECK(histogram.model.peak_found);
    EXPECT_ERROR(sie::Status::InvalidArgument, context.histogram(summary.histogram_count));

    // The same clouds through a 16-byte stride (a pcl::PointXYZ-like layout), from a guess.
    struct Padded {
        float x, y, z, pad;
    };
    std::vector<Padded> source16, target16;
    for (const auto &p : clouds.source) {
        source16.push_back({p[0], p[1], p[2], std::numeric_limits<float>::quiet_NaN()});
    }
    for (const auto &p : clouds.target) {
        target16.push_back({p[0], p[1], p[2], std::numeric_limits<float>::quiet_NaN()});
    }
    const sie::Transform strided = context.align(sie::Points(&source16[0].x, source16.size(), sizeof(Padded)),
                                                 sie::Points(&target16[0].x, target16.size(), sizeof(Padded)),
                                                 scene::rigid(0.05, {0.3, -0.2, 1.0}, {0.05, 0.0, 0.0}));
    CHECK(close_to(strided, clouds.truth, 0.2, 0.004));

    // Double precision.
    std::vector<std::array<double, 3>> source_d, target_d;
    for (const auto &p : clouds.source) {
        source_d.push_back({p[0], p[1], p[2]});
    }
    for (const auto &p : clouds.target) {
        target_d.push_back({p[0], p[1], p[2]});
    }
    CHECK(close_to(context.align(source_d, target_d), clouds.truth, 0.2, 0.004));

    // Caller-supplied normals.
    CHECK(close_to(context.align_with_normals(clouds.source, clouds.target, clouds.target_normals), clouds.truth,
                   0.2, 0.004));
    std::vector<std::array<float, 3>> too_few(clouds.target_normals.begin(), clouds.target_normals.end() - 1);
    EXPECT_ERROR(sie::Status::InvalidArgument, context.align_with_normals(clouds.source, clouds.target, too_few));
    std::vector<std::array<float, 3>> long_normals = clouds.target_normals;
    long_normals[5] = {2.0f, 0.0f, 0.0f};
    std::string detail = EXPECT_ERROR(sie::Status::InvalidArgument,
                                      context.align_with_normals(clouds.source, clouds.target, long_normals));
    CHECK(contains(detail, "[5]"));
    // A failed call drops the stored result.
    EXPECT_ERROR(sie::Status::NoResult, context.summary());
    EXPECT_ERROR(sie::Status::NoResult, context.pose_uncertainty());
}

void test_input_errors(const Clouds &clouds) {
    sie::Context context;
    std::vector<std::array<float, 3>> with_nan = clouds.source;
    with_nan[17][1] = std::numeric_limits<float>::quiet_NaN();
    std::string detail = EXPECT_ERROR(sie::Status::NonFiniteInput, context.align(with_nan, clouds.target));
    CHECK(contains(detail, "17"));
    EXPECT_ERROR(sie::Status::NullArgument, context.align(sie::Points(), clouds.target));
    EXPECT_ERROR(sie::Status::InvalidArgument,
                 context.align(sie::Points(clouds.source[0].data(), clouds.source.size(), 10), clouds.target));
    sie::Transform not_rigid = sie::identity_transform();
    not_rigid[0] = 2.0;
    EXPECT_ERROR(sie::Status::InvalidArgument, context.align(clouds.source, clouds.target, not_rigid));
}

void test_correspondences() {
    // The paper's simulation in small: inliers A uniform in [0,1]^3, B = A + noise, A moved by
    // T0; as many outliers with B uniform around A.
    scene::Random random(5);
    const scene::Matrix t0 = scene::rigid(0.5, {1.0, 0.0, 0.0}, {0.3, 0.0, 0.0});
    std::vector<std::array<double, 3>> source, target;
    for (int i = 0; i < 400; ++i) {
        const scene::Point a{random.uniform(0, 1), random.uniform(0, 1), random.uniform(0, 1)};
        const scene::Point moved = scene::apply(t0, a);
        source.push_back(moved);
        target.push_back({a[0] + random.gaussian(0.01), a[1] + random.gaussian(0.01), a[2] + random.gaussian(0.01)});
    }
    for (int i = 0; i < 400; ++i) {
        const scene::Point a{random.uniform(0, 1), random.uniform(0, 1), random.uniform(0, 1)};
        source.push_back(a);
        target.push_back({a[0] + random.uniform(-1, 1), a[1] + random.uniform(-1, 1), a[2] + random.uniform(-1, 1)});
    }
    sie::Context context;
    const sie::Transform T = context.align_correspondences(source, target);
    CHECK(close_to(T, scene::inverse(t0), 1.0, 0.01));
    const std::vector<double> p = context.inlier_probabilities();
    double inlier_mean = 0.0, outlier_mean = 0.0;
    for (int i = 0; i < 400; ++i) {
        inlier_mean += p[i] / 400.0;
        outlier_mean += p[400 + i] / 400.0;
    }
    CHECK(inlier_mean > 0.8);
    CHECK(outlier_mean < 0.3);
    const std::vector<std::int64_t> matches = context.correspondences();
    CHECK(matches.size() == 800 && matches[0] == 0 && matches[799] == 799);
    const sie::Summary summary = context.summary();
    CHECK(summary.verdict == sie::Verdict::Good);
    CHECK(summary.hypotheses > 0 && summary.sigma_to_spacing == 0.0 && summary.significance > 0.0);
    CHECK(summary.start == sie::StartKind::InitialGuess || summary.start == sie::StartKind::Hypothesis);
    check_pose_uncertainty(context.pose_uncertainty(), __LINE__);

    std::vector<std::array<float, 3>> source_f, target_f;
    for (std::size_t i = 0; i < source.size(); ++i) {
        source_f.push_back({float(source[i][0]), float(source[i][1]), float(source[i][2])});
        target_f.push_back({float(target[i][0]), float(target[i][1]), float(target[i][2])});
    }
    CHECK(close_to(context.align_correspondences(source_f, target_f), scene::inverse(t0), 1.0, 0.01));
    target_f.pop_back();
    EXPECT_ERROR(sie::Status::InvalidArgument, context.align_correspondences(source_f, target_f));
}

struct CallbackFailure : std::runtime_error {
    explicit CallbackFailure(int code_) : std::runtime_error("callback failure"), code(code_) {}
    int code;
};

void test_noise_callback(const Clouds &clouds) {
    int calls_source = 0, calls_target = 0;
    std::size_t points_seen = 0;
    sie::Context context;
    // Quadratic in depth, as a structured-light camera: sigma = 1 + (|z| / 1 m)^2 (relative).
    context.set_noise_callback([&](sie::Cloud cloud, const double *xyz, std::size_t n, double *sigma) {
        (cloud == sie::Cloud::Source ? calls_source : calls_target) += 1;
        points_seen += n;
        for (std::size_t i = 0; i < n; ++i) {
            const double z = xyz[3 * i + 2];
            sigma[i] = 1.0 + z * z;
        }
    });
    CHECK(close_to(context.align(clouds.source, clouds.target), clouds.truth, 0.2, 0.004));
    CHECK(calls_source == 1 && calls_target == 1);
    CHECK(points_seen == clouds.source.size() + clouds.target.size());

    // The holder survives a move of the context: the new owner still calls it.
    sie::Context moved = std::move(context);
    calls_source = 0;
    moved.align(clouds.source, clouds.target);
    CHECK(calls_source == 1);

    // An exception thrown in the callback comes back out of align() with its type and data,
    // and the context stays usable.
    moved.set_noise_callback([](sie::Cloud cloud, const double *, std::size_t, double *) {
        if (cloud == sie::Cloud::Target) {
            throw CallbackFailure(42);
        }
    });
    bool rethrown = false;
    try {
        moved.align(clouds.source, clouds.target);
    } catch (const CallbackFailure &failure) {
        rethrown = failure.code == 42;
    } catch (...) {
    }
    CHECK(rethrown);
    EXPECT_ERROR(sie::Status::NoResult, moved.summary());

    // Non-exception types too.
    moved.set_noise_callback([](sie::Cloud, const double *, std::size_t, double *) { throw 7; });
    bool int_rethrown = false;
    try {
        moved.align(clouds.source, clouds.target);
    } catch (int value) {
        int_rethrown = value == 7;
    }
    CHECK(int_rethrown);

    // Scales the library rejects are its own error, with its message.
    moved.set_noise_callback([](sie::Cloud, const double *, std::size_t n, double *sigma) { sigma[n / 2] = -1.0; });
    std::string detail = EXPECT_ERROR(sie::Status::CallbackFailed, moved.align(clouds.source, clouds.target));
    CHECK(!detail.empty());

    // Calling back into the busy context from the callback: the library refuses with BUSY,
    // the wrapper throws that inside the callback, and it surfaces from align().
    moved.set_noise_callback([&moved](sie::Cloud, const double *, std::size_t, double *) { moved.set_seed(1); });
    EXPECT_ERROR(sie::Status::Busy, moved.align(clouds.source, clouds.target));

    // Removing the callback: no more calls, registration as without one.
    int calls_after_clear = 0;
    moved.set_noise_callback([&](sie::Cloud, const double *, std::size_t, double *) { ++calls_after_clear; });
    moved.clear_noise_callback();
    CHECK(close_to(moved.align(clouds.source, clouds.target), clouds.truth, 0.2, 0.004));
    CHECK(calls_after_clear == 0);
    // An empty std::function also removes it.
    moved.set_noise_callback([&](sie::Cloud, const double *, std::size_t, double *) { ++calls_after_clear; });
    moved.set_noise_callback(sie::NoiseFunction());
    moved.align(clouds.source, clouds.target);
    CHECK(calls_after_clear == 0);

    // A context destroyed with a callback installed frees both (valgrind checks the leak).
    sie::Context short_lived;
    short_lived.set_noise_callback([](sie::Cloud, const double *, std::size_t, double *) {});
}

struct ProgressFailure : std::runtime_error {
    ProgressFailure() : std::runtime_error("progress failure") {}
};

void test_progress_cancel_and_skipping(const Clouds &clouds) {
    sie::Context context;
    std::vector<std::uint32_t> seen;
    context.set_progress_callback([&seen](const sie::TraceEntry &entry) {
        seen.push_back(entry.iteration);
        return true;
    });
    context.align(clouds.source, clouds.target);
    const sie::Summary full = context.summary();
    CHECK(full.converged);
    CHECK(seen.size() == full.iterations && !seen.empty() && seen.front() == 1 && seen.back() == full.iterations);

    // Returning false cancels: not an error, the transform so far and a CANCELLED result.
    context.set_progress_callback([](const sie::TraceEntry &entry) { return entry.iteration < 3; });
    const sie::Transform partial = context.align(clouds.source, clouds.target);
    const sie::Summary cancelled = context.summary();
    CHECK(cancelled.stop_reason == sie::StopReason::Cancelled && !cancelled.converged);
    CHECK(cancelled.iterations == 3);
    CHECK(partial != sie::identity_transform());

    // Throwing cancels too, and the exception comes out of align().
    context.set_progress_callback([](const sie::TraceEntry &) -> bool { throw ProgressFailure(); });
    bool rethrown = false;
    try {
        context.align(clouds.source, clouds.target);
    } catch (const ProgressFailure &) {
        rethrown = true;
    }
    CHECK(rethrown);
    context.clear_progress_callback();

    // cancel() with nothing running stops the next registration after its first iteration.
    context.cancel();
    context.align(clouds.source, clouds.target);
    CHECK(context.summary().stop_reason == sie::StopReason::Cancelled);
    CHECK(context.summary().iterations == 1);
    // The request was consumed: the next one runs to convergence.
    context.align(clouds.source, clouds.target);
    CHECK(context.summary().converged);

    // Non-finite points: refused by default, dropped on request with P = 0 and no match.
    std::vector<std::array<float, 3>> with_nan = clouds.source;
    with_nan[17][0] = std::numeric_limits<float>::infinity();
    context.set_skip_non_finite(true);
    CHECK(close_to(context.align(with_nan, clouds.target), clouds.truth, 0.2, 0.004));
    CHECK(context.inlier_probabilities()[17] == 0.0);
    CHECK(context.correspondences()[17] == -1);
    CHECK(context.summary().source_count == clouds.source.size());
}

void test_estimate_inliers() {
    scene::Random random(9);
    std::vector<double> residuals;
    for (int i = 0; i < 3000; ++i) {
        residuals.push_back(random.gaussian(0.02));
    }
    for (int i = 0; i < 1000; ++i) {
        residuals.push_back(random.uniform(-1.0, 1.0));
    }
    sie::Context context;
    const sie::InlierEstimate estimate = context.estimate_inliers(residuals.data(), residuals.size(), 1);
    CHECK(estimate.probabilities.size() == residuals.size());
    CHECK(estimate.models.size() == 1);
    CHECK(std::fabs(estimate.models[0].sigma - 0.02) < 0.003);
    double outliers_far = 0.0;
    int far = 0;
    for (std::size_t i = 3000; i < residuals.size(); ++i) {
        if (std::fabs(residuals[i]) > 0.2) {
            outliers_far += estimate.probabilities[i];
            ++far;
        }
    }
    CHECK(far > 0 && outliers_far / far < 0.01);
    EXPECT_ERROR(sie::Status::InvalidArgument, context.estimate_inliers(residuals.data(), residuals.size(), 0));
}

// Where SIE starts, and verdicts other than GOOD.
void test_starts_and_verdicts(const Clouds &clouds) {
    sie::Context context;
    context.set_trace(true).set_starts(sie::Starts::InitialGuess);
    CHECK(close_to(context.align(clouds.source, clouds.target), clouds.truth, 0.2, 0.004));
    sie::Summary one = context.summary();
    // It travelled from the identity, by a local correction with every direction fixed: one run.
    CHECK(one.starts_run == 1 && one.start == sie::StartKind::InitialGuess && one.agreeing_starts == 1);
    CHECK(one.margin == 0.0 && one.runner_up_significance == 0.0);
    CHECK(one.verdict == sie::Verdict::Good);
    CHECK(context.trace().size() == one.iterations);
    // The cap holds per start: one start stops at it, the automatic ones make more updates.
    context.set_max_iterations(4);
    context.align(clouds.source, clouds.target);
    CHECK(context.summary().iterations == 4 && context.summary().stop_reason == sie::StopReason::IterationLimit);
    context.set_starts(sie::Starts::Automatic);
    context.align(clouds.source, clouds.target);
    CHECK(context.summary().starts_run == 3);
    CHECK(context.summary().iterations > 4 && context.summary().iterations <= 16);
    CHECK(context.trace().size() == context.summary().iterations);

    // A warm start from the previous summary, from the answer itself: one short run, kept.
    context.set_max_iterations(200);
    const sie::Transform cold = context.align(clouds.source, clouds.target);
    const sie::Summary cold_summary = context.summary();
    context.set_warm_start(cold_summary);
    CHECK(close_to(context.align(clouds.source, clouds.target, cold), clouds.truth, 0.2, 0.004));
    CHECK(context.summary().start == sie::StartKind::WarmStart && context.summary().starts_run == 1);
    CHECK(context.summary().iterations < cold_summary.iterations);
    CHECK(std::string(sie::to_string(sie::StartKind::WarmStart)) == "warm start");
    context.clear_warm_start();
    context.align(clouds.source, clouds.target, cold);
    CHECK(context.summary().start != sie::StartKind::WarmStart);
    // A summary that is not GOOD clears the warm start: its successor runs cold.
    CHECK(cold_summary.verdict == sie::Verdict::Good);
    sie::Summary doubtful = cold_summary;
    doubtful.verdict = sie::Verdict::Doubtful;
    context.set_warm_start(doubtful);
    context.align(clouds.source, clouds.target, cold);
    CHECK(context.summary().start != sie::StartKind::WarmStart);

    // Pairs with no relation at all: nothing stands out from chance.
    scene::Random random(21);
    std::vector<std::array<double, 3>> source, target;
    for (int i = 0; i < 600; ++i) {
        source.push_back({random.uniform(-1, 1), random.uniform(-1, 1), random.uniform(-1, 1)});
        target.push_back({random.uniform(-1, 1), random.uniform(-1, 1), random.uniform(-1, 1)});
    }
    sie::Context pairs;
    pairs.align_correspondences(source, target);
    const sie::Summary unrelated = pairs.summary();
    CHECK(unrelated.verdict == sie::Verdict::Unsupported);
    CHECK(unrelated.significance == 0.0);
    std::printf("unrelated pairs: verdict %s, significance %g, %u hypotheses\n", sie::to_string(unrelated.verdict),
                unrelated.significance, unrelated.hypotheses);
}

} // namespace

void test_prepared_target(const Clouds &clouds) {
    static_assert(std::is_copy_constructible<sie::Target>::value, "copies share one target");
    sie::Context context;
    context.set_threads(1);
    const sie::Transform direct = context.align(clouds.source, clouds.target);
    const std::vector<std::int64_t> direct_matches = context.correspondences();
    sie::Target empty;
    CHECK(!empty && empty.size() == 0);
    EXPECT_ERROR(sie::Status::NullArgument, context.align(clouds.source, empty));
    EXPECT_ERROR(sie::Status::NullArgument, empty.estimate_normals());

    const sie::Target target = context.prepare_target(clouds.target);
    CHECK(target && target.size() == clouds.target.size());
    for (int round = 0; round < 2; ++round) {
        CHECK(context.align(clouds.source, target) == direct);
        CHECK(context.correspondences() == direct_matches);
    }
    // Contexts on four threads at once, onto one target (a copy: shared ownership).
    const sie::Target shared = target;
    std::vector<sie::Transform> results(4);
    std::vector<std::thread> threads;
    for (std::size_t k = 0; k < results.size(); ++k) {
        threads.emplace_back([&, k] {
            sie::Context own;
            own.set_threads(1);
            results[k] = own.align(clouds.source, shared);
        });
    }
    for (auto &thread : threads) {
        thread.join();
    }
    for (const auto &result : results) {
        CHECK(result == direct);
    }
    target.estimate_normals(2);
    CHECK(context.align(clouds.source, target) == direct);
    // Given normals, and double clouds, take the same paths as align().
    const sie::Transform with_normals = context.align_with_normals(clouds.source, clouds.target, clouds.target_normals);
    CHECK(context.align(clouds.source, context.prepare_target(clouds.target, clouds.target_normals)) == with_normals);
    std::vector<std::array<double, 3>> source_d, target_d;
    for (const auto &p : clouds.source) {
        source_d.push_back({p[0], p[1], p[2]});
    }
    for (const auto &p : clouds.target) {
        target_d.push_back({p[0], p[1], p[2]});
    }
    const sie::Transform direct_d = context.align(source_d, target_d);
    CHECK(context.align(source_d, context.prepare_target(sie::PointsD(target_d))) == direct_d);
    CHECK(close_to(direct_d, clouds.truth, 0.2, 0.004));
    // Errors: normal count, settings that do not fit the target's normals.
    const std::string detail =
        EXPECT_ERROR(sie::Status::InvalidArgument,
                     context.prepare_target(clouds.target, sie::Points(clouds.target_normals.front().data(), 10, 12)));
    CHECK(contains(detail, "normals"));
    context.set_normal_neighbours(20);
    CHECK(context.normal_neighbours() == 20);
    EXPECT_ERROR(sie::Status::InvalidArgument, context.align(clouds.source, target));
}

// Odometry: the target's scan is the first frame (the world), the source's the second; its pose
// is T_target_source. A repeat and a refused frame change nothing.
void test_odometry(const Clouds &clouds) {
    sie::Context context;
    sie::Odometry empty;
    CHECK(!empty && empty.pose() == sie::identity_transform());
    EXPECT_ERROR(sie::Status::NullArgument, context.register_frame(empty, clouds.source));
    sie::Odometry odometry = context.odometry();
    CHECK(static_cast<bool>(odometry));
    const sie::Frame first = context.register_frame(odometry, clouds.target);
    CHECK(first.status == sie::FrameStatus::First && first.T_world_sensor == sie::identity_transform());
    const sie::Frame second = context.register_frame(odometry, clouds.source);
    CHECK(second.status == sie::FrameStatus::Accepted);
    CHECK(close_to(second.T_world_sensor, clouds.truth, 0.2, 0.004));
    CHECK(context.summary().verdict == sie::Verdict::Good);
    CHECK(odometry.pose() == second.T_world_sensor);
    const sie::Frame again = context.register_frame(odometry, clouds.source);
    CHECK(again.status == sie::FrameStatus::Repeated && again.T_world_sensor == second.T_world_sensor);
    EXPECT_ERROR(sie::Status::TooFewPoints, context.register_frame(odometry, sie::Points(clouds.source.front().data(), 2)));
    CHECK(odometry.pose() == second.T_world_sensor);
}

int main() {
    try {
        const Clouds clouds = room_clouds(2500);
        test_version_and_handle();
        test_settings_errors();
        test_cloud_registration(clouds);
        test_input_errors(clouds);
        test_correspondences();
        test_noise_callback(clouds);
        test_progress_cancel_and_skipping(clouds);
        test_starts_and_verdicts(clouds);
        test_prepared_target(clouds);
        test_odometry(clouds);
        test_estimate_inliers();
    } catch (const std::exception &unexpected) {
        std::fprintf(stderr, "unexpected exception: %s\n", unexpected.what());
        ++failures;
    }
    std::printf("sie.hpp: %d checks, %d failed\n", checks, failures);
    return failures == 0 ? 0 : 1;
}
