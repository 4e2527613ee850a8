// compare_pcl: one pair of clouds registered by PCL's IterativeClosestPoint (point-to-point),
// PCL's IterativeClosestPointWithNormals (point-to-plane) and sie (SIE cost, point-to-plane,
// defaults), all from the identity, with a table of the errors against the ground truth.
//
//   compare_pcl [options] [SOURCE TARGET [GROUND_TRUTH]]
//
//   --max-distance M   PCL's maximum correspondence distance (default per pair)
//   --iterations N     PCL's iteration cap (default 100)
//   --tolerance DEG M  sie's accuracy check (default 1 deg, 5 mm)
//   --synthetic        the built-in synthetic pair even when the bunny is present
//   --csv              CSV instead of the table: one header line, then one row per method
//                      (library,method,points,threads,seconds,iterations,rotation_error_deg,
//                      translation_error_m,converged,note); everything else goes to stderr
//   --sie-threads N    sie's worker threads (default: sie's default, all cores; 0 = all cores)
//   --skip-pcl         run only sie
//   --repeats R        run each method R times and report the median time (default 1); the
//                      errors, iterations and convergence are those of the last run
//
// SOURCE and TARGET are .pcd or .ply files; GROUND_TRUTH is a text file with T_target_source
// (p_target = T * p_source) as 16 (or 12) numbers, row-major. Without files: bun0 -> bun4 from
// $SIE_DATA_DIR/pcl-test-bunny or ../shared/data/pcl-test-bunny, else a synthetic pair.
//
// PCL needs a maximum correspondence distance; sie has no such threshold. Exit status 1 only
// when sie's result misses --tolerance (never because of PCL's result), 2 on bad input.
//
// Times are wall-clock and cover everything each library needs from the loaded clouds to the
// transform: PCL's normal estimation (point-to-plane), kd-tree set-up and align(); sie's single
// call (it estimates normals and builds its trees itself). PCL's ICP and NormalEstimation are
// single-threaded; sie uses --sie-threads. The CSV's errors are those of E = inv(T_gt) * T_est:
// rotation angle in degrees and |t_E| in metres, empty without ground truth.
#include <sie_pcl.hpp>

#include <pcl/features/normal_3d.h>
#include <pcl/io/pcd_io.h>
#include <pcl/io/ply_io.h>
#include <pcl/kdtree/kdtree_flann.h>
#include <pcl/point_cloud.h>
#include <pcl/point_types.h>
#include <pcl/registration/icp.h>

#include <Eigen/Geometry>

#include <algorithm>
#include <chrono>
#include <cerrno>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <functional>
#include <optional>
#include <sstream>
#include <stdexcept>
#include <string>
#include <thread>
#include <vector>

