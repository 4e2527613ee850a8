/*
 * sie_pcl.hpp: PCL and Eigen adapter for sie.hpp (header-only, C++17).
 *
 *   sie::Context ctx;
 *   Eigen::Matrix4d T = sie::align(ctx, *source, *target);          // any PCL point type with xyz
 *   Eigen::Matrix4d T = sie::align_with_normals(ctx, *source, *target_with_normals);
 *   Eigen::Matrix<double, 6, 6> cov = sie::to_eigen(ctx.pose_uncertainty().covariance);  // rotation first
 *
 *   sie::PclRegistration<pcl::PointXYZ, pcl::PointXYZ> icp;         // a pcl::Registration: in place
 *   icp.setInputSource(source); icp.setInputTarget(target);        // of pcl::IterativeClosestPoint
 *   icp.align(aligned); icp.hasConverged(); icp.getFitnessScore(); icp.getFinalTransformation();
 *   icp.getCorrespondences();                                     // the inliers' pairs
 *
 * Clouds are passed to the library in place through its byte-stride API (sizeof(PointT) between
 * points): nothing is copied. A NaN coordinate is Status::NonFiniteInput unless
 * context.set_skip_non_finite(true) (for clouds with is_dense = false), which drops such points
 * and also treats NaN normals as "no normal". A zero normal (0 0 0) marks a target point without
 * a normal.
 *
 * Transforms are Eigen matrices in Eigen's own (column-major) storage; the row-major
 * conversion for the C API happens here.
 */
#ifndef SIE_PCL_HPP
#define SIE_PCL_HPP

#include "sie.hpp"

#include <Eigen/Core>
#include <Eigen/LU>
#include <pcl/common/io.h>
#include <pcl/common/point_tests.h>
#include <pcl/common/transforms.h>
#include <pcl/correspondence.h>
#include <pcl/point_cloud.h>
#include <pcl/point_types.h>
#include <pcl/registration/registration.h>
#include <pcl/type_traits.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <optional>
#include <string>
#include <vector>

