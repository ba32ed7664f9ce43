// Tests of camera_model.hpp: distortion round trip, projection, the reading row.
#include "image_sequence/camera_model.hpp"

#include <gtest/gtest.h>

#include "ceiling_render/ceiling_renderer.hpp"

namespace mspace {
namespace {

TEST(CameraModel, UndistortInvertsDistortAcrossTheImage) {
  const camera::CameraModel c = ceiling_render::default_camera();
  for (double u = 0; u <= 319; u += 31.9) {
    for (double v = 0; v <= 239; v += 23.9) {
      const Eigen::Vector2d uv(u, v);
      const Eigen::Vector2d back = c.pixel_from_normalised(c.normalised_from_pixel(uv));
      EXPECT_NEAR((back - uv).norm(), 0.0, 1e-9) << u << ", " << v;
    }
  }
}

TEST(CameraModel, DistortionMatchesOpenCvFormulaAtAKnownPoint) {
  camera::CameraModel c;
  c.distortion = {-0.2, 0.05, 0.001, -0.002, 0.01};
  // x = 0.3, y = -0.2: r² = 0.13, radial = 1 - 0.026 + 0.000845 + 0.00002197.
  const Eigen::Vector2d d = c.distort({0.3, -0.2});
  const double radial = 1.0 - 0.2 * 0.13 + 0.05 * 0.13 * 0.13 + 0.01 * 0.13 * 0.13 * 0.13;
  EXPECT_NEAR(d.x(), 0.3 * radial + 2 * 0.001 * 0.3 * -0.2 + -0.002 * (0.13 + 2 * 0.09), 1e-15);
  EXPECT_NEAR(d.y(), -0.2 * radial + 0.001 * (0.13 + 2 * 0.04) + 2 * -0.002 * 0.3 * -0.2, 1e-15);
}

TEST(CameraModel, ProjectsThePrincipalRayToThePrincipalPoint) {
  const camera::CameraModel c = ceiling_render::default_camera();
  Eigen::Vector2d uv;
  ASSERT_TRUE(c.project({0.0, 0.0, 2.0}, uv));
  EXPECT_NEAR(uv.x(), 159.5, 1e-12);
  EXPECT_NEAR(uv.y(), 119.5, 1e-12);
  EXPECT_FALSE(c.project({0.0, 0.0, -1.0}, uv));
}

TEST(CameraModel, ReadingRowRoundTrips) {
  const camera::CameraModel c = ceiling_render::default_camera();
  SensorReading r;
  r.values = camera::reading_row(c);
  const camera::CameraModel back = camera::camera_from_reading(r);
  EXPECT_EQ(back.width, 320);
  EXPECT_EQ(back.height, 240);
  EXPECT_EQ(back.fx, c.fx);
  EXPECT_EQ(back.cy, c.cy);
  EXPECT_EQ(back.distortion, c.distortion);
  r.values = Eigen::MatrixXd::Zero(2, 3);
  r.channel = "cam";
  EXPECT_THROW(camera::camera_from_reading(r), std::runtime_error);
}

}  // namespace
}  // namespace mspace