namespace {

using CloudXYZ = pcl::PointCloud<pcl::PointXYZ>;
using CloudNormal = pcl::PointCloud<pcl::PointNormal>;
using Clock = std::chrono::steady_clock;

constexpr int kNormalNeighbours = 10; // the same k as sie's default
constexpr double kPi = 3.14159265358979323846;

struct Options {
    std::string source_path, target_path, truth_path;
    std::optional<double> max_distance; // PCL's max correspondence distance
    int iterations = 100;               // PCL's iteration cap
    double tolerance_degrees = 1.0;
    double tolerance_metres = 0.005;
    bool synthetic = false;
    bool csv = false;
    std::optional<std::uint32_t> sie_threads; // unset: sie's default (all cores)
    bool skip_pcl = false;
    int repeats = 1;
};

struct Pair {
    std::string description;
    CloudXYZ::Ptr source{new CloudXYZ}, target{new CloudXYZ};
    std::optional<Eigen::Matrix4d> truth; // T_target_source
    std::string truth_description;
    double default_max_distance = 1.0;
};

struct Row {
    std::string method;
    Eigen::Matrix4d transform = Eigen::Matrix4d::Identity();
    int iterations = 0;
    std::string stop;         // as the library reports it
    double own_rmse = 0.0;    // as the library reports it (metres)
    double milliseconds = 0.0; // the median over --repeats runs
    // For --csv:
    std::string library;     // "pcl" or "sie"
    std::string csv_method;  // "point-to-point" or "point-to-plane"
    unsigned threads = 1;
    bool converged = false;  // as the library reports it
    std::string note;        // settings, without commas
};

[[noreturn]] void usage(const char *message) {
    std::fprintf(stderr,
                 "%s\nusage: compare_pcl [--max-distance M] [--iterations N] [--tolerance DEG M] [--synthetic]\n"
                 "                   [--csv] [--sie-threads N] [--skip-pcl] [--repeats R]\n"
                 "                   [SOURCE.pcd|ply TARGET.pcd|ply [T_target_source.txt]]\n",
                 message);
    std::exit(2);
}

double parse_number(const char *text, const char *what) {
    char *end = nullptr;
    const double value = std::strtod(text, &end);
    if (end == text || *end != '\0' || !std::isfinite(value) || value <= 0.0) {
        usage((std::string("bad ") + what + ": " + text).c_str());
    }
    return value;
}

// A whole number in [minimum, maximum].
long parse_count(const char *text, const char *what, long minimum, long maximum) {
    char *end = nullptr;
    errno = 0;
    const long value = std::strtol(text, &end, 10);
    if (end == text || *end != '\0' || errno != 0 || value < minimum || value > maximum) {
        usage((std::string("bad ") + what + ": " + text).c_str());
    }
    return value;
}

Options parse_options(int argc, char **argv) {
    Options options;
    std::vector<std::string> positional;
    for (int i = 1; i < argc; ++i) {
        const std::string arg = argv[i];
        const bool has_value = i + 1 < argc;
        if (arg == "--max-distance" && has_value) {
            options.max_distance = parse_number(argv[++i], "--max-distance");
        } else if (arg == "--iterations" && has_value) {
            options.iterations = static_cast<int>(parse_number(argv[++i], "--iterations"));
        } else if (arg == "--tolerance" && i + 2 < argc) {
            options.tolerance_degrees = parse_number(argv[++i], "--tolerance degrees");
            options.tolerance_metres = parse_number(argv[++i], "--tolerance metres");
        } else if (arg == "--synthetic") {
            options.synthetic = true;
        } else if (arg == "--csv") {
            options.csv = true;
        } else if (arg == "--sie-threads" && has_value) {
            options.sie_threads = static_cast<std::uint32_t>(parse_count(argv[++i], "--sie-threads", 0, 1024));
        } else if (arg == "--skip-pcl") {
            options.skip_pcl = true;
        } else if (arg == "--repeats" && has_value) {
            options.repeats = static_cast<int>(parse_count(argv[++i], "--repeats", 1, 1000000));
        } else if (arg == "-h" || arg == "--help") {
            usage("compare_pcl: PCL ICP vs sie on one pair of clouds");
        } else if (!arg.empty() && arg[0] == '-') {
            usage(("unknown option " + arg).c_str());
        } else {
            positional.push_back(arg);
        }
    }
    if (positional.size() == 1 || positional.size() > 3) {
        usage("give SOURCE and TARGET (and optionally GROUND_TRUTH), or nothing");
    }
    if (positional.size() >= 2) {
        options.source_path = positional[0];
        options.target_path = positional[1];
    }
    if (positional.size() == 3) {
        options.truth_path = positional[2];
    }
    return options;
}

bool ends_with(const std::string &text, const std::string &suffix) {
    return text.size() >= suffix.size() && text.compare(text.size() - suffix.size(), suffix.size(), suffix) == 0;
}

bool file_exists(const std::string &path) { return std::ifstream(path).good(); }

// Loads xyz and drops non-finite points (sie rejects them; PCL would skip them).
CloudXYZ::Ptr load_cloud(const std::string &path) {
    CloudXYZ::Ptr cloud(new CloudXYZ);
    int status = -1;
    if (ends_with(path, ".pcd")) {
        status = pcl::io::loadPCDFile<pcl::PointXYZ>(path, *cloud);
    } else if (ends_with(path, ".ply")) {
        status = pcl::io::loadPLYFile<pcl::PointXYZ>(path, *cloud);
    } else {
        throw std::runtime_error(path + ": only .pcd and .ply are read");
    }
    if (status < 0 || cloud->empty()) {
        throw std::runtime_error(path + ": could not read any point");
    }
    CloudXYZ::Ptr finite(new CloudXYZ);
    finite->reserve(cloud->size());
    for (const auto &p : cloud->points) {
        if (std::isfinite(p.x) && std::isfinite(p.y) && std::isfinite(p.z)) {
            finite->push_back(p);
        }
    }
    return finite;
}

Eigen::Matrix4d load_transform(const std::string &path) {
    std::ifstream file(path);
    std::vector<double> values;
    double value = 0.0;
    while (file >> value) {
        values.push_back(value);
    }
    if (!file.eof() || (values.size() != 16 && values.size() != 12)) {
        throw std::runtime_error(path + ": expected 16 (or 12) numbers, a row-major 4x4 (or 3x4) transform");
    }
    Eigen::Matrix4d T = Eigen::Matrix4d::Identity();
    for (std::size_t i = 0; i < values.size(); ++i) {
        T(static_cast<Eigen::Index>(i / 4), static_cast<Eigen::Index>(i % 4)) = values[i];
    }
    return T;
}

// bun000 -> bun045 from the Stanford bun.conf poses (shared/data/pcl-test-bunny/README.md:
// preferred over PCL's y-only test matrix, which is 0.78 degrees away from it).
Eigen::Matrix4d bunny_truth() {
    Eigen::Matrix4d T;
    T << 0.826351, 0.004137, -0.563141, 0.036838, //
        -0.0106, 0.99991, -0.00821, -0.000257,    //
        0.563056, 0.012754, 0.82632, 0.038321,    //
        0.0, 0.0, 0.0, 1.0;
    return T;
}

// A deterministic room corner (floor, two walls, a sphere, a box) scanned twice with 3 mm
// noise, different crops and 3 % outliers; the source is seen from a moved sensor.
Pair synthetic_pair() {
    Pair pair;
    pair.description = "synthetic room corner (4000 points per cloud, 3 mm noise, 3 % outliers)";
    const Eigen::Affine3d truth = Eigen::Translation3d(0.12, -0.06, 0.05) *
                                  Eigen::AngleAxisd(10.0 * kPi / 180.0, Eigen::Vector3d(0.2, -0.3, 0.93).normalized());
    pair.truth = truth.matrix();
    pair.truth_description = "known by construction";
    pair.default_max_distance = 0.2;
    std::uint64_t state = 42;
    auto uniform = [&state](double lo, double hi) {
        state = state * 6364136223846793005ULL + 1442695040888963407ULL;
        return lo + (hi - lo) * static_cast<double>(state >> 11) / 9007199254740992.0;
    };
    auto gaussian = [&uniform](double sigma) {
        return sigma * std::sqrt(-2.0 * std::log(uniform(1e-12, 1.0))) * std::cos(2.0 * kPi * uniform(0.0, 1.0));
    };
    auto surface_point = [&]() -> Eigen::Vector3d {
        const double pick = uniform(0, 1), u = uniform(0, 2), v = uniform(0, 2);
        if (pick < 0.3) return {u, v, 0.0};
        if (pick < 0.5) return {0.0, u, 0.75 * v};
        if (pick < 0.7) return {u, 0.0, 0.75 * v};
        if (pick < 0.9) {
            const double z = uniform(0, 1), phi = uniform(0, 2 * kPi), r = std::sqrt(1 - z * z);
            return Eigen::Vector3d(1.2, 1.0, 0.3) + 0.3 * Eigen::Vector3d(r * std::cos(phi), r * std::sin(phi), z);
        }
        return {0.4 + 0.15 * u, 1.4 + 0.2 * v, 0.45};
    };
    auto scan = [&](CloudXYZ &cloud, double min_x, const Eigen::Affine3d &sensor_from_world) {
        while (cloud.size() < 4000) {
            Eigen::Vector3d p = surface_point();
            if (p.x() < min_x) continue; // the two scans overlap only partly
            if (uniform(0, 1) < 0.03) p = Eigen::Vector3d(uniform(0, 2), uniform(0, 2), uniform(0, 1.5));
            p += Eigen::Vector3d(gaussian(0.003), gaussian(0.003), gaussian(0.003));
            const Eigen::Vector3f q = (sensor_from_world * p).cast<float>();
            cloud.push_back(pcl::PointXYZ(q.x(), q.y(), q.z()));
        }
    };
    scan(*pair.target, 0.0, Eigen::Affine3d::Identity());
    scan(*pair.source, 0.25, truth.inverse());
    return pair;
}

std::string data_dir() {
    if (const char *dir = std::getenv("SIE_DATA_DIR")) {
        return dir;
    }
    return "../shared/data";
}

Pair load_pair(const Options &options) {
    Pair pair;
    if (!options.source_path.empty()) {
        pair.source = load_cloud(options.source_path);
        pair.target = load_cloud(options.target_path);
        pair.description = options.source_path + " -> " + options.target_path;
        if (!options.truth_path.empty()) {
            pair.truth = load_transform(options.truth_path);
            pair.truth_description = options.truth_path;
        }
        return pair;
    }
    const std::string bunny = data_dir() + "/pcl-test-bunny";
    if (!options.synthetic && file_exists(bunny + "/bun0.pcd") && file_exists(bunny + "/bun4.pcd")) {
        pair.source = load_cloud(bunny + "/bun0.pcd");
        pair.target = load_cloud(bunny + "/bun4.pcd");
        pair.description = bunny + "/bun0.pcd -> bun4.pcd";
        pair.truth = bunny_truth();
        pair.truth_description = "Stanford bun.conf (built in)";
        pair.default_max_distance = 0.05; // what PCL's own bun0/bun4 ICP test uses
        return pair;
    }
    return synthetic_pair();
}

// PCL keeps its iteration count protected; these expose it.
template <typename Icp> struct CountingIcp : Icp {
    int iterations() const { return this->nr_iterations_; }
};

// PCL's convergence state, named like its enum (CONVERGENCE_CRITERIA_...).
template <typename Icp> std::string pcl_state(Icp &icp) {
    using Criteria = pcl::registration::DefaultConvergenceCriteria<double>;
    const char *state = "?";
    switch (icp.getConvergeCriteria()->getConvergenceState()) {
    case Criteria::CONVERGENCE_CRITERIA_NOT_CONVERGED:
        state = "NOT_CONVERGED";
        break;
    case Criteria::CONVERGENCE_CRITERIA_ITERATIONS:
        state = "ITERATIONS";
        break;
    case Criteria::CONVERGENCE_CRITERIA_TRANSFORM:
        state = "TRANSFORM";
        break;
    case Criteria::CONVERGENCE_CRITERIA_ABS_MSE:
        state = "ABS_MSE";
        break;
    case Criteria::CONVERGENCE_CRITERIA_REL_MSE:
        state = "REL_MSE";
        break;
    case Criteria::CONVERGENCE_CRITERIA_NO_CORRESPONDENCES:
        state = "NO_CORRESPONDENCES";
        break;
    case Criteria::CONVERGENCE_CRITERIA_FAILURE_AFTER_MAX_ITERATIONS:
        state = "FAILURE_AFTER_MAX_ITERATIONS";
        break;
    }
    return state;
}

template <typename Icp> std::string pcl_stop(Icp &icp) {
    return std::string(icp.hasConverged() ? "yes" : "no") + " (" + pcl_state(icp) + ")";
}

// sie's stop reason, named like the C enum (SIE_STOP_REASON_...).
std::string sie_reason(const sie::Summary &summary) {
    const char *reason = "?";
    switch (summary.stop_reason) {
    case sie::StopReason::None:
        reason = "NONE";
        break;
    case sie::StopReason::Converged:
        reason = "CONVERGED";
        break;
    case sie::StopReason::IterationLimit:
        reason = "ITERATION_LIMIT";
        break;
    case sie::StopReason::Degenerate:
        reason = "DEGENERATE";
        break;
    case sie::StopReason::Cancelled:
        reason = "CANCELLED";
        break;
    }
    return reason;
}

// sie's converged flag and stop reason.
std::string sie_stop(const sie::Summary &summary) {
    return std::string(summary.converged ? "yes" : "no") + " (" + sie_reason(summary) + ")";
}

template <typename Icp> void configure_pcl(Icp &icp, double max_distance, int iterations) {
    icp.setMaxCorrespondenceDistance(max_distance);
    icp.setMaximumIterations(iterations);
    icp.setTransformationEpsilon(1e-8);
}

double milliseconds_since(Clock::time_point start) {
    return std::chrono::duration<double, std::milli>(Clock::now() - start).count();
}

// Cloud with PCL's normals (k nearest neighbours, oriented towards the sensor at the origin).
CloudNormal::Ptr with_normals(const CloudXYZ::Ptr &cloud) {
    pcl::NormalEstimation<pcl::PointXYZ, pcl::Normal> estimation;
    pcl::PointCloud<pcl::Normal> normals;
    estimation.setInputCloud(cloud);
    estimation.setSearchMethod(pcl::search::KdTree<pcl::PointXYZ>::Ptr(new pcl::search::KdTree<pcl::PointXYZ>));
    estimation.setKSearch(kNormalNeighbours);
    estimation.compute(normals);
    CloudNormal::Ptr out(new CloudNormal);
    pcl::concatenateFields(*cloud, normals, *out);
    return out;
}

// Quadratic-in-depth sensor noise (structured light, Khoshelham and Elberink 2012):
// sigma(d) = 1 mm + 1.425e-3 / m * d^2, with d the distance from the sensor at each cloud's origin.
struct DepthNoise {
    int calls = 0;
    std::size_t points = 0;
    double smallest = INFINITY, largest = 0.0;