namespace sie {

namespace pcl_detail {

// The library reads three consecutive floats per point, so x, y, z (and the normal's
// components) must be adjacent, as they are in every PCL type built on PCL_ADD_POINT4D.
template <typename PointT, typename X, typename Y, typename Z> constexpr bool consecutive_floats() {
    return pcl::traits::offset<PointT, Y>::value == pcl::traits::offset<PointT, X>::value + sizeof(float) &&
           pcl::traits::offset<PointT, Z>::value == pcl::traits::offset<PointT, Y>::value + sizeof(float) &&
           std::is_same<typename pcl::traits::datatype<PointT, X>::type, float>::value;
}

template <typename PointT> void require_points(const pcl::PointCloud<PointT> &cloud, const char *which) {
    if (cloud.empty()) {
        throw Error(Status::TooFewPoints, std::string(which) + " cloud is empty");
    }
}

} // namespace pcl_detail

/** The xyz of a PCL cloud as a strided view into its own memory (no copy). */
template <typename PointT> Points xyz_view(const pcl::PointCloud<PointT> &cloud) noexcept {
    static_assert(pcl::traits::has_xyz_v<PointT>, "the point type has no x, y, z fields");
    static_assert(pcl_detail::consecutive_floats<PointT, pcl::fields::x, pcl::fields::y, pcl::fields::z>(),
                  "x, y, z must be consecutive floats");
    if (cloud.empty()) {
        return {};
    }
    return {&cloud.points.front().x, cloud.size(), sizeof(PointT)};
}

/** The normals of a PCL cloud (e.g. pcl::PointNormal) as a strided view (no copy). */
template <typename PointT> Points normals_view(const pcl::PointCloud<PointT> &cloud) noexcept {
    static_assert(pcl::traits::has_normal_v<PointT>, "the point type has no normal_x, normal_y, normal_z fields");
    static_assert(
        pcl_detail::consecutive_floats<PointT, pcl::fields::normal_x, pcl::fields::normal_y, pcl::fields::normal_z>(),
        "normal_x, normal_y, normal_z must be consecutive floats");
    if (cloud.empty()) {
        return {};
    }
    return {&cloud.points.front().normal_x, cloud.size(), sizeof(PointT)};
}

/** Row-major sie::Transform to an Eigen matrix. */
inline Eigen::Matrix4d to_eigen(const Transform &transform) {
    return Eigen::Map<const Eigen::Matrix<double, 4, 4, Eigen::RowMajor>>(transform.data());
}

/** A row-major 6x6 of sie::PoseUncertainty (covariance or information) to an Eigen matrix;
 * rows and columns 0..2 are the rotation vector, 3..5 the translation. */
inline Eigen::Matrix<double, 6, 6> to_eigen(const std::array<double, 36> &matrix) {
    return Eigen::Map<const Eigen::Matrix<double, 6, 6, Eigen::RowMajor>>(matrix.data());
}

/** Any 4x4 Eigen matrix (float or double, any storage order) to a row-major sie::Transform. */
template <typename Derived> Transform to_transform(const Eigen::MatrixBase<Derived> &matrix) {
    static_assert(Derived::RowsAtCompileTime == 4 && Derived::ColsAtCompileTime == 4, "a 4x4 matrix is required");
    Transform transform{};
    Eigen::Map<Eigen::Matrix<double, 4, 4, Eigen::RowMajor>>(transform.data()) = matrix.template cast<double>();
    return transform;
}

/** ICP of source onto target with the context's settings; returns T_target_source. */
template <typename PointSource, typename PointTarget>
Eigen::Matrix4d align(Context &context, const pcl::PointCloud<PointSource> &source,
                      const pcl::PointCloud<PointTarget> &target,
                      const Eigen::Matrix4d &guess = Eigen::Matrix4d::Identity()) {
    pcl_detail::require_points(source, "source");
    pcl_detail::require_points(target, "target");
    return to_eigen(context.align(xyz_view(source), xyz_view(target), to_transform(guess)));
}

/** As align(), with the target cloud's own normals for point-to-plane (caller-supplied). */
template <typename PointSource, typename PointTarget>
Eigen::Matrix4d align_with_normals(Context &context, const pcl::PointCloud<PointSource> &source,
                                   const pcl::PointCloud<PointTarget> &target,
                                   const Eigen::Matrix4d &guess = Eigen::Matrix4d::Identity()) {
    pcl_detail::require_points(source, "source");
    pcl_detail::require_points(target, "target");
    return to_eigen(
        context.align_with_normals(xyz_view(source), xyz_view(target), normals_view(target), to_transform(guess)));
}

/**
 * sie as a pcl::Registration: a drop-in for pcl::IterativeClosestPoint<PointSource, PointTarget>
 * (a change of type name), and a Registration::Ptr for anything that takes one
 * (pcl::registration::IncrementalRegistration, ELCH, your own pipeline).
 *
 * What PCL's settings mean here:
 * - One run from the guess, as PCL's ICP (and a second from its result when the first ended
 *   more than 10 fitted sigma from the guess, beyond a local correction): the context is set to sie::Starts::InitialGuess on
 *   construction, so the updates, the visualisation callback, the increments and the criteria
 *   below are those of one run (a second run's updates follow in order; it has its own cap, as
 *   every start does). context().set_starts(sie::Starts::Automatic) runs SIE from
 *   several starts instead (the updates of every start are then reported in order, and the
 *   iteration cap holds per start); context().set_starts(sie::Starts::Global) needs no guess
 *   (FPFH descriptor matches propose the starts; slower, and small or flat clouds are refused).
 * - Sequences (odometry, scan-to-map): after each align(), context().set_warm_start(summary())
 *   starts the next one from this frame's noise model (~60 % of the updates; sie falls
 *   back to the full schedule by itself when the guess was bad).
 * - setMaximumIterations(n): caps each run's updates at n. The default is sie's 200, not PCL's 10:
 *   SIE anneals its noise model over typically 30-60 updates.
 * - hasConverged(): the C summary's `converged` (sie stopped by its own criteria), or the
 *   Euclidean fitness criterion below was met. A run that reached the iteration cap has not
 *   converged (PCL's default criteria call that converged; here it is always the failure
 *   PCL's setFailureAfterMaximumIterations(true) asks for, and its verdict is never GOOD);
 *   false also when the registration could not run or found no unique solution.
 *   summary().stop_reason says why it stopped, summary().verdict how far to trust the pose.
 * - setTransformationEpsilon(e) (> 0): converged when an update translates by at most sqrt(e)
 *   (PCL compares the squared translation) and rotates by at most acos(1 - e), or
 *   acos(setTransformationRotationEpsilon's cosine) when that is set. 0 keeps sie's tolerances.
 * - setEuclideanFitnessEpsilon(e) (> 0): also converged when, after SIE's annealing, the
 *   weighted mean squared residual changes by less than the fraction e between two updates
 *   (PCL's relative MSE criterion).
 * - setMaxCorrespondenceDistance, setRANSACOutlierRejectionThreshold, correspondence
 *   rejectors and transformation estimation objects are accepted and not used: sie has no
 *   distance gate and estimates the inliers itself. setSearchMethodTarget gives the kd-tree
 *   getFitnessScore uses (sie matches with its own).
 * - getFitnessScore(max_range) is PCL's own: mean squared nearest-neighbour distance of the
 *   aligned source to the target.
 * - getCorrespondences() (PCL's Registration keeps them protected): the inliers of the last
 *   align() as pcl::Correspondences, the pairs Open3D's correspondence_set lists.
 * - getPoseCovariance() / getPoseInformation() (sie's; PCL has none): the 6x6 covariance of
 *   the final transformation and its inverse, ROTATION FIRST: for T = Exp(d) * T_final with
 *   d = (rotation vector [rad], translation [input units]) in the target frame (a left
 *   perturbation; GTSAM's Pose3 orders rotation first too but perturbs on the right, in the
 *   source frame).
 * - registerVisualizationCallback(f): f(source moved by the current transform, source indices,
 *   target, their nearest target points) after every update, like PCL's ICP.
 * - Errors follow PCL: a missing input cloud, too few points or bad input make align() print
 *   PCL_ERROR and return with hasConverged() == false, the guess as the final transformation
 *   and the source moved by it; lastError() keeps sie's status and message. Exceptions thrown
 *   by a visualisation callback propagate out of align().
 * - Metric: point-to-plane (sie's default), with the target's own normals when PointTarget has
 *   normal_x/y/z (setUseTargetNormals(false) estimates them instead). When that finds no unique
 *   solution (a handful of points, a single plane) align() reruns point-to-point from the same
 *   guess, like pcl::IterativeClosestPoint; setMetric() fixes the metric instead.
 * - PointSource and PointTarget must be the same type with PCL 1.13: pcl::Registration's own
 *   initCompute() does not compile for mixed types (its reciprocal kd-tree types clash). For a
 *   PointXYZ source on a PointNormal target use sie::align_with_normals, or PointNormal for both.
 * - Clouds with is_dense == false, or target normals with NaN, drop the non-finite points
 *   (normals) as PCL's kd-trees do; setIndices() registers that subset of the source.
 * The adapter sets the context's iteration cap, tolerances, metric, skip_non_finite and
 * progress callback on each align(); other sie settings (cost, noise model, threads, noise
 * callback, ...) are the context()'s.
 */
template <typename PointSource, typename PointTarget, typename Scalar = float>
class PclRegistration : public pcl::Registration<PointSource, PointTarget, Scalar> {
    using Base = pcl::Registration<PointSource, PointTarget, Scalar>;

