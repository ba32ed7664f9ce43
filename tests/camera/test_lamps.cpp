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
using lamps::ThresholdMode;

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

/// Detections of one extractor on rendered frames of the route, scored
/// against the world's true lamps.
struct LampScore {
  int expected = 0;          ///< lamps whose whole disc is in view (3 px margin)
  int found = 0;             ///< of those, detected within 0.5°
  int detections = 0;
  int false_detections = 0;  ///< detections within 0.5° of no lamp
  double worst = 0.0, sum = 0.0;  ///< bearing errors of the found lamps (rad)
  double recall() const { return expected > 0 ? static_cast<double>(found) / expected : 0.0; }
  double precision() const {
    return detections > 0 ? 1.0 - static_cast<double>(false_detections) / detections : 1.0;
  }
  double mean_error() const { return found > 0 ? sum / found : 0.0; }
};

LampScore score_lamps(const CeilingWorld& world, const CeilingRenderer& renderer, LampExtractor& extractor,
                      std::size_t stride) {
  const camera::CameraModel& cam = renderer.settings().camera;
  LampScore s;
  std::uint64_t frame = 0;
  for (const Pose6& x_mr : camera_test::route_poses(stride)) {
    std::vector<Measurement> seen;
    extractor.extract_image(renderer.render(x_mr, frame++).view(), cam, seen);
    s.detections += static_cast<int>(seen.size());
    // A detection is false unless it points at some lamp (in view or partly cut off).
    for (const Measurement& m : seen) {
      const bool at_a_lamp =
          std::any_of(world.lamps().begin(), world.lamps().end(), [&](const auto& lamp) {
            return angle_between(m.v, camera_test::in_camera(lamp.centre, x_mr, cam)) <
                   0.5 * kDegree;
          });
      s.false_detections += at_a_lamp ? 0 : 1;
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
      ++s.expected;
      double best = 1.0;
      for (const Measurement& m : seen) best = std::min(best, angle_between(m.v, p));
      if (best > 0.5 * kDegree) continue;
      ++s.found;
      s.worst = std::max(s.worst, best);
      s.sum += best;
    }
  }
  return s;
}

void print_score(const char* name, const LampScore& s) {
  std::printf("lamps %-34s recall %3d/%3d = %.3f  precision %.3f (%d of %d false)  bearing error mean %.4f "
              "worst %.4f deg\n",
              name, s.found, s.expected, s.recall(), s.precision(), s.false_detections, s.detections,
              s.mean_error() / kDegree, s.worst / kDegree);
}

TEST(Lamps, FindsTheRenderedLampsWithSmallBearingErrors) {
  for (const ThresholdMode mode : {ThresholdMode::Relative, ThresholdMode::Absolute}) {
    const CeilingWorld world(1);
    const ceiling_render::RenderSettings settings{ceiling_render::default_camera()};
    const CeilingRenderer renderer(world, settings, 1);
    LampConfig config;
    config.mode = mode;
    LampExtractor extractor{config};
    const LampScore s = score_lamps(world, renderer, extractor, 5);
    print_score(mode == ThresholdMode::Relative ? "relative, default rendering" : "absolute, default rendering",
                s);
    EXPECT_GE(s.expected, 100);
    EXPECT_EQ(s.found, s.expected);
    EXPECT_LE(s.mean_error(), 0.05 * kDegree);
    EXPECT_LE(s.worst, 0.15 * kDegree);
    // Lamps cut by the image border are left out on purpose; nothing else is a lamp.
    EXPECT_EQ(s.false_detections, 0);
  }
}

// The relative detector on renderings it was not tuned on: recall and
// precision on each variant, and the bearing error of what it finds; the
// absolute threshold (the first version) on the same frames for comparison.
TEST(Lamps, RelativeDetectionSurvivesExposureNoiseVignettingAndSmallerDimmerLamps) {
  for (const camera_test::RenderVariant& variant : camera_test::render_variants()) {
    const CeilingWorld world(1, variant.appearance());
    const CeilingRenderer renderer(world, variant.settings(), 1);

    LampExtractor relative{LampConfig{}};
    const LampScore s = score_lamps(world, renderer, relative, 15);
    LampConfig absolute_config;
    absolute_config.mode = ThresholdMode::Absolute;
    LampExtractor absolute{absolute_config};
    const LampScore a = score_lamps(world, renderer, absolute, 15);
    std::printf("%s\n", variant.name);
    print_score("  relative", s);
    print_score("  absolute (245)", a);
    SCOPED_TRACE(variant.name);
    EXPECT_GE(s.expected, 40);
    EXPECT_GE(s.recall(), 0.95);
    EXPECT_EQ(s.false_detections, 0);
    // Noise σ 6 at r ≈ 5 px moves a centroid by ≈ σ_n/(contrast·√(area)) px.
    EXPECT_LE(s.mean_error(), 0.10 * kDegree);
  }
}

}  // namespace
}  // namespace mspace
