// Trajectory evaluation (SE(2) alignment, interpolation, ATE) and χ² helpers
// against answers known in closed form.
#include <gtest/gtest.h>

#include <cmath>
#include <numbers>
#include <random>

#include "chi2.hpp"
#include "evaluation.hpp"

namespace {

using namespace mspace;
using namespace mspace::kernel;

TEST(Chi2, QuantilesMatchTables) {
  // Standard table values.
  EXPECT_NEAR(chi2_quantile(0.95, 1), 3.841459, 1e-5);
  EXPECT_NEAR(chi2_quantile(0.99, 2), 9.210340, 1e-5);
  EXPECT_NEAR(chi2_quantile(0.99, 3), 11.344867, 1e-5);
  EXPECT_NEAR(chi2_quantile(0.025, 60), 40.481748, 1e-4);
  EXPECT_NEAR(chi2_quantile(0.975, 60), 83.297675, 1e-4);
  // χ²(2) has the closed-form CDF 1 − exp(−x/2).
  for (double x : {0.1, 1.0, 5.0, 20.0}) EXPECT_NEAR(chi2_cdf(x, 2), 1.0 - std::exp(-x / 2), 1e-12);
  EXPECT_THROW(chi2_quantile(1.0, 3), std::invalid_argument);
}

TEST(Evaluation, AlignSe2RecoversAKnownTransform) {
  std::mt19937 rng(3);
  std::uniform_real_distribution<double> u(-20, 20);
  Se2Alignment truth;
  truth.theta = 0.7;
  truth.t = {3.0, -2.0};
  std::vector<Eigen::Vector2d> est, ref;
  for (int i = 0; i < 50; ++i) {
    est.emplace_back(u(rng), u(rng));
    ref.push_back(truth.apply(est.back()));
  }
  const Se2Alignment a = align_se2(est, ref);
  EXPECT_NEAR(a.theta, 0.7, 1e-12);
  EXPECT_NEAR((a.t - truth.t).norm(), 0.0, 1e-10);
}

TEST(Evaluation, InterpolatesBetweenPosesAndRespectsGaps) {
  std::vector<StampedPose> traj = {{0.0, make_pose2d(0, 0, 3.0)}, {1.0, make_pose2d(2, 4, -3.0)},
                                   {5.0, make_pose2d(0, 0, 0)}};
  const auto mid = interpolate(traj, 0.25, 2.0);
  ASSERT_TRUE(mid.has_value());
  EXPECT_NEAR((*mid)[kX], 0.5, 1e-12);
  EXPECT_NEAR((*mid)[kY], 1.0, 1e-12);
  // From 3 rad to −3 rad the short way crosses ±π: a quarter of 2π − 6.
  EXPECT_NEAR((*mid)[kTheta], wrap_angle(3.0 + 0.25 * (2 * std::numbers::pi - 6.0)), 1e-12);
  EXPECT_FALSE(interpolate(traj, 3.0, 2.0).has_value());  // the poses around t = 3 are 4 s apart
  EXPECT_FALSE(interpolate(traj, -1.0, 2.0).has_value());
  EXPECT_TRUE(interpolate(traj, 1.0, 0.0).has_value());  // exact time stamp
}

TEST(Evaluation, AteOfARigidlyMovedTrajectoryIsZeroAndNoiseGivesItsRms) {
  std::vector<StampedPose> est, ref;
  Se2Alignment moved;
  moved.theta = -0.4;
  moved.t = {10, 5};
  for (int i = 0; i <= 100; ++i) {
    const double t = 0.1 * i;
    est.push_back({t, make_pose2d(std::cos(t) * 5, std::sin(2 * t) * 3, 0.1 * t)});
    if (i % 4 == 0) {  // position-only reference (like GPS) at a quarter of the rate
      const Eigen::Vector2d p = moved.apply({est.back().pose[kX], est.back().pose[kY]});
      ref.push_back({t, make_pose2d(p.x(), p.y(), 0), static_cast<std::uint8_t>((1u << kX) | (1u << kY))});
    }
  }
  TrajectoryErrors e = evaluate_trajectory(est, ref, 0.5);
  EXPECT_EQ(e.matched, ref.size());
  EXPECT_NEAR(e.ate_rmse, 0.0, 1e-9);
  EXPECT_FALSE(e.final_heading.has_value());  // the reference has no heading

  // Alternating ±d offsets along x on a symmetric set: alignment cannot remove them, RMSE = d.
  const double d = 0.3;
  for (std::size_t i = 0; i < ref.size(); ++i) ref[i].pose[kX] += (i % 2 == 0 ? d : -d);
  if (ref.size() % 2 == 1) ref.pop_back();
  e = evaluate_trajectory(est, ref, 0.5);
  EXPECT_NEAR(e.ate_rmse, d, 0.02);
}

}  // namespace