  public:
    using typename Base::Matrix4;
    using typename Base::PointCloudSource;
    using typename Base::PointCloudTarget;
    using typename Base::PointCloudTargetConstPtr;
    using Ptr = pcl::shared_ptr<PclRegistration<PointSource, PointTarget, Scalar>>;
    using ConstPtr = pcl::shared_ptr<const PclRegistration<PointSource, PointTarget, Scalar>>;

    /** sie's default cap on updates (RegistrationConfig::default().max_iterations). */
    static constexpr int kDefaultMaximumIterations = 200;

    PclRegistration() { init(); }
    explicit PclRegistration(Context context) : context_(std::move(context)) { init(); }

    /** The underlying context, for sie settings (cost, noise model, threads, noise callback, ...). */
    Context &context() noexcept { return context_; }

    /** Use a PointTarget type's own normals for point-to-plane (default true). */
    void setUseTargetNormals(bool use) noexcept { use_target_normals_ = use; }
    /** Fix the metric (no point-to-point rerun on a degenerate point-to-plane problem). */
    void setMetric(Metric metric) noexcept {
        metric_ = metric;
        metric_fixed_ = true;
    }
    /** Accepted for PCL's interface: reaching the iteration cap is always a failure here. */
    void setFailureAfterMaximumIterations(bool /*failure*/) noexcept {}

