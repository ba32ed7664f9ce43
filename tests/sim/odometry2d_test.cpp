// Tests of the planar odometry motion model: f (eq. 25), its Jacobians and C_d (eq. 26).
#include "odometry2d/odometry2d.hpp"

#include <gtest/gtest.h>

#include <cmath>
#include <numbers>
#include <stdexcept>

#include "sim_world/sim_random.hpp"

namespace mspace {
namespace {

using odometry2d::Odometry2dModel;
using planar_odometry::Increment;
using planar_odometry::kDegree;

Odometry2dModel noise_free_model() { return Odometry2dModel(planar_odometry::NoiseModel{}); }

TEST(Odometry2d, EstimatesXYTheta) {
  EXPECT_EQ(noise_free_model().estimated_dofs(), (std::vector<int>{kX, kY, kTheta}));
}

TEST(Odometry2d, PredictsKnownPose) {
  // Heading 90°: the robot's x axis is the map's y axis.
  const Pose6 x_r = make_pose(1.0, 2.0, 0.5, 0.5 * std::numbers::pi, 0.1, 0.2);
  const MotionPrediction p = noise_free_model().predict(x_r, Eigen::Vector3d(1.0, 0.5, 0.3), 0.1);
  EXPECT_NEAR(p.pose[kX], 0.5, 1e-15);  // 1 − 0.5
  EXPECT_NEAR(p.pose[kY], 3.0, 1e-15);  // 2 + 1
  EXPECT_NEAR(p.pose[kTheta], 0.5 * std::numbers::pi + 0.3, 1e-15);
  EXPECT_EQ(p.pose[kZ], 0.5);
  EXPECT_EQ(p.pose[kPhi], 0.1);
  EXPECT_EQ(p.pose[kPsi], 0.2);
}

TEST(Odometry2d, WrapsHeading) {
  const MotionPrediction p =
      noise_free_model().predict(make_pose2d(0, 0, 3.0), Eigen::Vector3d(0.0, 0.0, 0.5), 0.1);
  EXPECT_NEAR(p.pose[kTheta], 3.5 - 2.0 * std::numbers::pi, 1e-15);
}

TEST(Odometry2d, RejectsIncrementOfWrongSize) {
  EXPECT_THROW(noise_free_model().predict(Pose6::Zero(), Eigen::Vector2d(1.0, 0.0), 0.1),
               std::invalid_argument);
}

TEST(Odometry2d, NoiseCovarianceFromParameters) {
  Params params = Params::defaults(Odometry2dModel::param_specs());
  params.set("xy_noise_per_m", 0.1);
  params.set("xy_noise_floor", 0.01);
  params.set("theta_noise_per_rad", 0.2);
  params.set("theta_noise_per_m", 2.0);  // deg/m
  params.set("theta_noise_floor", 0.5);  // deg
  const Odometry2dModel model(PluginArgs{"odo", params, nullptr});

  const MotionPrediction p = model.predict(Pose6::Zero(), Eigen::Vector3d(3.0, 4.0, -0.5), 0.1);
  const double sigma_xy = 0.1 * 5.0 + 0.01;  // d = 5 m
  const double sigma_theta = 0.2 * 0.5 + (2.0 * 5.0 + 0.5) * kDegree;
  Eigen::Matrix3d expected = Eigen::Matrix3d::Zero();
  expected.diagonal() << sigma_xy * sigma_xy, sigma_xy * sigma_xy, sigma_theta * sigma_theta;
  EXPECT_TRUE(p.C_d.isApprox(expected, 1e-14)) << p.C_d;
}

TEST(Odometry2d, DefaultNoiseParameters) {
  const Params params = Params::defaults(Odometry2dModel::param_specs());
  EXPECT_EQ(params.values().size(), 5u);
  EXPECT_EQ(params.get_double("xy_noise_per_m"), 0.02);
  EXPECT_EQ(params.get_double("xy_noise_floor"), 0.001);
  EXPECT_EQ(params.get_double("theta_noise_per_rad"), 0.02);
  EXPECT_EQ(params.get_double("theta_noise_per_m"), 0.5);
  EXPECT_EQ(params.get_double("theta_noise_floor"), 0.01);
}

/// f restricted to the estimated coordinates, as a function of (x, y, θ) and x_d.
Eigen::Vector3d f3(const Eigen::Vector3d& r, const Increment& d) {
  const Pose6 moved =
      planar_odometry::apply_increment(make_pose(r[0], r[1], 0.7, r[2], 0.0, 0.0), d);
  return {moved[kX], moved[kY], moved[kTheta]};
}

/// Central difference (f(v + h e_i) − f(v − h e_i)) / 2h, the angle difference wrapped.
template <class F>
Eigen::Matrix3d central_difference(const F& f, const Eigen::Vector3d& v, double h) {
  Eigen::Matrix3d J;
  for (int i = 0; i < 3; ++i) {
    Eigen::Vector3d plus = v, minus = v;
    plus[i] += h;
    minus[i] -= h;
    Eigen::Vector3d diff = f(plus) - f(minus);
    diff[2] = wrap_angle(diff[2]);
    J.col(i) = diff / (2.0 * h);
  }
  return J;
}

TEST(Odometry2d, JacobiansMatchCentralDifferences) {
  // Positions up to 50 m, increments up to 2 m and ±π. With h = 1e-5 the
  // truncation error is ~h²·|f'''| ≲ 1e-9 and the rounding error
  // ~ε·50/h ≈ 1e-9, so 1e-8 separates a correct Jacobian from a wrong one
  // (a wrong entry is off by O(0.1–10)).
  sim_world::SimRandom rng(42, 0);
  const double h = 1e-5;
  const Odometry2dModel model = noise_free_model();
  for (int trial = 0; trial < 2000; ++trial) {
    const Eigen::Vector3d r(rng.uniform(-50, 50), rng.uniform(-50, 50),
                            rng.uniform(-std::numbers::pi, std::numbers::pi));
    const Increment d(rng.uniform(-2, 2), rng.uniform(-2, 2),
                      rng.uniform(-std::numbers::pi, std::numbers::pi));
    const MotionPrediction p = model.predict(make_pose(r[0], r[1], 0.7, r[2], 0.0, 0.0), d, 0.1);
    ASSERT_EQ(p.J_rr.rows(), 3);
    ASSERT_EQ(p.J_rr.cols(), 3);
    ASSERT_EQ(p.J_rd.rows(), 3);
    ASSERT_EQ(p.J_rd.cols(), 3);
    const Eigen::Matrix3d J_rr =
        central_difference([&](const Eigen::Vector3d& v) { return f3(v, d); }, r, h);
    const Eigen::Matrix3d J_rd =
        central_difference([&](const Eigen::Vector3d& v) { return f3(r, v); }, d, h);
    ASSERT_LT((J_rr - p.J_rr).cwiseAbs().maxCoeff(), 1e-8) << "trial " << trial << "\n"
                                                           << p.J_rr << "\nvs\n"
                                                           << J_rr;
    ASSERT_LT((J_rd - p.J_rd).cwiseAbs().maxCoeff(), 1e-8) << "trial " << trial << "\n"
                                                           << p.J_rd << "\nvs\n"
                                                           << J_rd;
  }
}

}  // namespace
}  // namespace mspace
