// Tests of the `range_bearing` extractor and of its hand-over to the `point`
// feature type.
#include <gtest/gtest.h>

#include <Eigen/Dense>
#include <cmath>
#include <limits>
#include <numbers>
#include <optional>
#include <stdexcept>
#include <string>

#include "mspace/transform.hpp"
#include "point_feature.hpp"
#include "range_bearing.hpp"

namespace mspace::range_bearing {
namespace {

constexpr double kDeg = std::numbers::pi / 180.0;

PluginArgs extractor_args() {
  PluginArgs args;
  args.instance_name = "laser_points";
  args.params = Params::defaults(RangeBearingExtractor::param_specs());
  args.params.set("range_sigma", 0.05);
  args.params.set("bearing_sigma_deg", 1.0);
  args.params.set("elevation_sigma_deg", 2.0);
  args.params.set("min_range", 0.1);
  args.params.set("max_range", 30.0);
  return args;
}

SensorReading reading(const Eigen::MatrixXd& values, std::string channel = "laser",
                      double t = 12.5) {
  SensorReading r;
  r.channel = std::move(channel);
  r.t = t;
  r.values = values;
  return r;
}

/// The message of the std::runtime_error `extract` throws ("" if none).
std::string extract_error(RangeBearingExtractor& ex, const SensorReading& r) {
  std::vector<Measurement> out;
  try {
    ex.extract(r, out);
  } catch (const std::runtime_error& e) {
    return e.what();
  }
  return "";
}

// A planar sensor measures no elevation: its measurements have two rows.
TEST(RangeBearing, PlanarRowsAreRangeBearingWithoutElevation) {
  RangeBearingExtractor ex(extractor_args());
  Eigen::MatrixXd values(4, 2);
  values << 5.0, 0.1,  //
      0.05, 0.2,       // closer than min_range: dropped
      40.0, 0.0,       // farther than max_range: dropped
      30.0, -3.0;      // exactly max_range: kept
  std::vector<Measurement> out;
  ex.extract(reading(values), out);
  ASSERT_EQ(out.size(), 2u);
  const Eigen::Matrix2d C = Eigen::Vector2d(0.05 * 0.05, kDeg * kDeg).asDiagonal();
  EXPECT_EQ(out[0].kind, "range_bearing");
  ASSERT_EQ(out[0].v.size(), 2);
  EXPECT_TRUE(out[0].v.isApprox(Eigen::Vector2d(5.0, 0.1), 0.0));
  ASSERT_EQ(out[0].C_v.rows(), 2);
  EXPECT_TRUE(out[0].C_v.isApprox(C, 1e-15));
  EXPECT_TRUE(out[1].v.isApprox(Eigen::Vector2d(30.0, -3.0), 0.0));
  EXPECT_TRUE(out[1].C_v.isApprox(C, 1e-15));
}

TEST(RangeBearing, ThreeColumnRowsKeepTheirElevation) {
  RangeBearingExtractor ex(extractor_args());
  Eigen::MatrixXd values(2, 3);
  values << 2.0, -0.5, 0.3,  //
      7.5, 1.0, -0.2;
  std::vector<Measurement> out;
  out.push_back(Measurement{});  // extract appends
  ex.extract(reading(values), out);
  ASSERT_EQ(out.size(), 3u);
  EXPECT_EQ(out[1].kind, "range_bearing_elevation");
  EXPECT_TRUE(out[1].v.isApprox(Eigen::Vector3d(2.0, -0.5, 0.3), 0.0));
  EXPECT_TRUE(out[2].v.isApprox(Eigen::Vector3d(7.5, 1.0, -0.2), 0.0));
  EXPECT_NEAR(out[2].C_v(2, 2), 4 * kDeg * kDeg, 1e-18);
  EXPECT_EQ(out[2].C_v(0, 1), 0.0);
}

TEST(RangeBearing, EmptyReadingGivesNothing) {
  RangeBearingExtractor ex(extractor_args());
  std::vector<Measurement> out;
  ex.extract(reading(Eigen::MatrixXd(0, 2)), out);
  ex.extract(reading(Eigen::MatrixXd(0, 0)), out);
  EXPECT_TRUE(out.empty());
}

TEST(RangeBearing, WrongColumnCountNamesChannelTimeAndRow) {
  RangeBearingExtractor ex(extractor_args());
  const std::string msg =
      extract_error(ex, reading(Eigen::MatrixXd::Ones(3, 4), "front_laser", 1234.25));
  EXPECT_NE(msg.find("channel 'front_laser'"), std::string::npos) << msg;
  EXPECT_NE(msg.find("t = 1234.25 s"), std::string::npos) << msg;
  EXPECT_NE(msg.find("row 0"), std::string::npos) << msg;
  EXPECT_NE(msg.find("4 columns"), std::string::npos) << msg;
  EXPECT_NE(extract_error(ex, reading(Eigen::MatrixXd::Ones(1, 1))).find("1 columns"),
            std::string::npos);
}

TEST(RangeBearing, NonFiniteValuesNameChannelTimeAndRow) {
  RangeBearingExtractor ex(extractor_args());
  Eigen::MatrixXd values(3, 2);
  values << 5.0, 0.1,  //
      6.0, 0.2,        //
      std::numeric_limits<double>::quiet_NaN(), 0.3;
  const std::string msg = extract_error(ex, reading(values, "laser", 12.5));
  EXPECT_NE(msg.find("channel 'laser', t = 12.5 s, row 2"), std::string::npos) << msg;
  EXPECT_NE(msg.find("non-finite"), std::string::npos) << msg;
  EXPECT_NE(msg.find("nan"), std::string::npos) << msg;

  values(2, 0) = 7.0;
  values(1, 1) = std::numeric_limits<double>::infinity();
  EXPECT_NE(extract_error(ex, reading(values)).find("row 1"), std::string::npos);
}

TEST(RangeBearing, RejectsInconsistentParameters) {
  PluginArgs args = extractor_args();
  args.params.set("min_range", 5.0);
  args.params.set("max_range", 4.0);
  EXPECT_THROW(RangeBearingExtractor{args}, std::invalid_argument);
  args = extractor_args();
  args.params.set("range_sigma", 0.0);
  EXPECT_THROW(RangeBearingExtractor{args}, std::invalid_argument);
  args = extractor_args();
  args.params.set("elevation_sigma_deg", 0.0);
  EXPECT_THROW(RangeBearingExtractor{args}, std::invalid_argument);
}

/// The point feature type with its defaults (min_observations 3).
point::PointType point_type() {
  PluginArgs args;
  args.params = Params::defaults(point::PointType::param_specs());
  return point::PointType(args);
}

// A planar measurement starts a point in the scan plane that predicts it
// exactly; the point enters the map at M-space dimension 2 (x, y), its height
// outside the M-space. The planar sensor's missing elevation is not turned
// into a vertical uncertainty: z varies only with the sensor pose (none here).
TEST(RangeBearing, PlanarMeasurementsStartPointsOfDimensionTwo) {
  EXPECT_STREQ(kMeasurementKind, point::kRangeBearingElevation);
  EXPECT_STREQ(kPlanarMeasurementKind, point::kRangeBearing);
  RangeBearingExtractor ex(extractor_args());
  Eigen::MatrixXd values(1, 2);
  values << 6.0, 0.7;
  std::vector<Measurement> out;
  ex.extract(reading(values), out);
  ASSERT_EQ(out.size(), 1u);

  point::PointType type = point_type();
  SensorView view;
  view.x_ms = make_pose(2.0, -1.0, 0.4, 1.0, 0.0, 0.0);
  view.C_ms = Mat6::Zero();
  auto f = type.create(out[0], view);
  ASSERT_NE(f, nullptr);
  EXPECT_NEAR(f->coords()[2], 0.4, 1e-15);  // the height of the scan plane
  Innovation inn;
  ASSERT_TRUE(f->innovation(to_sensor_frame(f->layout(), f->coords(), view.x_ms), out[0], inn));
  ASSERT_EQ(inn.eta.size(), 2);
  EXPECT_LT(inn.eta.norm(), 1e-12);
  EXPECT_EQ(f->gating_covariance()(2, 2), 0.0);
  std::optional<Extension> ext;
  for (int k = 0; k < 3 && !ext; ++k) {
    view.t = k;
    f->add_dense_information(out[0], view);
    ext = f->extend(view);
  }
  ASSERT_TRUE(ext.has_value());
  EXPECT_EQ(ext->new_dims, 2);
  EXPECT_EQ(f->mspace_dim(), 2);
  EXPECT_NEAR(f->coords()[2], 0.4, 1e-15);
}

// 3-column rows keep working as before: a point of dimension 3.
TEST(RangeBearing, ElevationMeasurementsStartPointsOfDimensionThree) {
  RangeBearingExtractor ex(extractor_args());
  Eigen::MatrixXd values(1, 3);
  values << 6.0, 0.7, 0.2;
  std::vector<Measurement> out;
  ex.extract(reading(values), out);
  ASSERT_EQ(out.size(), 1u);
  point::PointType type = point_type();
  SensorView view;
  view.x_ms = make_pose(2.0, -1.0, 0.4, 1.0, 0.0, 0.0);
  auto f = type.create(out[0], view);
  ASSERT_NE(f, nullptr);
  Innovation inn;
  ASSERT_TRUE(f->innovation(to_sensor_frame(f->layout(), f->coords(), view.x_ms), out[0], inn));
  ASSERT_EQ(inn.eta.size(), 3);
  EXPECT_LT(inn.eta.norm(), 1e-12);
  // σz = r·σe = 6 m · 2° for a level sensor and e ≈ 0.2.
  EXPECT_NEAR(f->gating_covariance()(2, 2), std::pow(6.0 * 2.0 * kDeg * std::cos(0.2), 2) +
                                                std::pow(0.05 * std::sin(0.2), 2), 1e-12);
  std::optional<Extension> ext;
  for (int k = 0; k < 3 && !ext; ++k) {
    view.t = k;
    f->add_dense_information(out[0], view);
    ext = f->extend(view);
  }
  ASSERT_TRUE(ext.has_value());
  EXPECT_EQ(ext->new_dims, 3);
  EXPECT_EQ(f->mspace_dim(), 3);
}

}  // namespace
}  // namespace mspace::range_bearing