    /** As PCL's: a new target. The prepared target (kd-tree, normals) is rebuilt on the next
     * align(); until then it is kept across setInputSource() and align() calls, as
     * setSearchMethodTarget(tree, true) keeps PCL's tree. Call it again after changing the
     * target cloud in place. */
    void setInputTarget(const PointCloudTargetConstPtr &cloud) override {
        Base::setInputTarget(cloud);
        prepared_ = Prepared{};
    }

    /** The prepared target the next align() uses (empty before the first align() after
     * setInputTarget()); a copy may be shared with other Contexts (sie::Context::align). */
    const Target &preparedTarget() const noexcept { return prepared_.target; }

    /** sie's summary of the last align() (stop_reason, sigma, inlier_fraction, ...). */
    const Summary &summary() const noexcept { return summary_; }
    /** sie's inlier-probability-weighted RMSE (input units) of the last align(). */
    double getRmse() const noexcept { return summary_.rmse; }
    /**
     * Covariance of the last align()'s getFinalTransformation(), 6x6, ROTATION FIRST: the left
     * perturbation T = Exp(d) * T_final with d = (rotation vector [rad], translation [input
     * units]), both in the target frame (sie_context_get_pose_uncertainty). Directions the
     * inliers leave free have a far larger variance. Zero when the last align() failed.
     */
    const Eigen::Matrix<double, 6, 6> &getPoseCovariance() const noexcept { return pose_covariance_; }
    /** The inverse of getPoseCovariance() where the data constrain the pose (near 0 in free
     * directions): the information matrix, same order and frame. Zero when align() failed. */
    const Eigen::Matrix<double, 6, 6> &getPoseInformation() const noexcept { return pose_information_; }
    /**
     * The last align()'s inliers as PCL correspondences, in source order: one per source point
     * with a match and P(inlier) >= kInlierProbability, index_query its index in the input
     * source (setIndices() respected), index_match the target point's, distance the squared
     * distance between them at getFinalTransformation() (as PCL's CorrespondenceEstimation
     * reports it). Their number over the source points registered is Open3D's fitness. Empty
     * after a failed align(). sie has no distance gate: setMaxCorrespondenceDistance does not
     * select them.
     */
    const pcl::Correspondences &getCorrespondences() const noexcept { return *this->correspondences_; }
    /** A matched source point with at least this P(inlier) is an inlier (getCorrespondences()). */
    static constexpr double kInlierProbability = 0.5;
    /** The metric the last align() ended with. */
    Metric getMetricUsed() const noexcept { return metric_used_; }
    /** Why the last align() could not run (empty after a successful one). */
    const std::optional<Error> &lastError() const noexcept { return last_error_; }

