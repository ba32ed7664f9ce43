// Tests of mspace/transform.hpp: the block-wise map ↔ sensor transforms of
// T-RO eqs. 7–9, the 2-D pseudo-rotation of eq. 34 and their Jacobians (eq. 19).
#include <gtest/gtest.h>

#include <Eigen/Dense>

#include <cmath>
#include <numbers>
#include <stdexcept>

#include "maths_test_support.hpp"
#include "mspace/transform.hpp"

namespace mspace {
namespace {

using test::kJacobianTol;
using test::kRandomStates;
using test::Sampler;
using test::WorstError;
using Vec = Eigen::VectorXd;
using Mat = Eigen::MatrixXd;

constexpr double kPi = std::numbers::pi;
constexpr double kExact = 1e-12;
constexpr BlockKind P3 = BlockKind::Point3D;
constexpr BlockKind P2 = BlockKind::Point2D;
constexpr BlockKind S = BlockKind::Scalar;

/// Every tenth state has a level sensor, the rest are tilted up to 0.5 rad.
Pose6 sample_pose(Sampler& sampler, int i) { return sampler.pose(i % 10 == 0 ? 0.0 : 0.5); }

/// Half the states use fixed layouts mixing all three kinds, the rest random ones.
CoordLayout sample_layout(Sampler& sampler, int i) {
  static const CoordLayout fixed[] = {{P3, P2, S}, {P2, P2}, {S, P3, P2, P3}, {P2, S, S, P3}};
  return i % 2 == 0 ? fixed[(i / 2) % 4] : sampler.layout();
}

std::string state_of(const CoordLayout& layout, const Vec& x, const Pose6& pose) {
  return "layout " + layout.describe() + " x=" + test::describe(x) + " x_ms=" + test::describe(pose);
}

/// Eq. 34 as a construction: with Q = Rᵀ, solving the sensor-z row for the
/// line's height and substituting gives the Schur complement of Q(2,2).
Mat2 schur_rotation2d(const Pose6& x_ms) {
  const Mat3 Q = rotation(x_ms).transpose();
  return Q.topLeftCorner<2, 2>() - Q.topRightCorner<2, 1>() * Q.bottomLeftCorner<1, 2>() / Q(2, 2);
}

TEST(Rotation2d, LevelSensorGivesPlainRotation) {
  for (double theta : {0.0, 0.3, -2.0, kPi}) {
    Mat2 expected;
    expected << std::cos(theta), std::sin(theta), -std::sin(theta), std::cos(theta);
    EXPECT_LT((rotation2d(make_pose2d(4, 5, theta)) - expected).cwiseAbs().maxCoeff(), kExact);
  }
}

TEST(Rotation2d, Eq34EqualsSchurComplementOfTransposedRotation) {
  Sampler sampler(21);
  for (int i = 0; i < kRandomStates; ++i) {
    const Pose6 p = sampler.pose(1.2);
    EXPECT_LT((rotation2d(p) - schur_rotation2d(p)).cwiseAbs().maxCoeff(), 1e-11) << test::describe(p);
  }
}

// The 2-D point of a vertical line is where the line cuts the sensor's x–y
// plane. Find that height by a secant on the sensor-z of 3-D points on the
// line, then compare the 2-D transform with the 3-D one.
TEST(Rotation2d, Point2dIsVerticalLineCutBySensorPlane) {
  Sampler sampler(22);
  const CoordLayout point3d{P3}, point2d{P2};
  for (int i = 0; i < kRandomStates; ++i) {
    const Pose6 p = sample_pose(sampler, i);
    const Vec xy = sampler.vector(2);
    auto sensor_of_height = [&](double z) { return to_sensor_frame(point3d, Eigen::Vector3d(xy[0], xy[1], z), p); };
    const double z0 = sensor_of_height(0.0)[2], z1 = sensor_of_height(1.0)[2];
    const Vec on_plane = sensor_of_height(-z0 / (z1 - z0));
    EXPECT_NEAR(on_plane[2], 0.0, 1e-9);
    const Vec x_o = to_sensor_frame(point2d, xy, p);
    EXPECT_LT((x_o - on_plane.head<2>()).cwiseAbs().maxCoeff(), 1e-9) << state_of(point2d, xy, p);
  }
}

TEST(Rotation2d, DerivativesMatchCentralDifferences) {
  Sampler sampler(23);
  WorstError worst;
  for (int i = 0; i < kRandomStates; ++i) {
    const Pose6 p = sample_pose(sampler, i);
    Mat2 d[3];
    rotation2d_derivatives(p, d[0], d[1], d[2]);
    for (int k = 0; k < 3; ++k) {
      Pose6 plus = p, minus = p;
      plus[kTheta + k] += test::kStep;
      minus[kTheta + k] -= test::kStep;
      worst.update(d[k], (rotation2d(plus) - rotation2d(minus)) / (2 * test::kStep),
                   "angle " + std::to_string(k) + " at " + test::describe(p));
    }
  }
  EXPECT_LT(worst.worst(), kJacobianTol) << worst.report();
}

TEST(Rotation2d, ThrowsWhenSensorPlaneIsVertical) {
  EXPECT_THROW(rotation2d(make_pose(0, 0, 0, 0.3, kPi / 2, 0)), std::domain_error);
  EXPECT_THROW(rotation2d(make_pose(0, 0, 0, 0.3, 0, -kPi / 2)), std::domain_error);
  Mat2 a, b, c;
  EXPECT_THROW(rotation2d_derivatives(make_pose(0, 0, 0, 0, 0, kPi / 2), a, b, c), std::domain_error);
  // Only 2-D points need eq. 34; 3-D points and the inverse transform do not.
  const Pose6 rolled = make_pose(1, 2, 3, 0.3, 0.1, kPi / 2);
  EXPECT_THROW(to_sensor_frame(CoordLayout{P3, P2}, Vec::Zero(5), rolled), std::domain_error);
  EXPECT_NO_THROW(to_sensor_frame(CoordLayout{P3, S}, Vec::Zero(4), rolled));
  EXPECT_NO_THROW(to_map_frame(CoordLayout{P3, P2}, Vec::Zero(5), rolled));
}

TEST(Transform, KnownAnswer) {
  // Sensor at (1, 2, 0.5) facing +y: a point 1 m ahead is at x_o = (1, 0, 0).
  const Pose6 sensor = make_pose(1, 2, 0.5, kPi / 2, 0, 0);
  const CoordLayout layout{P3, P2, S};
  Vec x_mf(6);
  x_mf << 1, 3, 0.5, 1, 3, 0.7;
  Vec expected(6);
  expected << 1, 0, 0, 1, 0, 0.7;
  EXPECT_LT((to_sensor_frame(layout, x_mf, sensor) - expected).cwiseAbs().maxCoeff(), kExact);
  EXPECT_LT((to_map_frame(layout, expected, sensor) - x_mf).cwiseAbs().maxCoeff(), kExact);
}

TEST(Transform, RejectsWrongSize) {
  EXPECT_THROW(to_sensor_frame(CoordLayout{P3, S}, Vec::Zero(3), Pose6::Zero()), std::invalid_argument);
  EXPECT_THROW(to_map_frame(CoordLayout{P2}, Vec::Zero(3), Pose6::Zero()), std::invalid_argument);
}

TEST(Transform, ToSensorFrameJacobiansMatchCentralDifferences) {
  Sampler sampler(24);
  WorstError worst_of, worst_os;
  for (int i = 0; i < kRandomStates; ++i) {
    const CoordLayout layout = sample_layout(sampler, i);
    const Vec x_mf = sampler.vector(layout.size());
    const Pose6 x_ms = sample_pose(sampler, i);
    Mat J_of, J_os;
    to_sensor_frame(layout, x_mf, x_ms, &J_of, &J_os);
    const std::string state = state_of(layout, x_mf, x_ms);
    worst_of.update(J_of, test::numeric_jacobian([&](const Vec& x) { return to_sensor_frame(layout, x, x_ms); }, x_mf),
                    state);
    worst_os.update(J_os, test::numeric_jacobian([&](const Vec& s) { return to_sensor_frame(layout, x_mf, Pose6(s)); },
                                                 x_ms),
                    state);
  }
  EXPECT_LT(worst_of.worst(), kJacobianTol) << "J_of: " << worst_of.report();
  EXPECT_LT(worst_os.worst(), kJacobianTol) << "J_os: " << worst_os.report();
}

TEST(Transform, ToMapFrameJacobiansMatchCentralDifferences) {
  Sampler sampler(25);
  WorstError worst_fo, worst_fs;
  for (int i = 0; i < kRandomStates; ++i) {
    const CoordLayout layout = sample_layout(sampler, i);
    const Vec x_o = sampler.vector(layout.size());
    const Pose6 x_ms = sample_pose(sampler, i);
    Mat J_fo, J_fs;
    to_map_frame(layout, x_o, x_ms, &J_fo, &J_fs);
    const std::string state = state_of(layout, x_o, x_ms);
    worst_fo.update(J_fo, test::numeric_jacobian([&](const Vec& x) { return to_map_frame(layout, x, x_ms); }, x_o),
                    state);
    worst_fs.update(J_fs, test::numeric_jacobian([&](const Vec& s) { return to_map_frame(layout, x_o, Pose6(s)); }, x_ms),
                    state);
  }
  EXPECT_LT(worst_fo.worst(), kJacobianTol) << "J_fo: " << worst_fo.report();
  EXPECT_LT(worst_fs.worst(), kJacobianTol) << "J_fs: " << worst_fs.report();
}

TEST(Transform, RoundTripsAndInverseJacobians) {
  Sampler sampler(26);
  for (int i = 0; i < kRandomStates; ++i) {
    const CoordLayout layout = sample_layout(sampler, i);
    const Vec x = sampler.vector(layout.size());
    const Pose6 x_ms = sample_pose(sampler, i);
    const std::string state = state_of(layout, x, x_ms);
    Mat J_of, J_fo;
    const Vec x_o = to_sensor_frame(layout, x, x_ms, &J_of);
    EXPECT_LT((to_map_frame(layout, x_o, x_ms, &J_fo) - x).cwiseAbs().maxCoeff(), 1e-11) << state;
    EXPECT_LT((J_fo * J_of - Mat::Identity(x.size(), x.size())).cwiseAbs().maxCoeff(), 1e-11) << state;
    // x taken as sensor-frame coordinates (2-D points in the sensor plane).
    EXPECT_LT((to_sensor_frame(layout, to_map_frame(layout, x, x_ms), x_ms) - x).cwiseAbs().maxCoeff(), 1e-11)
        << state;
  }
}

}  // namespace
}  // namespace mspace
