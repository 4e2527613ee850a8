// PCL's ICP tutorial program ("How to use iterative closest point", iterative_closest_point.cpp),
// written again here with the same API calls: five random points, the same points shifted by
// 0.7 along x, one pcl::IterativeClosestPoint, then the convergence flag, the fitness score and
// the final transformation.
//
// examples-cpp/CMakeLists.txt builds it as `pcl_tutorial_icp_sie` with one change, the type
// name pcl::IterativeClosestPoint -> sie::PclRegistration (and sie_pcl.hpp included), and CI
// checks what it prints: converged, score ~0, x translation 0.7.
#include <iostream>
#include <pcl/io/pcd_io.h>
#include <pcl/point_types.h>
#include <pcl/registration/icp.h>

int main() {
    pcl::PointCloud<pcl::PointXYZ>::Ptr cloud_in(new pcl::PointCloud<pcl::PointXYZ>(5, 1));
    pcl::PointCloud<pcl::PointXYZ>::Ptr cloud_out(new pcl::PointCloud<pcl::PointXYZ>);

    // Five points anywhere in a 1024-unit cube.
    for (auto &point : *cloud_in) {
        point.x = 1024.0f * rand() / (RAND_MAX + 1.0f);
        point.y = 1024.0f * rand() / (RAND_MAX + 1.0f);
        point.z = 1024.0f * rand() / (RAND_MAX + 1.0f);
    }
    std::cout << "Saved " << cloud_in->size() << " data points to input:\n";
    for (const auto &point : *cloud_in) {
        std::cout << point << "\n";
    }

    // The same points moved by 0.7 along x.
    *cloud_out = *cloud_in;
    std::cout << "size:" << cloud_out->size() << "\n";
    for (auto &point : *cloud_out) {
        point.x += 0.7f;
    }
    std::cout << "Transformed " << cloud_in->size() << " data points:\n";
    for (const auto &point : *cloud_out) {
        std::cout << point << "\n";
    }

    pcl::IterativeClosestPoint<pcl::PointXYZ, pcl::PointXYZ> icp;
    icp.setInputSource(cloud_in);
    icp.setInputTarget(cloud_out);

    pcl::PointCloud<pcl::PointXYZ> Final;
    icp.align(Final);

    std::cout << "has converged:" << icp.hasConverged() << " score: " << icp.getFitnessScore() << "\n";
    std::cout << icp.getFinalTransformation() << "\n";
    return 0;
}