  protected:
    using Base::converged_;
    using Base::correspondences_;
    using Base::final_transformation_;
    using Base::indices_;
    using Base::input_;
    using Base::nr_iterations_;
    using Base::previous_transformation_;
    using Base::target_;
    using Base::transformation_;
    using Base::tree_;
    using Base::update_visualizer_;

    void computeTransformation(PointCloudSource &output, const Matrix4 &guess) override {
        nr_iterations_ = 0;
        converged_ = false;
        last_error_.reset();
        summary_ = Summary{};
        pose_covariance_.setZero();
        pose_information_.setZero();
        correspondences_->clear();
        final_transformation_ = guess;
        // A subset given by setIndices() is registered on its own (copied); otherwise in place.
        const bool subset = indices_->size() != input_->size();
        PointCloudSource selected;
        if (subset) {
            pcl::copyPointCloud(*input_, *indices_, selected);
        }
        const PointCloudSource &source = subset ? selected : *input_;
        try {
            register_source(source, guess);
        } catch (const Error &error) {
            PCL_ERROR("[pcl::%s::computeTransformation] %s\n", this->getClassName().c_str(), error.what());
            last_error_ = error;
            converged_ = false;
            final_transformation_ = guess;
            pose_covariance_.setZero();
            pose_information_.setZero();
            correspondences_->clear();
        }
        move_source(output, final_transformation_);
    }

  private:
    void init() {
        this->reg_name_ = "sie::PclRegistration";
        this->max_iterations_ = kDefaultMaximumIterations;
        context_.set_starts(Starts::InitialGuess);
    }

    void register_source(const PointCloudSource &source, const Matrix4 &guess) {
        pcl_detail::require_points(source, "source");
        pcl_detail::require_points(*target_, "target");
        if (this->max_iterations_ < 1) {
            throw Error(Status::InvalidArgument,
                        "setMaximumIterations: " + std::to_string(this->max_iterations_) + " must be >= 1");
        }
        context_.set_max_iterations(static_cast<std::uint32_t>(this->max_iterations_));
        apply_tolerances();
        const bool normals = use_target_normals();
        prepare_target(normals);
        context_.set_skip_non_finite(!source.is_dense || prepared_.skip_non_finite);

        // Progress: the visualiser, PCL's relative-MSE criterion and the last increment.
        const double fitness_epsilon = this->euclidean_fitness_epsilon_;
        bool fitness_converged = false;
        double previous_mse = -1.0;
        Eigen::Matrix4d previous = guess.template cast<double>(), current = previous;
        context_.set_progress_callback([&](const TraceEntry &entry) {
            previous = current;
            current = Eigen::Map<const Eigen::Matrix<double, 4, 4, Eigen::RowMajor>>(entry.transform);
            if (update_visualizer_) {
                visualize(source, current);
            }
            const double mse = entry.rmse * entry.rmse;
            if (fitness_epsilon > 0.0 && !entry.annealing && previous_mse > 0.0 &&
                std::abs(mse - previous_mse) < fitness_epsilon * previous_mse) {
                fitness_converged = true;
                return false; // stop: converged by the caller's criterion
            }
            previous_mse = entry.annealing ? -1.0 : mse;
            return true;
        });
        struct ClearProgress {
            Context &context;
            ~ClearProgress() {
                try {
                    context.clear_progress_callback();
                } catch (...) {
                }
            }
        } clear{context_};

        const Eigen::Matrix4d guess_d = guess.template cast<double>();
        metric_used_ = metric_fixed_ ? metric_ : Metric::PointToPlane;
        Eigen::Matrix4d transform = run(source, guess_d, metric_used_);
        if (!metric_fixed_ && summary_.stop_reason == StopReason::Degenerate) {
            // Point-to-plane has no unique solution (e.g. all normals from one plane fit):
            // what pcl::IterativeClosestPoint would do, point-to-point from the same guess.
            metric_used_ = Metric::PointToPoint;
            previous_mse = -1.0;
            previous = current = guess_d;
            transform = run(source, guess_d, metric_used_);
        }
        const StopReason stop = summary_.stop_reason;
        converged_ = stop == StopReason::Converged || (stop == StopReason::Cancelled && fitness_converged);
        nr_iterations_ = static_cast<int>(summary_.iterations);
        final_transformation_ = transform.cast<Scalar>();
        previous_transformation_ = previous.cast<Scalar>();
        transformation_ = (current * previous.inverse()).cast<Scalar>();
        collect_inliers(source, transform);
    }

