// Tests of the lamps extractor: bearing covariance, and detection rate, false
// detections and bearing errors on rendered images of known lamps.
#include "lamps/lamps.hpp"

#include <gtest/gtest.h>

#include <Eigen/Geometry>
#include <algorithm>
#include <cmath>
#include <numbers>

#include "lamp_scoring.hpp"

namespace mspace {
namespace {

using ceiling_render::CeilingRenderer;
using ceiling_render::CeilingWorld;
using lamps::LampConfig;
using lamps::LampExtractor;
using lamps::ThresholdMode;

using camera_test::kDegree;
using camera_test::LampScore;
using camera_test::print_score;
using camera_test::score_lamps;

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