    void operator()(sie::Cloud, const double *xyz, std::size_t n, double *sigma) {
        ++calls;
        points += n;
        for (std::size_t i = 0; i < n; ++i) {
            const double d2 = xyz[3 * i] * xyz[3 * i] + xyz[3 * i + 1] * xyz[3 * i + 1] + xyz[3 * i + 2] * xyz[3 * i + 2];
            sigma[i] = 1e-3 + 1.425e-3 * d2;
            smallest = std::min(smallest, sigma[i]);
            largest = std::max(largest, sigma[i]);
        }
    }
};

struct Errors {
    double degrees, metres;
};

Errors pose_error(const Eigen::Matrix4d &estimate, const Eigen::Matrix4d &truth) {
    const Eigen::Matrix3d relative = estimate.topLeftCorner<3, 3>() * truth.topLeftCorner<3, 3>().transpose();
    const double cosine = std::clamp((relative.trace() - 1.0) / 2.0, -1.0, 1.0);
    return {std::acos(cosine) * 180.0 / kPi, (estimate.topRightCorner<3, 1>() - truth.topRightCorner<3, 1>()).norm()};
}

// The same yardstick for every method: RMS distance from each transformed source point to its
// nearest target point, over the points closer than `gate`, and the fraction of such points.
struct Fit {
    double rmse, fraction;
};

Fit fit_after(const CloudXYZ &source, const pcl::KdTreeFLANN<pcl::PointXYZ> &target_tree,
              const Eigen::Matrix4d &transform, double gate) {
    const Eigen::Matrix4f T = transform.cast<float>();
    std::vector<int> index(1);
    std::vector<float> squared(1);
    double sum = 0.0;
    std::size_t inside = 0;
    for (const auto &p : source.points) {
        const Eigen::Vector4f q = T * Eigen::Vector4f(p.x, p.y, p.z, 1.0f);
        if (target_tree.nearestKSearch(pcl::PointXYZ(q.x(), q.y(), q.z()), 1, index, squared) == 1 &&
            squared[0] < gate * gate) {
            sum += squared[0];
            ++inside;
        }
    }
    return {inside ? std::sqrt(sum / static_cast<double>(inside)) : NAN,
            static_cast<double>(inside) / static_cast<double>(source.size())};
}

std::string cpu_name() {
    std::ifstream cpuinfo("/proc/cpuinfo");
    std::string line;
    while (std::getline(cpuinfo, line)) {
        if (line.rfind("model name", 0) == 0) {
            const auto colon = line.find(':');
            return colon == std::string::npos ? line : line.substr(colon + 2);
        }
    }
    return "unknown CPU";
}

// The row of a finished PCL run started at `start`; `settings` goes into the CSV note.
template <typename Icp>
Row pcl_row(Icp &icp, Clock::time_point start, const char *method, const char *csv_method, double max_distance,
            bool with_rmse, const std::string &settings) {
    Row row;
    row.milliseconds = milliseconds_since(start);
    row.method = method;
    row.transform = icp.getFinalTransformation();
    row.iterations = icp.iterations();
    row.stop = pcl_stop(icp);
    if (with_rmse) {
        row.own_rmse = std::sqrt(icp.getFitnessScore(max_distance));
    }
    row.library = "pcl";
    row.csv_method = csv_method;
    row.threads = 1; // pcl::NormalEstimation (not the OpenMP variant) and ICP: one thread
    row.converged = icp.hasConverged();
    row.note = settings + " stop=" + pcl_state(icp);
    return row;
}

// Runs `run` `repeats` times; the last run's row with the median of the runs' times.
Row median_of_runs(int repeats, const std::function<Row()> &run) {
    std::vector<double> times;
    Row row;
    for (int i = 0; i < repeats; ++i) {
        row = run();
        times.push_back(row.milliseconds);
    }
    std::sort(times.begin(), times.end());
    const std::size_t n = times.size();
    row.milliseconds = n % 2 == 1 ? times[n / 2] : 0.5 * (times[n / 2 - 1] + times[n / 2]);
    return row;
}

} // namespace