    // getCorrespondences(): the last run's matched points with P(inlier) >= kInlierProbability.
    void collect_inliers(const PointCloudSource &source, const Eigen::Matrix4d &transform) {
        const std::vector<double> probabilities = context_.inlier_probabilities();
        const std::vector<std::int64_t> matches = context_.correspondences();
        const bool subset = indices_->size() != input_->size();
        const Eigen::Matrix3d rotation = transform.topLeftCorner<3, 3>();
        const Eigen::Vector3d translation = transform.topRightCorner<3, 1>();
        correspondences_->clear();
        for (std::size_t i = 0; i < matches.size(); ++i) {
            if (matches[i] < 0 || probabilities[i] < kInlierProbability) {
                continue;
            }
            const auto &p = source.points[i];
            const auto &q = target_->points[static_cast<std::size_t>(matches[i])];
            const Eigen::Vector3d moved = rotation * Eigen::Vector3d(p.x, p.y, p.z) + translation;
            const double squared_distance = (moved - Eigen::Vector3d(q.x, q.y, q.z)).squaredNorm();
            const pcl::index_t query = subset ? (*indices_)[i] : static_cast<pcl::index_t>(i);
            correspondences_->emplace_back(query, static_cast<pcl::index_t>(matches[i]),
                                           static_cast<float>(squared_distance));
        }
    }

    // The target's kd-tree and normals, built once per setInputTarget() (and again only when
    // the settings it depends on change). Point-to-point ignores given normals, so one
    // prepared target serves the point-to-point rerun too.
    struct Prepared {
        Target target;
        bool with_normals = false;
        bool skip_non_finite = false;
        std::uint32_t normal_neighbours = 0;
    };

    void prepare_target(bool with_normals) {
        if (prepared_.target && prepared_.with_normals == with_normals &&
            prepared_.normal_neighbours == context_.normal_neighbours()) {
            return;
        }
        Prepared prepared;
        prepared.with_normals = with_normals;
        prepared.skip_non_finite = !target_->is_dense || (with_normals && !finite_normals());
        prepared.normal_neighbours = context_.normal_neighbours();
        context_.set_skip_non_finite(prepared.skip_non_finite);
        if constexpr (pcl::traits::has_normal_v<PointTarget>) {
            prepared.target = with_normals ? context_.prepare_target(xyz_view(*target_), normals_view(*target_))
                                           : context_.prepare_target(xyz_view(*target_));
        } else {
            prepared.target = context_.prepare_target(xyz_view(*target_));
        }
        prepared_ = std::move(prepared);
    }

    Eigen::Matrix4d run(const PointCloudSource &source, const Eigen::Matrix4d &guess, Metric metric) {
        context_.set_metric(metric);
        const Eigen::Matrix4d transform =
            to_eigen(context_.align(xyz_view(source), prepared_.target, to_transform(guess)));
        summary_ = context_.summary();
        const PoseUncertainty uncertainty = context_.pose_uncertainty();
        pose_covariance_ = to_eigen(uncertainty.covariance);
        pose_information_ = to_eigen(uncertainty.information);
        return transform;
    }

