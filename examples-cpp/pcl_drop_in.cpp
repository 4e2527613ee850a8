// The README's "drop sie into a PCL pipeline" snippets, compiled and run by CI so they stay true.
//   pcl_drop_in SOURCE.pcd TARGET.pcd
#include <sie_pcl.hpp> // sie.hpp plus the PCL/Eigen adapter

#include <pcl/common/transforms.h>
#include <pcl/io/pcd_io.h>

#include <iostream>

int main(int argc, char **argv) {
    if (argc != 3) {
        std::cerr << "usage: pcl_drop_in SOURCE.pcd TARGET.pcd\n";
        return 2;
    }
    pcl::PointCloud<pcl::PointXYZ>::Ptr source(new pcl::PointCloud<pcl::PointXYZ>);
    pcl::PointCloud<pcl::PointXYZ>::Ptr target(new pcl::PointCloud<pcl::PointXYZ>);
    if (pcl::io::loadPCDFile(argv[1], *source) < 0 || pcl::io::loadPCDFile(argv[2], *target) < 0) {
        return 2;
    }

    // --- README snippet 1: a function call on the clouds (read in place, not copied) ---
    sie::Context sie_ctx;                                       // SIE cost, point-to-plane, no threshold
    Eigen::Matrix4d T = sie::align(sie_ctx, *source, *target);  // T_target_source
    pcl::PointCloud<pcl::PointXYZ> aligned;
    pcl::transformPointCloud(*source, aligned, T);
    const sie::Summary s = sie_ctx.summary();
    std::cout << s.iterations << " iterations, " << sie::to_string(s.stop_reason) << ", inlier sigma "
              << s.sigma[0] << " m\n";

    // --- README snippet 2: in place of pcl::IterativeClosestPoint<pcl::PointXYZ, pcl::PointXYZ> ---
    sie::PclRegistration<pcl::PointXYZ, pcl::PointXYZ> icp;     // no setMaxCorrespondenceDistance
    icp.setInputSource(source);
    icp.setInputTarget(target);
    icp.align(aligned);
    const Eigen::Matrix4f T_icp = icp.getFinalTransformation();

    std::cout << "same result: " << (T_icp.cast<double>() - T).cwiseAbs().maxCoeff() << "\n";
    return s.converged && icp.hasConverged() && (T_icp.cast<double>() - T).cwiseAbs().maxCoeff() < 1e-5 ? 0 : 1;
}