int main(int argc, char **argv) {
    const Options options = parse_options(argc, argv);
    Pair pair;
    try {
        pair = load_pair(options);
    } catch (const std::exception &error) {
        std::fprintf(stderr, "compare_pcl: %s\n", error.what());
        return 2;
    }
    const double max_distance = options.max_distance.value_or(pair.default_max_distance);
    // With --csv, stdout carries only the CSV; everything else goes to stderr.
    std::FILE *const info = options.csv ? stderr : stdout;
    const unsigned cores = std::max(1u, std::thread::hardware_concurrency());
    const unsigned sie_threads = options.sie_threads.value_or(0) > 0 ? *options.sie_threads : cores;
    const std::string repeats_note = " repeats=" + std::to_string(options.repeats);

    std::fprintf(info, "pair: %s (%zu source / %zu target points)\n", pair.description.c_str(), pair.source->size(),
                 pair.target->size());
    std::fprintf(info, "ground truth: %s\n", pair.truth ? pair.truth_description.c_str() : "none given");
    std::fprintf(info, "machine: %s, %u hardware threads; sie %s, PCL %s\n", cpu_name().c_str(),
                 std::thread::hardware_concurrency(), sie_version_string(), PCL_VERSION_PRETTY);
    if (!options.skip_pcl) {
        std::fprintf(info,
                     "PCL settings: max correspondence distance %.3g m, at most %d iterations, transformation "
                     "epsilon 1e-8, normals from k = %d neighbours (timed with the registration)\n",
                     max_distance, options.iterations, kNormalNeighbours);
    }
    const std::string sie_threads_text = options.sie_threads.value_or(0) == 0 ? "all cores"
                                         : *options.sie_threads == 1        ? "1 worker thread"
                                                                            : std::to_string(*options.sie_threads) +
                                                                                  " worker threads";
    std::fprintf(info,
                 "sie settings: defaults (SIE cost, point-to-plane, normals from k = %d, no distance threshold, "
                 "%s)\n",
                 kNormalNeighbours, sie_threads_text.c_str());
    if (options.repeats > 1) {
        std::fprintf(info, "times: median of %d runs per method (everything else from the last run)\n",
                     options.repeats);
    }
    std::fprintf(info, "\n");

    std::vector<Row> rows;
    if (!options.skip_pcl) {
        char settings[96];
        std::snprintf(settings, sizeof settings, "maxdist=%g maxiter=%d eps=1e-8", max_distance, options.iterations);
        const std::string pcl_settings = settings;
        rows.push_back(median_of_runs(options.repeats, [&] {
            CountingIcp<pcl::IterativeClosestPoint<pcl::PointXYZ, pcl::PointXYZ, double>> icp;
            configure_pcl(icp, max_distance, options.iterations);
            const auto start = Clock::now();
            icp.setInputSource(pair.source);
            icp.setInputTarget(pair.target);
            CloudXYZ aligned;
            icp.align(aligned);
            Row row = pcl_row(icp, start, "PCL ICP (point-to-point)", "point-to-point", max_distance, !options.csv,
                              pcl_settings);
            row.note += repeats_note;
            return row;
        }));
        rows.push_back(median_of_runs(options.repeats, [&] {
            CountingIcp<pcl::IterativeClosestPointWithNormals<pcl::PointNormal, pcl::PointNormal, double>> icp;
            configure_pcl(icp, max_distance, options.iterations);
            const auto start = Clock::now();
            icp.setInputSource(with_normals(pair.source));
            icp.setInputTarget(with_normals(pair.target));
            CloudNormal aligned;
            icp.align(aligned);
            Row row = pcl_row(icp, start, "PCL ICP with normals (plane)", "point-to-plane", max_distance,
                              !options.csv, pcl_settings + " k=" + std::to_string(kNormalNeighbours));
            row.note += repeats_note;
            return row;
        }));
    }

    int status = 0;
    std::optional<Errors> sie_errors;
    DepthNoise noise;
    // A fresh context per run (created outside the timing), every setting at its default but
    // the thread count when --sie-threads is given.
    const auto new_context = [&options] {
        sie::Context context;
        if (options.sie_threads) {
            context.set_threads(*options.sie_threads);
        }
        return context;
    };
    const auto sie_row = [&](const char *method, const sie::Summary &summary) {
        Row row;
        row.method = method;
        row.iterations = static_cast<int>(summary.iterations);
        row.stop = sie_stop(summary);
        row.own_rmse = summary.rmse;
        row.library = "sie";
        row.csv_method = "point-to-plane";
        row.threads = sie_threads;
        row.converged = summary.converged;
        row.note = "cost=SIE k=" + std::to_string(kNormalNeighbours) + " maxdist=none stop=" + sie_reason(summary) +
                   repeats_note;
        return row;
    };
    try {
        sie::Summary summary;
        const Row plain = median_of_runs(options.repeats, [&] {
            sie::Context context = new_context();
            const auto start = Clock::now();
            const Eigen::Matrix4d T = sie::align(context, *pair.source, *pair.target);
            const double elapsed = milliseconds_since(start);
            summary = context.summary();
            Row row = sie_row("sie SIE (point-to-plane)", summary);
            row.transform = T;
            row.milliseconds = elapsed;
            return row;
        });
        rows.push_back(plain);
        if (pair.truth) {
            sie_errors = pose_error(plain.transform, *pair.truth);
        }
        std::fprintf(info, "sie: residual sigma %.3g m, inlier fraction %.3f\n", summary.sigma[0],
                     summary.inlier_fraction);

        if (!options.csv) {
            // The same registration with per-point noise from a C++ callback. std::ref: the
            // context copies the callable, and the counters should land in `noise`.
            rows.push_back(median_of_runs(options.repeats, [&] {
                sie::Context context = new_context();
                noise = DepthNoise{};
                context.set_noise_callback(std::ref(noise));
                const auto start = Clock::now();
                const Eigen::Matrix4d T_noise = sie::align(context, *pair.source, *pair.target);
                const double elapsed = milliseconds_since(start);
                Row row = sie_row("sie SIE + depth-noise callback", context.summary());
                row.transform = T_noise;
                row.milliseconds = elapsed;
                return row;
            }));
            std::printf("noise callback: %d calls, %zu points, sigma %.3g .. %.3g m "
                        "(1 mm + 1.425e-3/m * range^2)\n",
                        noise.calls, noise.points, noise.smallest, noise.largest);
        }
    } catch (const sie::Error &error) {
        std::fprintf(stderr, "sie failed: %s\n", error.what());
        status = 1;
    }

    if (options.csv) {
        std::printf("library,method,points,threads,seconds,iterations,rotation_error_deg,translation_error_m,"
                    "converged,note\n");
        for (const Row &row : rows) {
            char rotation[32] = "", translation[32] = "";
            if (pair.truth) {
                const Errors e = pose_error(row.transform, *pair.truth);
                std::snprintf(rotation, sizeof rotation, "%.6f", e.degrees);
                std::snprintf(translation, sizeof translation, "%.6f", e.metres);
            }
            std::printf("%s,%s,%zu,%u,%.6f,%d,%s,%s,%s,%s\n", row.library.c_str(), row.csv_method.c_str(),
                        pair.source->size(), row.threads, row.milliseconds * 1e-3, row.iterations, rotation,
                        translation, row.converged ? "true" : "false", row.note.c_str());
        }
        std::fflush(stdout);
    } else {
        pcl::KdTreeFLANN<pcl::PointXYZ> target_tree;
        target_tree.setInputCloud(pair.target);
        std::printf("\n%-31s %9s %10s %9s %17s %5s  %-27s %9s\n", "method", "rot [deg]", "trans [mm]", "RMSE [mm]",
                    "NN RMSE [mm]", "iters", "converged (as reported)", "time [ms]");
        for (const Row &row : rows) {
            const Fit fit = fit_after(*pair.source, target_tree, row.transform, max_distance);
            char rotation[32] = "-", translation[32] = "-", nn[48];
            if (pair.truth) {
                const Errors e = pose_error(row.transform, *pair.truth);
                std::snprintf(rotation, sizeof rotation, "%.3f", e.degrees);
                std::snprintf(translation, sizeof translation, "%.2f", e.metres * 1e3);
            }
            std::snprintf(nn, sizeof nn, "%.2f (%.1f%%)", fit.rmse * 1e3, 100.0 * fit.fraction);
            std::printf("%-31s %9s %10s %9.2f %17s %5d  %-27s %9.1f\n", row.method.c_str(), rotation, translation,
                        row.own_rmse * 1e3, nn, row.iterations, row.stop.c_str(), row.milliseconds);
        }
        std::printf("RMSE: as each library reports it (PCL: sqrt of getFitnessScore(%.3g m), point-to-point nearest "
                    "neighbours; sie: inlier-probability-weighted point-to-plane RMSE).\n"
                    "NN RMSE: one yardstick for every row, nearest-neighbour distance from the aligned source to the "
                    "target over the source points closer than %.3g m (their share in brackets).\n",
                    max_distance, max_distance);
    }

    if (status == 0 && sie_errors) {
        const bool pass = sie_errors->degrees <= options.tolerance_degrees &&
                          sie_errors->metres <= options.tolerance_metres;
        std::fprintf(info,
                     "\ncheck: sie SIE within %.3g deg and %.3g mm of the ground truth: %.3f deg, %.2f mm -> %s\n",
                     options.tolerance_degrees, options.tolerance_metres * 1e3, sie_errors->degrees,
                     sie_errors->metres * 1e3, pass ? "PASS" : "FAIL");
        status = pass ? 0 : 1;
    }
    return status;
}
