// Tests of the lamps extractor: bearing covariance, and detection rate, false
// detections and bearing errors on rendered images of known lamps.
#include "lamps/lamps.hpp"

#include <gtest/gtest.h>

#include <Eigen/Geometry>
#include <algorithm>
#include <cmath>
#include <numbers>

#include "camera_test_support.hpp"

namespace mspace {
namespace {

using ceiling_render::CeilingRenderer;
using ceiling_render::CeilingWorld;
using lamps::LampConfig;
using lamps::LampExtractor;

constexpr double kDegree = std::numbers::pi / 180.0;

double angle_between(const Eigen::Vector3d& a, const Eigen::Vector3d& b) {
  return std::atan2(a.cross(b).norm(), a.dot(b));
}

TEST(Lamps, BearingCovarianceIsTheProjectedPixelNoise) {
  const camera::CameraModel cam = ceiling_render::default_camera();
  // At the principal point undistortion is the identity to first order (the
  // tangential terms are second order) and b = (0, 0, 1): C = σ²/f² on x, y.
  const Measurement m = lamps::bearing_measurement({159.5, 119.5}, cam, 0.5);
  EXPECT_EQ(m.kind, "bearing3d");
  EXPECT_NEAR((m.v - Eigen::Vector3d(0, 0, 1)).norm(), 0.0, 1e-12);
  const double var = 0.25 / (260.0 * 260.0);
  EXPECT_NEAR(m.C_v(0, 0), var, 1e-4 * var);
  EXPECT_NEAR(m.C_v(1, 1), var, 1e-4 * var);
  EXPECT_NEAR(m.C_v(2, 2), 0.0, 1e-18);
  // Off-centre: still no variance along b (b stays a unit vector).
  const Measurement off = lamps::bearing_measurement({40.0, 200.0}, cam, 0.5);
  EXPECT_NEAR(off.v.norm(), 1.0, 1e-15);
  EXPECT_NEAR((off.C_v * off.v).norm(), 0.0, 1e-18);
  EXPECT_NEAR((off.C_v - off.C_v.transpose()).norm(), 0.0, 1e-18);
}

TEST(Lamps, FindsTheRenderedLampsWithSmallBearingErrors) {
  const CeilingWorld world(1);
  const ceiling_render::RenderSettings settings{ceiling_render::default_camera()};
  const CeilingRenderer renderer(world, settings, 1);
  const camera::CameraModel& cam = settings.camera;
  LampExtractor extractor{LampConfig{}};

  int expected = 0, found = 0, detections = 0, false_detections = 0;
  double worst = 0.0, sum = 0.0;
  std::uint64_t frame = 0;
  for (const Pose6& x_mr : camera_test::route_poses(5)) {
    std::vector<Measurement> seen;
    extractor.extract_image(renderer.render(x_mr, frame++).view(), cam, seen);
    detections += static_cast<int>(seen.size());
    // A detection is false unless it points at some lamp (in view or partly cut off).
    for (const Measurement& m : seen) {
      const bool at_a_lamp =
          std::any_of(world.lamps().begin(), world.lamps().end(), [&](const auto& lamp) {
            return angle_between(m.v, camera_test::in_camera(lamp.centre, x_mr, cam)) <
                   0.5 * kDegree;
          });
      false_detections += at_a_lamp ? 0 : 1;
    }
    for (const ceiling_render::Lamp& lamp : world.lamps()) {
      const Eigen::Vector3d p = camera_test::in_camera(lamp.centre, x_mr, cam);
      Eigen::Vector2d uv;
      // Expected: the whole disc is in view with a 3 px margin.
      const double radius_px = cam.focal() * lamp.radius / p.z() * 1.2;
      if (!cam.project(p, uv) || uv.x() < radius_px + 3 || uv.y() < radius_px + 3 ||
          uv.x() > cam.width - radius_px - 4 || uv.y() > cam.height - radius_px - 4) {
        continue;
      }
      ++expected;
      double best = 1.0;
      for (const Measurement& m : seen) best = std::min(best, angle_between(m.v, p));
      if (best > 0.5 * kDegree) continue;
      ++found;
      worst = std::max(worst, best);
      sum += best;
    }
  }
  std::printf("lamps: %d of %d lamps fully in view found, mean / worst bearing error %.4f / "
              "%.4f deg, %d of %d detections point at no lamp\n",
              found, expected, sum / found / kDegree, worst / kDegree, false_detections,
              detections);
  EXPECT_GE(expected, 100);
  EXPECT_EQ(found, expected);
  EXPECT_LE(sum / found, 0.05 * kDegree);
  EXPECT_LE(worst, 0.15 * kDegree);
  // Lamps cut by the image border are left out on purpose; nothing else is a lamp.
  EXPECT_EQ(false_detections, 0);
}

}  // namespace
}  // namespace mspace
