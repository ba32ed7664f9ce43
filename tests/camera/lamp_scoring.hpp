// Scoring of lamp detections against the ceiling renderer's true lamps
// (shared by the lamps tests): recall, precision and bearing errors.
#pragma once

#include <Eigen/Geometry>
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <numbers>
#include <vector>

#include "camera_test_support.hpp"
#include "lamps/lamps.hpp"

namespace mspace::camera_test {

inline constexpr double kDegree = std::numbers::pi / 180.0;
/// A detection is of a lamp when its bearing is within this angle of the lamp's centre.
inline constexpr double kMatchAngle = 0.5 * kDegree;

inline double angle_between(const Eigen::Vector3d& a, const Eigen::Vector3d& b) {
  return std::atan2(a.cross(b).norm(), a.dot(b));
}

/// Detections of one extractor on rendered frames of the route, scored
/// against the world's true lamps.
struct LampScore {
  int expected = 0;          ///< lamps wholly in view (3 px margin)
  int found = 0;             ///< of those, detected within kMatchAngle
  int detections = 0;
  int false_detections = 0;  ///< detections within kMatchAngle of no lamp
  double worst = 0.0, sum = 0.0;  ///< bearing errors of the found lamps (rad)
  double recall() const { return expected > 0 ? static_cast<double>(found) / expected : 0.0; }
  double precision() const {
    return detections > 0 ? 1.0 - static_cast<double>(false_detections) / detections : 1.0;
  }
  double mean_error() const { return found > 0 ? sum / found : 0.0; }
};

/// Scores `extractor` on every `stride`-th frame of the route. A lamp is
/// expected when the circle that holds all of it (CeilingWorld::lamp_extent,
/// 20 % larger for the lens distortion) projects inside the image with a
/// 3 px margin; lamps cut by the border are left out on purpose (the
/// detector drops them: their centres would be biased), but a detection of
/// one is not false.
inline LampScore score_lamps(const ceiling_render::CeilingWorld& world,
                             const ceiling_render::CeilingRenderer& renderer, lamps::LampExtractor& extractor,
                             std::size_t stride) {
  const camera::CameraModel& cam = renderer.settings().camera;
  LampScore s;
  std::uint64_t frame = 0;
  for (const Pose6& x_mr : route_poses(stride)) {
    std::vector<Measurement> seen;
    extractor.extract_image(renderer.render(x_mr, frame++).view(), cam, seen);
    s.detections += static_cast<int>(seen.size());
    for (const Measurement& m : seen) {
      const bool at_a_lamp = std::any_of(world.lamps().begin(), world.lamps().end(), [&](const auto& lamp) {
        return angle_between(m.v, in_camera(lamp.centre, x_mr, cam)) < kMatchAngle;
      });
      s.false_detections += at_a_lamp ? 0 : 1;

    }
    for (const ceiling_render::Lamp& lamp : world.lamps()) {
      const Eigen::Vector3d p = in_camera(lamp.centre, x_mr, cam);
      Eigen::Vector2d uv;
      const double radius_px = cam.focal() * world.lamp_extent(lamp) / p.z() * 1.2;
      if (!cam.project(p, uv) || uv.x() < radius_px + 3 || uv.y() < radius_px + 3 ||
          uv.x() > cam.width - radius_px - 4 || uv.y() > cam.height - radius_px - 4) {
        continue;
      }
      ++s.expected;
      double best = 1.0;
      for (const Measurement& m : seen) best = std::min(best, angle_between(m.v, p));
      if (best > kMatchAngle) continue;
      ++s.found;
      s.worst = std::max(s.worst, best);
      s.sum += best;
    }
  }
  return s;
}

inline void print_score(const char* name, const LampScore& s) {
  std::printf("lamps %-40s recall %3d/%3d = %.3f  precision %.3f (%d of %d false)  bearing error mean %.4f "
              "worst %.4f deg\n",
              name, s.found, s.expected, s.recall(), s.precision(), s.false_detections, s.detections,
              s.mean_error() / kDegree, s.worst / kDegree);
}

}  // namespace mspace::camera_test