    bool use_target_normals() const noexcept {
        if constexpr (pcl::traits::has_normal_v<PointTarget>) {
            return use_target_normals_;
        }
        return false;
    }

    bool finite_normals() const {
        if constexpr (pcl::traits::has_normal_v<PointTarget>) {
            for (const auto &p : target_->points) {
                if (!std::isfinite(p.normal_x) || !std::isfinite(p.normal_y) || !std::isfinite(p.normal_z)) {
                    return false;
                }
            }
        }
        return true;
    }

    // PCL's criteria map onto sie's two tolerances; untouched (sie's) when neither is set.
    void apply_tolerances() {
        const double epsilon = this->transformation_epsilon_;
        const double rotation_cosine = this->transformation_rotation_epsilon_;
        if (epsilon > 0.0 || rotation_cosine > 0.0) {
            const auto angle = [](double cosine) { return std::acos(std::min(1.0, std::max(-1.0, cosine))); };
            const double translation = epsilon > 0.0 ? std::sqrt(epsilon) : kSieTolerance;
            const double rotation = rotation_cosine > 0.0 ? angle(rotation_cosine) : angle(1.0 - epsilon);
            context_.set_convergence(translation, rotation);
            tolerances_set_ = true;
        } else if (tolerances_set_) {
            context_.set_convergence(kSieTolerance, kSieTolerance);
            tolerances_set_ = false;
        }
    }

    // PCL's ICP passes the source moved by the current estimate and its correspondences.
    void visualize(const PointCloudSource &source, const Eigen::Matrix4d &transform) {
        PointCloudSource moved;
        pcl::transformPointCloud(source, moved, transform.cast<float>());
        pcl::Indices source_indices, target_indices;
        source_indices.reserve(moved.size());
        target_indices.reserve(moved.size());
        pcl::Indices nearest(1);
        std::vector<float> distance(1);
        PointTarget query;
        for (std::size_t i = 0; i < moved.size(); ++i) {
            query.x = moved[i].x;
            query.y = moved[i].y;
            query.z = moved[i].z;
            if (pcl::isFinite(moved[i]) && tree_->nearestKSearch(query, 1, nearest, distance) > 0) {
                source_indices.push_back(static_cast<pcl::index_t>(i));
                target_indices.push_back(nearest[0]);
            }
        }
        update_visualizer_(moved, source_indices, *target_, target_indices);
    }

    // As PCL's ICP: the output is the (selected) source moved by the final transformation,
    // normals rotated along when the type has them; other fields are copied.
    void move_source(PointCloudSource &output, const Matrix4 &transform) const {
        if constexpr (pcl::traits::has_normal_v<PointSource>) {
            if (indices_->size() != input_->size()) {
                pcl::transformPointCloudWithNormals(*input_, *indices_, output, transform);
            } else {
                pcl::transformPointCloudWithNormals(*input_, output, transform);
            }
        } else {
            if (indices_->size() != input_->size()) {
                pcl::transformPointCloud(*input_, *indices_, output, transform);
            } else {
                pcl::transformPointCloud(*input_, output, transform);
            }
        }
    }

    static constexpr double kSieTolerance = 1e-6; // RegistrationConfig::default()'s tolerances

    Context context_;
    bool use_target_normals_ = true;
    Metric metric_ = Metric::PointToPlane;
    bool metric_fixed_ = false;
    Metric metric_used_ = Metric::PointToPlane;
    bool tolerances_set_ = false;
    Summary summary_{};
    Eigen::Matrix<double, 6, 6> pose_covariance_ = Eigen::Matrix<double, 6, 6>::Zero();
    Eigen::Matrix<double, 6, 6> pose_information_ = Eigen::Matrix<double, 6, 6>::Zero();
    std::optional<Error> last_error_;
    Prepared prepared_;

  public:
    PCL_MAKE_ALIGNED_OPERATOR_NEW
};

} // namespace sie

#endif /* SIE_PCL_HPP */
