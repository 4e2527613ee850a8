// Tests of bindings/sie_pcl.hpp with real PCL types: the views point into the clouds' own
// memory (no copy), caller-supplied PointNormal normals are what the library uses, Eigen
// transforms convert in the right storage order, and PclRegistration behaves like PCL's
// Registration interface. Built by examples-cpp (needs PCL), run by its ctest.
#include <sie_pcl.hpp>

#include <pcl/point_cloud.h>
#include <pcl/point_types.h>

#include <Eigen/Geometry>

#include <cmath>
#include <cstdint>
#include <cstdio>
#include <limits>
#include <string>

namespace {

int checks = 0;
int failures = 0;

void check(bool ok, const char *what, int line) {
    ++checks;
    if (!ok) {
        ++failures;
        std::fprintf(stderr, "pcl_adapter_test.cpp:%d: check failed: %s\n", line, what);
    }
}

#define CHECK(cond) check((cond), #cond, __LINE__)

constexpr double kPi = 3.14159265358979323846;

// Floor, two walls and a slanted roof panel, sampled on a grid with exact normals.
template <typename PointT> pcl::PointCloud<PointT> planes(const Eigen::Affine3d &pose) {
    pcl::PointCloud<PointT> cloud;
    const Eigen::Vector3d roof_normal = Eigen::Vector3d(0.3, 0.4, 1.0).normalized();
    for (int i = 0; i < 30; ++i) {
        for (int j = 0; j < 30; ++j) {
            const double u = 0.05 * i + 0.01 * std::sin(j), v = 0.05 * j + 0.01 * std::cos(i);
            const Eigen::Vector3d samples[4][2] = {
                {{u, v, 0.0}, {0.0, 0.0, 1.0}},
                {{0.0, u, v}, {1.0, 0.0, 0.0}},
                {{u, 0.0, v}, {0.0, 1.0, 0.0}},
                {{0.5 + 0.3 * u, 0.5 + 0.3 * v, 1.2 - 0.09 * u - 0.12 * v}, roof_normal},
            };
            for (const auto &sample : samples) {
                const Eigen::Vector3f p = (pose * sample[0]).cast<float>();
                const Eigen::Vector3f n = (pose.linear() * sample[1]).cast<float>();
                PointT point;
                point.x = p.x();
                point.y = p.y();
                point.z = p.z();
                if constexpr (pcl::traits::has_normal_v<PointT>) {
                    point.normal_x = n.x();
                    point.normal_y = n.y();
                    point.normal_z = n.z();
                }
                cloud.push_back(point);
            }
        }
    }
    return cloud;
}

double rotation_degrees(const Eigen::Matrix4d &a, const Eigen::Matrix4d &b) {
    const Eigen::Matrix3d relative = a.topLeftCorner<3, 3>() * b.topLeftCorner<3, 3>().transpose();
    return std::acos(std::min(1.0, std::max(-1.0, (relative.trace() - 1.0) / 2.0)) ) * 180.0 / kPi;
}

double translation_distance(const Eigen::Matrix4d &a, const Eigen::Matrix4d &b) {
    return (a.topRightCorner<3, 1>() - b.topRightCorner<3, 1>()).norm();
}

} // namespace

