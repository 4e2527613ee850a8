// Deterministic synthetic data for the C++ tests: a scanned room corner with a sphere and a
// box (well-constrained for point-to-plane ICP), and rigid-transform helpers.
#ifndef SIE_TEST_SCENE_HPP
#define SIE_TEST_SCENE_HPP

#include <array>
#include <cmath>
#include <cstdint>
#include <vector>

namespace scene {

using Point = std::array<double, 3>;
using Matrix = std::array<double, 16>; // row-major rigid transform

// A fixed linear congruential generator: the same numbers on every platform and run.
class Random {
  public:
    explicit Random(std::uint64_t seed) : state_(seed * 2862933555777941757ULL + 3037000493ULL) {}
    double uniform(double lo, double hi) {
        state_ = state_ * 6364136223846793005ULL + 1442695040888963407ULL;
        return lo + (hi - lo) * static_cast<double>(state_ >> 11) / 9007199254740992.0;
    }
    double gaussian(double sigma) {
        const double u1 = uniform(1e-12, 1.0);
        const double u2 = uniform(0.0, 1.0);
        return sigma * std::sqrt(-2.0 * std::log(u1)) * std::cos(6.283185307179586 * u2);
    }

  private:
    std::uint64_t state_;
};

// Rotation by `angle` about the unit-normalised `axis` (Rodrigues), then translation.
inline Matrix rigid(double angle, Point axis, Point translation) {
    const double n = std::sqrt(axis[0] * axis[0] + axis[1] * axis[1] + axis[2] * axis[2]);
    const double x = axis[0] / n, y = axis[1] / n, z = axis[2] / n;
    const double c = std::cos(angle), s = std::sin(angle), C = 1.0 - c;
    return {c + x * x * C,     x * y * C - z * s, x * z * C + y * s, translation[0],
            y * x * C + z * s, c + y * y * C,     y * z * C - x * s, translation[1],
            z * x * C - y * s, z * y * C + x * s, c + z * z * C,     translation[2],
            0.0,               0.0,               0.0,               1.0};
}

inline Point apply(const Matrix &T, const Point &p) {
    return {T[0] * p[0] + T[1] * p[1] + T[2] * p[2] + T[3], T[4] * p[0] + T[5] * p[1] + T[6] * p[2] + T[7],
            T[8] * p[0] + T[9] * p[1] + T[10] * p[2] + T[11]};
}

inline Matrix inverse(const Matrix &T) {
    Matrix inv{};
    for (int r = 0; r < 3; ++r) {
        for (int c = 0; c < 3; ++c) {
            inv[4 * r + c] = T[4 * c + r];
        }
        inv[4 * r + 3] = -(T[r] * T[3] + T[4 + r] * T[7] + T[8 + r] * T[11]);
    }
    inv[15] = 1.0;
    return inv;
}

// Rotation angle (degrees) and translation distance between two rigid transforms.
struct PoseError {
    double rotation_degrees;
    double translation;
};

inline PoseError pose_error(const Matrix &estimate, const Matrix &truth) {
    // trace(R_estimate^T R_truth) = 1 + 2 cos(angle)
    double trace = 0.0;
    for (int r = 0; r < 3; ++r) {
        for (int c = 0; c < 3; ++c) {
            trace += estimate[4 * r + c] * truth[4 * r + c];
        }
    }
    const double cosine = std::fmax(-1.0, std::fmin(1.0, (trace - 1.0) / 2.0));
    const double dx = estimate[3] - truth[3], dy = estimate[7] - truth[7], dz = estimate[11] - truth[11];
    return {std::acos(cosine) * 57.29577951308232, std::sqrt(dx * dx + dy * dy + dz * dz)};
}

struct Surfel {
    Point position;
    Point normal;
};

// One scan of the room corner: floor, two walls, a sphere and a box top, each point with its
// exact surface normal; Gaussian noise of `noise` per coordinate.
inline std::vector<Surfel> room_corner(std::size_t count, double noise, std::uint64_t seed) {
    Random random(seed);
    std::vector<Surfel> points;
    points.reserve(count);
    for (std::size_t i = 0; i < count; ++i) {
        Surfel s{};
        const double pick = random.uniform(0.0, 1.0);
        const double u = random.uniform(0.0, 2.0), v = random.uniform(0.0, 2.0);
        if (pick < 0.3) {
            s = {{u, v, 0.0}, {0.0, 0.0, 1.0}}; // floor
        } else if (pick < 0.5) {
            s = {{0.0, u, v * 0.75}, {1.0, 0.0, 0.0}}; // wall x = 0
        } else if (pick < 0.7) {
            s = {{u, 0.0, v * 0.75}, {0.0, 1.0, 0.0}}; // wall y = 0
        } else if (pick < 0.9) {
            // sphere of radius 0.3 at (1.2, 1.0, 0.3), upper half
            const double z = random.uniform(0.0, 1.0);
            const double phi = random.uniform(0.0, 6.283185307179586);
            const double r = std::sqrt(1.0 - z * z);
            const Point n{r * std::cos(phi), r * std::sin(phi), z};
            s = {{1.2 + 0.3 * n[0], 1.0 + 0.3 * n[1], 0.3 + 0.3 * n[2]}, n};
        } else {
            s = {{0.4 + 0.3 * u / 2.0, 1.4 + 0.4 * v / 2.0, 0.45}, {0.0, 0.0, 1.0}}; // box top
        }
        for (double &c : s.position) {
            c += random.gaussian(noise);
        }
        points.push_back(s);
    }
    return points;
}

} // namespace scene

#endif
