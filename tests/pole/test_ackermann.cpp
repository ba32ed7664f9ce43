// Tests of the `ackermann` motion model: known motions, the encoder-to-centre
// speed, the laser-point kinematics of the data set's README, J_rr and J_rd
// (eq. 26) against central differences, and the time scaling of the noise.
#include <gtest/gtest.h>

#include <cmath>
#include <numbers>
#include <random>

#include "ackermann.hpp"

namespace mspace::ackermann {
namespace {

constexpr double kPi = std::numbers::pi;
constexpr double kStep = 1e-6;
constexpr double kJacobianTol = 1e-7;

/// The Victoria Park constants of the data set's README.
AckermannConfig acfr() {
  AckermannConfig c;
  c.wheelbase = 2.83;
  c.encoder_offset = 0.76;
  c.speed_sigma = 0.1;
  c.speed_sigma_rel = 0.05;
  c.steering_sigma = 2.0 * kPi / 180;
  c.noise_period = 0.025;
  return c;
}

TEST(Ackermann, StraightLineAtEncoderSpeed) {
  const AckermannModel model(acfr());
  const MotionPrediction p = model.predict(make_pose2d(1, 2, kPi / 6), Eigen::Vector2d(2.0, 0.0), 0.5);
  EXPECT_NEAR(p.pose[kX], 1 + std::cos(kPi / 6), 1e-12);
  EXPECT_NEAR(p.pose[kY], 2 + std::sin(kPi / 6), 1e-12);
  EXPECT_NEAR(p.pose[kTheta], kPi / 6, 1e-15);
}

TEST(Ackermann, EncoderOnTheLeftWheelRunsFastOnALeftTurn) {
  // tan α = 0.1: v_c = v_e / (1 − 0.1·0.76/2.83), turn rate v_c·0.1/2.83.
  const AckermannConfig c = acfr();
  const double alpha = std::atan(0.1);
  const double v_c = centre_speed(c, 3.0, alpha);
  EXPECT_NEAR(v_c, 3.0 / (1 - 0.1 * 0.76 / 2.83), 1e-12);
  const Pose6 moved = motion(c, Pose6::Zero(), Eigen::Vector2d(3.0, alpha), 0.025);
  EXPECT_NEAR(moved[kTheta], 0.025 * v_c * 0.1 / 2.83, 1e-15);
  EXPECT_THROW(centre_speed(c, 1.0, std::atan(2.83 / 0.76)), std::invalid_argument);
}

TEST(Ackermann, SteeringOffsetIsAddedToEverySample) {
  // The steering encoder's zero error: a sample α with offset δ moves the car
  // as α + δ would without, Jacobians and noise included.
  AckermannConfig with = acfr();
  with.steering_offset = 0.3 * kPi / 180;
  const AckermannModel offset_model(with), plain(acfr());
  const Pose6 x = make_pose2d(1, 2, 0.4);
  const MotionPrediction a = offset_model.predict(x, Eigen::Vector2d(3.0, 0.05), 0.2);
  const MotionPrediction b = plain.predict(x, Eigen::Vector2d(3.0, 0.05 + with.steering_offset), 0.2);
  EXPECT_EQ(a.pose, b.pose);
  EXPECT_EQ(a.J_rr, b.J_rr);
  EXPECT_EQ(a.J_rd, b.J_rd);
  EXPECT_EQ(a.C_d, b.C_d);
  EXPECT_GT(a.pose[kTheta], plain.predict(x, Eigen::Vector2d(3.0, 0.05), 0.2).pose[kTheta]);  // positive = left
}

// The README gives the motion of the laser point at (a, b) from the rear axle
// with a = 3.78 m (= L + 0.95, see ackermann.hpp). Composing this model with
// the mount must give the same velocity.
TEST(Ackermann, LaserPointFollowsTheReadmeKinematics) {
  const AckermannConfig c = acfr();
  const double a = 3.78, b = 0.50, L = c.wheelbase;
  const Pose6 mount = make_pose2d(a, b, 0.0);
  std::mt19937 rng(3);
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  for (int i = 0; i < 100; ++i) {
    const Pose6 x_r = make_pose2d(10 * u(rng), 10 * u(rng), kPi * u(rng));
    const double v_e = 4 * u(rng), alpha = 0.5 * u(rng), dt = 1e-7;
    const Pose6 before = compound(x_r, mount);
    const Pose6 after = compound(motion(c, x_r, Eigen::Vector2d(v_e, alpha), dt), mount);
    const double v_c = v_e / (1 - std::tan(alpha) * c.encoder_offset / L), phi = x_r[kTheta];
    const double xdot = v_c * std::cos(phi) - v_c / L * std::tan(alpha) * (a * std::sin(phi) + b * std::cos(phi));
    const double ydot = v_c * std::sin(phi) + v_c / L * std::tan(alpha) * (a * std::cos(phi) - b * std::sin(phi));
    EXPECT_NEAR((after[kX] - before[kX]) / dt, xdot, 1e-5);
    EXPECT_NEAR((after[kY] - before[kY]) / dt, ydot, 1e-5);
  }
}

TEST(Ackermann, JacobiansMatchCentralDifferences) {
  const AckermannConfig c = acfr();
  std::mt19937 rng(5);
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  double worst = 0.0;
  for (int i = 0; i < 1000; ++i) {
    const Pose6 x_r = make_pose2d(50 * u(rng), 50 * u(rng), 3.0 * u(rng));
    const Eigen::Vector2d x_d(5 * u(rng), 0.6 * u(rng));
    const double dt = 0.05 * (1 + u(rng));
    Eigen::Matrix3d J_rr;
    Eigen::Matrix<double, 3, 2> J_rd;
    motion(c, x_r, x_d, dt, &J_rr, &J_rd);
    Eigen::Matrix3d num_rr;
    Eigen::Matrix<double, 3, 2> num_rd;
    const int pose_index[3] = {kX, kY, kTheta};
    auto planar = [](const Pose6& p) { return Eigen::Vector3d(p[kX], p[kY], p[kTheta]); };
    for (int j = 0; j < 3; ++j) {
      Pose6 p = x_r, m = x_r;
      p[pose_index[j]] += kStep;
      m[pose_index[j]] -= kStep;
      num_rr.col(j) = (planar(motion(c, p, x_d, dt)) - planar(motion(c, m, x_d, dt))) / (2 * kStep);
    }
    for (int j = 0; j < 2; ++j) {
      Eigen::Vector2d p = x_d, m = x_d;
      p[j] += kStep;
      m[j] -= kStep;
      num_rd.col(j) = (planar(motion(c, x_r, p, dt)) - planar(motion(c, x_r, m, dt))) / (2 * kStep);
    }
    worst = std::max({worst, (J_rr - num_rr).norm() / std::max(1.0, num_rr.norm()),
                      (J_rd - num_rd).norm() / std::max(1.0, num_rd.norm())});
  }
  EXPECT_LT(worst, kJacobianTol);
}

// Two half steps add up to the pose noise of one whole step (eq. 26, Q = J_rd C_d J_rdᵀ).
TEST(Ackermann, NoiseGrowsLinearlyWithTime) {
  const AckermannModel model(acfr());
  const Pose6 x_r = make_pose2d(0, 0, 0.3);
  const Eigen::Vector2d x_d(3.0, 0.1);
  auto Q = [&](double dt) {
    const MotionPrediction p = model.predict(x_r, x_d, dt);
    return Eigen::Matrix3d(p.J_rd * p.C_d * p.J_rd.transpose());
  };
  EXPECT_TRUE((2 * Q(0.0125)).isApprox(Q(0.025), 1e-12));
  // One nominal period: C_d = diag(σ_v², σ_α²) with σ_v = 0.1 + 0.05·3.
  const MotionPrediction p = model.predict(x_r, x_d, 0.025);
  EXPECT_NEAR(p.C_d(0, 0), 0.25 * 0.25, 1e-15);
  EXPECT_NEAR(p.C_d(1, 1), std::pow(2.0 * kPi / 180, 2), 1e-15);
}

TEST(Ackermann, FirstStepAndBadInput) {
  const AckermannModel model(acfr());
  const Pose6 x_r = make_pose2d(1, 2, 0.3);
  const MotionPrediction p = model.predict(x_r, Eigen::Vector2d(3.0, 0.1), 0.0);
  EXPECT_EQ(p.pose, x_r);
  EXPECT_TRUE(p.C_d.allFinite());
  EXPECT_EQ(p.J_rd.norm(), 0.0);
  EXPECT_THROW(model.predict(x_r, Eigen::Vector3d(1, 2, 3), 0.1), std::invalid_argument);
  EXPECT_THROW(model.predict(x_r, Eigen::Vector2d(1, 0), -0.1), std::invalid_argument);
  EXPECT_EQ(model.estimated_dofs(), (std::vector<int>{kX, kY, kTheta}));
}

}  // namespace
}  // namespace mspace::ackermann
