// A pcl_icp-style tool (PCL's tools/icp.cpp workflow, written here with the same API calls):
// registers each cloud onto the one before it, accumulates the transforms into the first
// cloud's frame, prints each pairwise transform and saves <file>.tf.pcd (binary) with the cloud
// moved into the first cloud's frame. The registration is held through a
// pcl::IterativeClosestPoint<PointType, PointType>, configured as pcl_icp configures it.
//
//   pcl_icp_tool [-i ITERATIONS] [-d MAX_DISTANCE] [-r RANSAC_THRESHOLD] a.pcd b.pcd [c.pcd ...]
//
// examples-cpp/CMakeLists.txt builds it as `pcl_icp_tool_sie` with only the type name changed
// to sie::PclRegistration; CI runs it on bun4 <- bun0 and loads the .tf.pcd with PCL.
#include <pcl/common/transforms.h>
#include <pcl/io/pcd_io.h>
#include <pcl/point_types.h>
#include <pcl/registration/icp.h>

#include <cstdlib>
#include <iostream>
#include <string>
#include <vector>

using PointType = pcl::PointXYZ;
using Cloud = pcl::PointCloud<PointType>;

int main(int argc, char **argv) {
    int iterations = 50;        // pcl_icp's defaults
    double distance = 5.0;
    double ransac = -1.0;       // -1: same as the distance
    std::vector<std::string> files;
    for (int a = 1; a < argc; ++a) {
        const std::string arg = argv[a];
        if ((arg == "-i" || arg == "-d" || arg == "-r") && a + 1 < argc) {
            const double value = std::atof(argv[++a]);
            if (arg == "-i") {
                iterations = static_cast<int>(value);
            } else if (arg == "-d") {
                distance = value;
            } else {
                ransac = value;
            }
        } else {
            files.push_back(arg);
        }
    }
    if (files.size() < 2) {
        std::cerr << "usage: " << argv[0] << " [-i iterations] [-d distance] [-r ransac] a.pcd b.pcd [...]\n";
        return 2;
    }
    if (ransac < 0) {
        ransac = distance;
    }

    pcl::IterativeClosestPoint<PointType, PointType>::Ptr icp(new pcl::IterativeClosestPoint<PointType, PointType>);
    icp->setMaximumIterations(iterations);
    icp->setMaxCorrespondenceDistance(distance);
    icp->setRANSACOutlierRejectionThreshold(ransac);

    Cloud::Ptr model(new Cloud);
    if (pcl::io::loadPCDFile(files[0], *model) < 0) {
        std::cerr << "cannot read " << files[0] << "\n";
        return 2;
    }
    icp->setInputTarget(model);

    Eigen::Matrix4f t = Eigen::Matrix4f::Identity();
    int failed = 0;
    for (std::size_t i = 1; i < files.size(); ++i) {
        Cloud::Ptr data(new Cloud);
        if (pcl::io::loadPCDFile(files[i], *data) < 0) {
            std::cerr << "cannot read " << files[i] << "\n";
            return 2;
        }
        icp->setInputSource(data);
        Cloud::Ptr tmp(new Cloud);
        icp->align(*tmp);
        if (!icp->hasConverged()) {
            std::cerr << files[i] << ": ICP did not converge\n";
            ++failed;
        }
        t = t * icp->getFinalTransformation();
        pcl::transformPointCloud(*data, *tmp, t);
        std::cout << files[i] << " -> " << files[i - 1] << " (fitness " << icp->getFitnessScore() << "):\n"
                  << icp->getFinalTransformation() << "\n";

        // The next cloud is registered onto this one, in its own frame.
        *model = *data;
        icp->setInputTarget(model);

        const std::string out = files[i].substr(0, files[i].rfind('.')) + ".tf.pcd";
        pcl::io::savePCDFileBinary(out, *tmp);
        std::cout << "saved " << out << "\n";
    }
    return failed == 0 ? 0 : 1;
}