int main() {
    const Eigen::Affine3d truth =
        Eigen::Translation3d(0.04, -0.03, 0.02) * Eigen::AngleAxisd(0.08, Eigen::Vector3d(0.2, 0.5, 1.0).normalized());
    const pcl::PointCloud<pcl::PointXYZ> target = planes<pcl::PointXYZ>(Eigen::Affine3d::Identity());
    const pcl::PointCloud<pcl::PointXYZ> source = planes<pcl::PointXYZ>(truth.inverse());

    // Zero copy: the views are the clouds' own memory, at the point type's size.
    const sie::Points xyz = sie::xyz_view(target);
    CHECK(xyz.xyz == &target.points[0].x);
    CHECK(xyz.count == target.size());
    CHECK(xyz.stride_bytes == sizeof(pcl::PointXYZ) && xyz.stride_bytes == 16);
    const pcl::PointCloud<pcl::PointNormal> target_normals = planes<pcl::PointNormal>(Eigen::Affine3d::Identity());
    const sie::Points normals = sie::normals_view(target_normals);
    CHECK(normals.xyz == &target_normals.points[0].normal_x);
    CHECK(normals.stride_bytes == sizeof(pcl::PointNormal) && normals.stride_bytes == 48);
    CHECK(sie::xyz_view(pcl::PointCloud<pcl::PointXYZ>()).xyz == nullptr);

    // Storage order: a row-major sie::Transform and Eigen agree element by element.
    Eigen::Matrix4f asymmetric = Eigen::Matrix4f::Identity();
    asymmetric(0, 3) = 5.0f;
    asymmetric(2, 1) = -2.0f;
    const sie::Transform row_major = sie::to_transform(asymmetric);
    CHECK(row_major[3] == 5.0 && row_major[9] == -2.0 && row_major[12] == 0.0);
    CHECK(sie::to_eigen(row_major).cast<float>() == asymmetric);

    sie::Context context;
    const Eigen::Matrix4d estimated = sie::align(context, source, target);
    CHECK(rotation_degrees(estimated, truth.matrix()) < 0.05);
    CHECK(translation_distance(estimated, truth.matrix()) < 1e-3);
    CHECK(context.summary().converged);

    // Caller-supplied normals are used: the correct ones register; all-zero normals mean "no
    // normal" for every target point, so nothing can be matched.
    const Eigen::Matrix4d with_normals = sie::align_with_normals(context, source, target_normals);
    CHECK(rotation_degrees(with_normals, truth.matrix()) < 0.05);
    pcl::PointCloud<pcl::PointNormal> no_normals = target_normals;
    for (auto &p : no_normals.points) {
        p.normal_x = p.normal_y = p.normal_z = 0.0f;
    }
    bool refused = false;
    try {
        const Eigen::Matrix4d unused = sie::align_with_normals(context, source, no_normals);
        (void)unused;
    } catch (const sie::Error &error) {
        refused = true;
        std::printf("all-zero normals: %s\n", error.what());
    }
    CHECK(refused);

    // A guess in float, as PCL pipelines usually hold one.
    const Eigen::Matrix4d from_guess =
        sie::align(context, source, target, (truth * Eigen::AngleAxisd(0.02, Eigen::Vector3d::UnitZ())).matrix());
    CHECK(rotation_degrees(from_guess, truth.matrix()) < 0.05);

    // NaN points (a non-dense PCL cloud) are refused with the index, not silently used.
    pcl::PointCloud<pcl::PointXYZ> with_nan = source;
    with_nan.points[3].y = std::numeric_limits<float>::quiet_NaN();
    try {
        sie::align(context, with_nan, target);
        CHECK(false);
    } catch (const sie::Error &error) {
        CHECK(error.status() == sie::Status::NonFiniteInput);
        CHECK(error.detail().find('3') != std::string::npos);
    }
    try {
        sie::align(context, pcl::PointCloud<pcl::PointXYZ>(), target);
        CHECK(false);
    } catch (const sie::Error &error) {
        CHECK(error.status() == sie::Status::TooFewPoints);
    }

    // pcl::Registration-style use, with a PointNormal target whose normals are used.
    sie::PclRegistration<pcl::PointXYZ, pcl::PointNormal> registration;
    registration.setInputSource(pcl::PointCloud<pcl::PointXYZ>::ConstPtr(new pcl::PointCloud<pcl::PointXYZ>(source)));
    registration.setInputTarget(pcl::PointCloud<pcl::PointNormal>::ConstPtr(new pcl::PointCloud<pcl::PointNormal>(target_normals)));
    pcl::PointCloud<pcl::PointXYZ> aligned;
    registration.align(aligned);
    CHECK(registration.hasConverged());
    const Eigen::Matrix4f final_transformation = registration.getFinalTransformation();
    CHECK(rotation_degrees(final_transformation.cast<double>(), truth.matrix()) < 0.05);
    CHECK(aligned.size() == source.size());
    // The output is the source moved by the result: close to the matching target point.
    const Eigen::Vector3f moved = aligned.points[10].getVector3fMap();
    const Eigen::Vector3f expected = target.points[10].getVector3fMap();
    CHECK((moved - expected).norm() < 2e-3f);

    pcl::PointCloud<pcl::PointXYZ> never_aligned;
    sie::PclRegistration<pcl::PointXYZ, pcl::PointXYZ> unconfigured;
    try {
        unconfigured.align(never_aligned);
        CHECK(false);
    } catch (const sie::Error &error) {
        CHECK(error.status() == sie::Status::NullArgument);
    }

    std::printf("sie_pcl.hpp: %d checks, %d failed\n", checks, failures);
    return failures == 0 ? 0 : 1;
}
