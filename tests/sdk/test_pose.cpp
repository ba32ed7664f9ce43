// Tests of mspace/pose.hpp: rotations and Euler angles, the compound
// operators of T-RO eqs. 17–18 and their analytic Jacobians (eq. 20).
#include <gtest/gtest.h>

#include <Eigen/Geometry>

#include <cmath>
#include <cstring>
#include <limits>
#include <numbers>
#include <random>
#include <stdexcept>
#include <vector>

#include "maths_test_support.hpp"
#include "mspace/pose.hpp"

namespace mspace {
namespace {

using test::kJacobianTol;
using test::kRandomStates;
using test::Sampler;
using test::WorstError;

constexpr double kPi = std::numbers::pi;
constexpr double kExact = 1e-12;  // for results that are exact up to rounding

/// Every tenth state is planar (φ = ψ = 0), the rest are tilted.
Pose6 sample_pose(Sampler& sampler, int i) { return sampler.pose(i % 10 == 0 ? 0.0 : 0.5); }

Mat3 rotation_by_axes(double theta, double phi, double psi) {
  return (Eigen::AngleAxisd(theta, Vec3::UnitZ()) * Eigen::AngleAxisd(phi, Vec3::UnitY()) *
          Eigen::AngleAxisd(psi, Vec3::UnitX()))
      .toRotationMatrix();
}

Mat3 skew(const Vec3& v) {
  Mat3 S;
  S << 0, -v.z(), v.y(), v.z(), 0, -v.x(), -v.y(), v.x(), 0;
  return S;
}

TEST(Pose, MakePoseOrdersComponents) {
  const Pose6 p = make_pose(1, 2, 3, 0.4, 0.5, 0.6);
  EXPECT_EQ(p[kX], 1.0);
  EXPECT_EQ(p[kY], 2.0);
  EXPECT_EQ(p[kZ], 3.0);
  EXPECT_EQ(p[kTheta], 0.4);
  EXPECT_EQ(p[kPhi], 0.5);
  EXPECT_EQ(p[kPsi], 0.6);
  EXPECT_TRUE(make_pose2d(1, 2, 0.3).isApprox(make_pose(1, 2, 0, 0.3, 0, 0)));
}

TEST(Pose, RotationIsRzRyRx) {
  Sampler sampler(11);
  for (int i = 0; i < kRandomStates; ++i) {
    const Pose6 p = sampler.pose(1.5);
    EXPECT_LT((rotation(p) - rotation_by_axes(p[kTheta], p[kPhi], p[kPsi])).cwiseAbs().maxCoeff(), kExact);
  }
  // Yaw by 90°: the frame's x axis points along the parent's y axis.
  EXPECT_TRUE((rotation(make_pose2d(0, 0, kPi / 2)) * Vec3::UnitX()).isApprox(Vec3::UnitY()));
  // Pitch by +90°: x axis points down; roll by +90°: y axis points up.
  EXPECT_TRUE((rotation(make_pose(0, 0, 0, 0, kPi / 2, 0)) * Vec3::UnitX()).isApprox(-Vec3::UnitZ()));
  EXPECT_TRUE((rotation(make_pose(0, 0, 0, 0, 0, kPi / 2)) * Vec3::UnitY()).isApprox(Vec3::UnitZ()));
}

TEST(Pose, WrapAngleIsTheRemainderBitForBit) {
  // wrap_angle returns angles in (−π, π] unchanged without calling
  // std::remainder: the same bits as the remainder formula everywhere.
  const auto by_remainder = [](double a) {
    double w = std::remainder(a, 2.0 * kPi);
    if (w <= -kPi) w += 2.0 * kPi;
    return w;
  };
  std::vector<double> angles = {0.0, -0.0, kPi, -kPi, 2 * kPi, -2 * kPi, 1e-300, -1e-300, 3.0, -3.0, 7.0, -7.0,
                                1e6, -1e6};
  for (double a : {kPi, -kPi, 2 * kPi, 3 * kPi}) {
    angles.push_back(std::nextafter(a, 0.0));
    angles.push_back(std::nextafter(a, 10.0 * a));
    angles.push_back(-std::nextafter(a, 0.0));
    angles.push_back(-std::nextafter(a, 10.0 * a));
  }
  std::mt19937 rng(3);
  std::uniform_real_distribution<double> u(-20.0, 20.0);
  for (int i = 0; i < 100000; ++i) angles.push_back(u(rng));
  for (double a : angles) {
    const double w = wrap_angle(a), r = by_remainder(a);
    EXPECT_EQ(std::memcmp(&w, &r, sizeof(double)), 0) << a;
  }
  EXPECT_TRUE(std::isnan(wrap_angle(std::numeric_limits<double>::quiet_NaN())));
  EXPECT_TRUE(std::isnan(wrap_angle(std::numeric_limits<double>::infinity())));
}

TEST(Pose, WrapAngleGivesHalfOpenInterval) {
  EXPECT_DOUBLE_EQ(wrap_angle(kPi), kPi);
  EXPECT_DOUBLE_EQ(wrap_angle(-kPi), kPi);
  EXPECT_NEAR(wrap_angle(1.5 * kPi), -0.5 * kPi, kExact);
  EXPECT_NEAR(wrap_angle(0.1 + 4 * kPi), 0.1, kExact);
  EXPECT_NEAR(wrap_angle(-0.1 - 6 * kPi), -0.1, kExact);
  EXPECT_DOUBLE_EQ(wrap_angle(0.0), 0.0);
}

TEST(Pose, EulerFromRotationInvertsRotation) {
  Sampler sampler(12);
  for (int i = 0; i < kRandomStates; ++i) {
    // Canonical angles come back unchanged ...
    const Pose6 p = make_pose(0, 0, 0, sampler.uniform(-kPi, kPi), sampler.uniform(-1.55, 1.55),
                              sampler.uniform(-kPi, kPi));
    const Vec3 e = euler_from_rotation(rotation(p));
    EXPECT_LT((e - p.tail<3>()).cwiseAbs().maxCoeff(), 1e-10) << test::describe(p);
    // ... and any angles (wrapped, φ beyond ±π/2) give the same rotation.
    const Pose6 wild = make_pose(0, 0, 0, sampler.uniform(-10, 10), sampler.uniform(-10, 10),
                                 sampler.uniform(-10, 10));
    const Vec3 w = euler_from_rotation(rotation(wild));
    EXPECT_LT((rotation_by_axes(w[0], w[1], w[2]) - rotation(wild)).cwiseAbs().maxCoeff(), 1e-12);
    EXPECT_GT(w[0], -kPi);
    EXPECT_LE(w[0], kPi);
    EXPECT_LE(std::abs(w[1]), kPi / 2);
    EXPECT_GT(w[2], -kPi);
    EXPECT_LE(w[2], kPi);
  }
}

TEST(Pose, EulerFromRotationAtGimbalLock) {
  for (double phi : {kPi / 2, -kPi / 2}) {
    const Mat3 R = rotation(make_pose(0, 0, 0, 0.7, phi, -0.4));
    const Vec3 e = euler_from_rotation(R);
    EXPECT_NEAR(e[1], phi, 1e-7);
    EXPECT_EQ(e[2], 0.0);
    EXPECT_LT((rotation_by_axes(e[0], e[1], e[2]) - R).cwiseAbs().maxCoeff(), 1e-12);
  }
}

// [ω]× = (∂R/∂e_i) Rᵀ must equal [E_i]× for every angle i.
TEST(Pose, EulerRateMatrixGivesAngularVelocity) {
  Sampler sampler(13);
  WorstError worst;
  for (int i = 0; i < kRandomStates; ++i) {
    const Pose6 p = sample_pose(sampler, i);
    const Mat3 E = euler_rate_matrix(p.tail<3>());
    for (int k = 0; k < 3; ++k) {
      Pose6 plus = p, minus = p;
      plus[kTheta + k] += test::kStep;
      minus[kTheta + k] -= test::kStep;
      const Mat3 dR = (rotation(plus) - rotation(minus)) / (2 * test::kStep);
      worst.update(skew(E.col(k)), dR * rotation(p).transpose(), test::describe(p));
    }
  }
  EXPECT_LT(worst.worst(), kJacobianTol) << worst.report();
}

TEST(Pose, CompoundKnownAnswers) {
  // Planar: robot at (1, 2) facing +y, sensor 1 m ahead.
  EXPECT_LT(pose_difference(compound(make_pose2d(1, 2, kPi / 2), make_pose2d(1, 0, 0)),
                            make_pose2d(1, 3, kPi / 2)).cwiseAbs().maxCoeff(), kExact);
  // Rolled by 90°: the frame's y axis is the parent's z axis.
  EXPECT_LT(pose_difference(compound(make_pose(1, 0, 0, 0, 0, kPi / 2), make_pose(0, 1, 0, 0, 0, 0)),
                            make_pose(1, 0, 1, 0, 0, kPi / 2)).cwiseAbs().maxCoeff(), kExact);
  // Yaws add and wrap.
  EXPECT_NEAR(compound(make_pose2d(0, 0, 3.0), make_pose2d(0, 0, 0.5))[kTheta], 3.5 - 2 * kPi, kExact);
}

TEST(Pose, CompoundMatchesMatrixProduct) {
  Sampler sampler(14);
  for (int i = 0; i < kRandomStates; ++i) {
    const Pose6 a = sampler.pose(1.0), b = sampler.pose(1.0);
    const Pose6 c = compound(a, b);
    EXPECT_LT((rotation(c) - rotation(a) * rotation(b)).cwiseAbs().maxCoeff(), 1e-12);
    EXPECT_LT((c.head<3>() - (a.head<3>() + rotation(a) * b.head<3>())).cwiseAbs().maxCoeff(), 1e-12);
  }
}

TEST(Pose, CompoundJacobiansMatchCentralDifferences) {
  Sampler sampler(15);
  WorstError worst_a, worst_b;
  for (int i = 0; i < kRandomStates; ++i) {
    const Pose6 a = sample_pose(sampler, i), b = sample_pose(sampler, i);
    Mat6 J_a, J_b;
    compound(a, b, &J_a, &J_b);
    const std::string state = "a=" + test::describe(a) + " b=" + test::describe(b);
    worst_a.update(J_a, test::numeric_pose_jacobian([&](const Pose6& x) { return compound(x, b); }, a), state);
    worst_b.update(J_b, test::numeric_pose_jacobian([&](const Pose6& x) { return compound(a, x); }, b), state);
  }
  EXPECT_LT(worst_a.worst(), kJacobianTol) << "J_a: " << worst_a.report();
  EXPECT_LT(worst_b.worst(), kJacobianTol) << "J_b: " << worst_b.report();
}

TEST(Pose, InverseJacobianMatchesCentralDifferences) {
  Sampler sampler(16);
  WorstError worst;
  for (int i = 0; i < kRandomStates; ++i) {
    const Pose6 a = sample_pose(sampler, i);
    Mat6 J;
    inverse(a, &J);
    worst.update(J, test::numeric_pose_jacobian([](const Pose6& x) { return inverse(x); }, a), test::describe(a));
  }
  EXPECT_LT(worst.worst(), kJacobianTol) << worst.report();
}

TEST(Pose, RelativeJacobiansMatchCentralDifferences) {
  Sampler sampler(17);
  WorstError worst_a, worst_b;
  for (int i = 0; i < kRandomStates; ++i) {
    const Pose6 a = sample_pose(sampler, i), b = sample_pose(sampler, i);
    Mat6 J_a, J_b;
    relative(a, b, &J_a, &J_b);
    const std::string state = "a=" + test::describe(a) + " b=" + test::describe(b);
    worst_a.update(J_a, test::numeric_pose_jacobian([&](const Pose6& x) { return relative(x, b); }, a), state);
    worst_b.update(J_b, test::numeric_pose_jacobian([&](const Pose6& x) { return relative(a, x); }, b), state);
  }
  EXPECT_LT(worst_a.worst(), kJacobianTol) << "J_a: " << worst_a.report();
  EXPECT_LT(worst_b.worst(), kJacobianTol) << "J_b: " << worst_b.report();
}

TEST(Pose, RoundTrips) {
  Sampler sampler(18);
  for (int i = 0; i < kRandomStates; ++i) {
    const Pose6 a = sampler.pose(1.0), b = sampler.pose(1.0);
    const std::string state = "a=" + test::describe(a) + " b=" + test::describe(b);
    EXPECT_LT(pose_difference(compound(a, inverse(a)), Pose6::Zero()).cwiseAbs().maxCoeff(), 1e-12) << state;
    EXPECT_LT(pose_difference(compound(inverse(a), a), Pose6::Zero()).cwiseAbs().maxCoeff(), 1e-12) << state;
    EXPECT_LT(pose_difference(inverse(inverse(a)), a).cwiseAbs().maxCoeff(), 1e-12) << state;
    EXPECT_LT(pose_difference(relative(a, b), compound(inverse(a), b)).cwiseAbs().maxCoeff(), 1e-12) << state;
    EXPECT_LT(pose_difference(compound(a, relative(a, b)), b).cwiseAbs().maxCoeff(), 1e-12) << state;
  }
}

TEST(Pose, JacobiansThrowAtGimbalLock) {
  // The compound is pitched by exactly 90°: its angles exist but their
  // Jacobian divides by cos φ = 0.
  const Pose6 a = make_pose(0, 0, 0, 0.2, kPi / 4, 0);
  const Pose6 b = make_pose(1, 0, 0, 0, kPi / 4, 0);
  EXPECT_NO_THROW(compound(a, b));
  EXPECT_NEAR(compound(a, b)[kPhi], kPi / 2, 1e-7);
  Mat6 J;
  EXPECT_THROW(compound(a, b, &J), std::domain_error);
  EXPECT_THROW(compound(a, b, nullptr, &J), std::domain_error);
  EXPECT_THROW(inverse(make_pose(0, 0, 0, 0, kPi / 2, 0), &J), std::domain_error);
}

TEST(Pose, QuaternionMatchesRotationMatrix) {
  Sampler sampler(19);
  for (int i = 0; i < kRandomStates; ++i) {
    const Pose6 p = sampler.pose(1.5);
    const Eigen::Vector4d q = quaternion_xyzw(p);
    EXPECT_NEAR(q.norm(), 1.0, kExact);
    EXPECT_GE(q[3], 0.0);
    const Mat3 R = Eigen::Quaterniond(q[3], q[0], q[1], q[2]).toRotationMatrix();
    EXPECT_LT((R - rotation(p)).cwiseAbs().maxCoeff(), 1e-12) << test::describe(p);
  }
  const double h = std::sqrt(0.5);
  EXPECT_TRUE(quaternion_xyzw(make_pose2d(0, 0, kPi / 2)).isApprox(Eigen::Vector4d(0, 0, h, h)));
  // Yaw of 181° (≡ −179°): the half-angle quaternion has w < 0 and is
  // flipped to the one of −179°.
  const double yaw = -179.0 * kPi / 180.0;
  EXPECT_TRUE(quaternion_xyzw(make_pose2d(0, 0, yaw))
                  .isApprox(Eigen::Vector4d(0, 0, std::sin(yaw / 2), std::cos(yaw / 2))));
  EXPECT_TRUE(quaternion_xyzw(make_pose2d(0, 0, yaw + 2 * kPi))
                  .isApprox(Eigen::Vector4d(0, 0, std::sin(yaw / 2), std::cos(yaw / 2))));
}

TEST(Pose, PoseDifferenceWrapsAngles) {
  const Pose6 d = pose_difference(make_pose(1, 2, 3, 3.1, 0.2, -3.0), make_pose(0.5, 2, 1, -3.1, 0.1, 3.0));
  const Pose6 expected = make_pose(0.5, 0, 2, 6.2 - 2 * kPi, 0.1, 2 * kPi - 6.0);
  EXPECT_LT((d - expected).cwiseAbs().maxCoeff(), kExact);
}

}  // namespace
}  // namespace mspace
