// pole_scene.cpp — see pole_scene.hpp.
#include "pole_scene.hpp"

#include <cmath>
#include <numbers>
#include <random>

namespace mspace::laser_poles {
namespace {

constexpr double kDegree = std::numbers::pi / 180.0;
constexpr double kSector = 40.0 * kDegree;

}  // namespace

std::vector<Trunk> sample_trunks(std::uint64_t seed) {
  std::mt19937_64 rng(seed);
  auto uniform = [&rng](double lo, double hi) { return std::uniform_real_distribution<double>(lo, hi)(rng); };
  std::vector<Trunk> out;
  for (int sector = 0; sector < 4; ++sector) {
    const bool present = uniform(0, 1) < 0.6 || (sector == 3 && out.empty());
    const double range = uniform(3, 10), diameter = uniform(0.3, 1.0);
    // Centre within ±10° of the sector's middle: a trunk's half-width is at
    // most asin(0.5 / 3) ≈ 9.6°, so neighbouring silhouettes stay apart.
    const double bearing = -80.0 * kDegree + (sector + 0.5) * kSector + uniform(-10, 10) * kDegree;
    if (present) out.push_back({range, bearing, diameter});
  }
  return out;
}

Pose6 sample_planar_pose(std::uint64_t seed) {
  std::mt19937_64 rng(seed ^ 0x9e3779b97f4a7c15ULL);
  auto uniform = [&rng](double lo, double hi) { return std::uniform_real_distribution<double>(lo, hi)(rng); };
  return make_pose2d(uniform(-50, 50), uniform(-50, 50), uniform(-std::numbers::pi, std::numbers::pi));
}

TrueShape trunk_shape(const Trunk& trunk, const Pose6& x_ms) {
  const double heading = x_ms[kTheta] + trunk.bearing;
  TrueShape shape;
  shape.kind = TrueShape::Kind::VerticalCylinder;
  shape.a = Eigen::Vector3d(x_ms[kX] + trunk.range * std::cos(heading), x_ms[kY] + trunk.range * std::sin(heading),
                            x_ms[kZ]);
  shape.radius = 0.5 * trunk.diameter;
  return shape;
}

}  // namespace mspace::laser_poles
