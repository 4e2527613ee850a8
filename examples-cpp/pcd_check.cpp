// Reads a cloud the way PCL users do, pcl::io::loadPCDFile<pcl::PointXYZ>, and checks that it is
// SOURCE moved by T: every point within TOLERANCE of T * source point (same order). CI uses it
// on `sie register --aligned out.pcd` (T from -o) and on pcl_icp_tool's .tf.pcd (T the ground
// truth).
//
//   pcd_check CLOUD.pcd SOURCE.pcd T.txt TOLERANCE      (T: 12 or 16 numbers, row-major)
#include <pcl/io/pcd_io.h>
#include <pcl/point_types.h>

#include <Eigen/Core>

#include <cmath>
#include <cstdlib>
#include <fstream>
#include <iostream>
#include <vector>

int main(int argc, char **argv) {
    if (argc != 5) {
        std::cerr << "usage: pcd_check CLOUD.pcd SOURCE.pcd T.txt TOLERANCE\n";
        return 2;
    }
    // PCL reports a field it cannot match ("Failed to find match for field 'x'", e.g. doubles)
    // as a warning and still returns 0 with zeros in the points: the field types are checked
    // below, and the coordinates against T * source.
    pcl::PointCloud<pcl::PointXYZ> cloud, source;
    if (pcl::io::loadPCDFile<pcl::PointXYZ>(argv[1], cloud) != 0 ||
        pcl::io::loadPCDFile<pcl::PointXYZ>(argv[2], source) != 0) {
        std::cerr << "pcd_check: cannot read the clouds\n";
        return 1;
    }
    pcl::PCLPointCloud2 blob;
    pcl::io::loadPCDFile(argv[1], blob);
    for (const auto &field : blob.fields) {
        if ((field.name == "x" || field.name == "y" || field.name == "z") &&
            field.datatype != pcl::PCLPointField::FLOAT32) {
            std::cerr << "pcd_check: field " << field.name << " is not float32\n";
            return 1;
        }
    }
    std::ifstream file(argv[3]);
    std::vector<double> values;
    for (double v; file >> v;) {
        values.push_back(v);
    }
    if (values.size() != 12 && values.size() != 16) {
        std::cerr << "pcd_check: " << argv[3] << " has " << values.size() << " numbers, not 12 or 16\n";
        return 2;
    }
    Eigen::Matrix4d T = Eigen::Matrix4d::Identity();
    for (int k = 0; k < 12; ++k) {
        T(k / 4, k % 4) = values[k];
    }
    const double tolerance = std::atof(argv[4]);
    if (cloud.size() != source.size() || cloud.empty()) {
        std::cerr << "pcd_check: " << cloud.size() << " points, source has " << source.size() << "\n";
        return 1;
    }
    double worst = 0.0;
    for (std::size_t i = 0; i < cloud.size(); ++i) {
        const Eigen::Vector4d p(source[i].x, source[i].y, source[i].z, 1.0);
        const Eigen::Vector3d expected = (T * p).head<3>();
        const Eigen::Vector3d got(cloud[i].x, cloud[i].y, cloud[i].z);
        worst = std::max(worst, (expected - got).norm());
    }
    std::cout << "pcd_check: " << cloud.size() << " points read by pcl::io::loadPCDFile<pcl::PointXYZ> (float32 "
              << "x y z), largest distance to T * source " << worst << " (tolerance " << tolerance << ")\n";
    return std::isfinite(worst) && worst <= tolerance ? 0 : 1;
}
