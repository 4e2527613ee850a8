/*
 * sie_pcl.hpp: PCL and Eigen adapter for sie.hpp (header-only, C++17).
 *
 *   sie::Context ctx;
 *   Eigen::Matrix4d T = sie::align(ctx, *source, *target);          // any PCL point type with xyz
 *   Eigen::Matrix4d T = sie::align_with_normals(ctx, *source, *target_with_normals);
 *
 *   sie::PclRegistration<pcl::PointXYZ, pcl::PointXYZ> reg;         // pcl::Registration-style
 *   reg.setInputSource(source); reg.setInputTarget(target); reg.align(aligned);
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
#include <pcl/point_cloud.h>
#include <pcl/point_types.h>
#include <pcl/type_traits.h>

#include <string>

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
 * The subset of pcl::Registration's interface a pipeline usually calls, so replacing
 * pcl::IterativeClosestPoint<PointSource, PointTarget, Scalar> is a change of type name.
 * With a target type that has normals, they are used (setUseTargetNormals(false) to estimate
 * them instead).
 */
template <typename PointSource, typename PointTarget, typename Scalar = float> class PclRegistration {
  public:
    using PointCloudSource = pcl::PointCloud<PointSource>;
    using PointCloudTarget = pcl::PointCloud<PointTarget>;
    using Matrix4 = Eigen::Matrix<Scalar, 4, 4>;

    PclRegistration() = default;
    explicit PclRegistration(Context context) : context_(std::move(context)) {}

    /** The underlying context, for sie settings (cost, metric, noise callback, ...). */
    Context &context() noexcept { return context_; }

    void setInputSource(const typename PointCloudSource::ConstPtr &cloud) { source_ = cloud; }
    void setInputTarget(const typename PointCloudTarget::ConstPtr &cloud) { target_ = cloud; }
    void setUseTargetNormals(bool use) noexcept { use_target_normals_ = use; }
    void setMaximumIterations(int iterations) { context_.set_max_iterations(static_cast<std::uint32_t>(iterations)); }

    /** Registers, writes the transformed source into output, keeps the transform. */
    void align(PointCloudSource &output, const Matrix4 &guess = Matrix4::Identity()) {
        if (!source_ || !target_) {
            throw Error(Status::NullArgument, "setInputSource and setInputTarget must be called before align");
        }
        const Eigen::Matrix4d guess_d = guess.template cast<double>();
        Eigen::Matrix4d transform;
        if constexpr (pcl::traits::has_normal_v<PointTarget>) {
            transform = use_target_normals_ ? align_with_normals(context_, *source_, *target_, guess_d)
                                            : sie::align(context_, *source_, *target_, guess_d);
        } else {
            transform = sie::align(context_, *source_, *target_, guess_d);
        }
        final_transformation_ = transform.cast<Scalar>();
        summary_ = context_.summary();
        transform_cloud(*source_, output, transform);
    }

    Matrix4 getFinalTransformation() const { return final_transformation_; }
    /** True only when the library reports convergence (unlike PCL, not at the iteration cap). */
    bool hasConverged() const noexcept { return summary_.converged; }
    /** sie's weighted RMSE (input units) of the last alignment. */
    double getRmse() const noexcept { return summary_.rmse; }
    const Summary &summary() const noexcept { return summary_; }

  private:
    // Rigid transform of xyz (and normals, when the type has them); other fields are copied.
    static void transform_cloud(const PointCloudSource &input, PointCloudSource &output,
                                const Eigen::Matrix4d &transform) {
        if (&input != &output) {
            output = input;
        }
        const Eigen::Matrix3f rotation = transform.topLeftCorner<3, 3>().cast<float>();
        const Eigen::Vector3f translation = transform.topRightCorner<3, 1>().cast<float>();
        for (auto &point : output.points) {
            Eigen::Map<Eigen::Vector3f> xyz(&point.x);
            xyz = rotation * xyz + translation;
            if constexpr (pcl::traits::has_normal_v<PointSource>) {
                Eigen::Map<Eigen::Vector3f> normal(&point.normal_x);
                normal = rotation * normal;
            }
        }
    }

    Context context_;
    typename PointCloudSource::ConstPtr source_;
    typename PointCloudTarget::ConstPtr target_;
    bool use_target_normals_ = true;
    Matrix4 final_transformation_ = Matrix4::Identity();
    Summary summary_{};
};

} // namespace sie

#endif /* SIE_PCL_HPP */
