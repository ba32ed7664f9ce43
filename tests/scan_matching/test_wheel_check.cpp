// The wheels' veto on laser odometry (sensors_plugins/scan_matching/wheel_check.hpp):
// logging gaps found relative to the log's own scan rate, the spread of the
// match−wheel difference measured back from synthetic increments with a known
// random-walk error, and exactly the planted wrong matches flagged.
#include "wheel_check.hpp"

#include <gtest/gtest.h>

#include <Eigen/Dense>

#include <algorithm>
#include <cmath>
#include <numbers>
#include <random>
#include <set>

namespace {

using namespace mspace::scan_matching;

TEST(WheelCheck, LoggingGapsAreRelativeToTheMedianScanInterval) {
  // 0.6 s apart, one 90 s gap and one 3 s pause (5 × the median: not a gap at factor 10).
  std::vector<double> t = {0.0};
  for (int i = 1; i < 40; ++i) t.push_back(t.back() + (i == 10 ? 90.0 : i == 20 ? 3.0 : 0.6));
  const std::vector<bool> gap = logging_gaps(t, 10.0);
  ASSERT_EQ(gap.size(), t.size());
  for (std::size_t i = 0; i < t.size(); ++i) EXPECT_EQ(gap[i], i == 10) << i;
  // The same log 10× faster: the same scans are gaps (relative, not in seconds).
  for (double& x : t) x *= 0.1;
  EXPECT_EQ(logging_gaps(t, 10.0), gap);
  EXPECT_EQ(std::count(gap.begin(), gap.end(), true), 1);
  const std::vector<bool> none = logging_gaps(t, 0.0);
  EXPECT_EQ(std::count(none.begin(), none.end(), true), 0);
}

TEST(WheelCheck, MeasuresTheSpreadAndFlagsExactlyThePlantedWrongMatches) {
  // Wheel increments of 0.05–0.6 m and ±0.3 rad; the match differs from them
  // by a random walk of σ 3 mm/√m and 0.2°/√m over the path proxy L = d + |θ| + L̄.
  std::mt19937_64 rng(5);
  std::uniform_real_distribution<double> length(0.05, 0.6), turn(-0.3, 0.3);
  std::normal_distribution<double> normal;
  const double s_xy = 0.003, s_th = 0.2 * std::numbers::pi / 180.0;
  const std::size_t n = 4000;
  std::vector<Eigen::Vector3d> wheel(n), laser(n);
  std::vector<IncrementSource> source(n, IncrementSource::matched);
  std::vector<double> path(n);
  for (std::size_t i = 0; i < n; ++i) {
    const double a = turn(rng);
    wheel[i] = Eigen::Vector3d(length(rng), 0.0, a);
    path[i] = wheel[i].head<2>().norm() + std::abs(a);
  }
  std::vector<double> sorted = path;
  std::nth_element(sorted.begin(), sorted.begin() + n / 2, sorted.end());
  const double median_path = sorted[n / 2];
  for (std::size_t i = 0; i < n; ++i) {
    const double root = std::sqrt(path[i] + median_path);
    laser[i] = wheel[i] + Eigen::Vector3d(s_xy * root * normal(rng), s_xy * root * normal(rng), s_th * root * normal(rng));
  }
  // Wrong matches: a corridor-length slide, a 0.3 m jump, a 10° turn; two matches failed, one gap.
  const std::set<std::size_t> wrong = {100, 1500, 3999};
  laser[100][0] += 2.0;
  laser[1500][1] += 0.3;
  laser[3999][2] += 10.0 * std::numbers::pi / 180.0;
  source[7] = source[8] = IncrementSource::failed;
  source[9] = IncrementSource::gap;
  laser[7][0] += 5.0;  // a failed match's increment is not judged

  const WheelCheckResult r = check_against_wheels(wheel, laser, source, WheelCheckOptions{});
  EXPECT_NEAR(r.median_path, median_path, 1e-12);
  EXPECT_NEAR(r.sigma_xy / s_xy, 1.0, 0.05);
  EXPECT_NEAR(r.sigma_theta / s_th, 1.0, 0.05);
  for (std::size_t i = 0; i < n; ++i) {
    if (i == 7 || i == 8) EXPECT_EQ(r.source[i], IncrementSource::failed);
    else if (i == 9) EXPECT_EQ(r.source[i], IncrementSource::gap);
    else EXPECT_EQ(r.source[i] == IncrementSource::inconsistent, wrong.count(i) == 1) << i << " chi2 " << r.chi2[i];
  }
  EXPECT_EQ(r.count(IncrementSource::inconsistent), 3u);
  EXPECT_EQ(r.count(IncrementSource::matched), n - 6);
  // No check asked for: nothing flagged.
  WheelCheckOptions off;
  off.gate = 0.0;
  EXPECT_EQ(check_against_wheels(wheel, laser, source, off).count(IncrementSource::inconsistent), 0u);
}

TEST(WheelCheck, PerfectDataKeepsAFloorInsteadOfFlaggingEverything) {
  // Matches equal to the wheels but for 0.1 mm: the spread's floor (2 mm over
  // a median increment) keeps them; a 5 cm jump on a 0.2 m step is still flagged.
  const std::size_t n = 200;
  std::vector<Eigen::Vector3d> wheel(n, Eigen::Vector3d(0.2, 0.0, 0.0)), laser(n);
  for (std::size_t i = 0; i < n; ++i) laser[i] = wheel[i] + Eigen::Vector3d(i % 2 ? 1e-4 : -1e-4, 0.0, 0.0);
  laser[50][0] += 0.05;
  const std::vector<IncrementSource> source(n, IncrementSource::matched);
  const WheelCheckResult r = check_against_wheels(wheel, laser, source, WheelCheckOptions{});
  EXPECT_EQ(r.count(IncrementSource::inconsistent), 1u);
  EXPECT_EQ(r.source[50], IncrementSource::inconsistent);
}

TEST(WheelModel, RecoversPlantedScaleTurnScaleAndDriftAndTheSpreadLeft) {
  // The laser sees the true motion; the wheels read it with a 2 % scale
  // error, a −3 % turn-scale error, a drift of 0.1°/m and a random walk of
  // 4 mm/√m and 0.3°/√m. The fit must find the three systematic errors and
  // the random walk that is left.
  std::mt19937_64 rng(11);
  std::uniform_real_distribution<double> length(-0.1, 0.7), turn(-0.4, 0.4);
  std::normal_distribution<double> normal;
  const double k_s = 0.02, k_t = -0.03, b = 0.1 * std::numbers::pi / 180.0;
  const double s_xy = 0.004, s_th = 0.3 * std::numbers::pi / 180.0;
  const std::size_t n = 5000;
  std::vector<Eigen::Vector3d> truth(n), wheel(n);
  std::vector<double> path(n);
  for (std::size_t i = 0; i < n; ++i) {
    truth[i] = Eigen::Vector3d(length(rng), 0.02 * normal(rng), turn(rng));
    path[i] = truth[i].head<2>().norm() + std::abs(truth[i][2]);
  }
  std::vector<double> sorted = path;
  std::nth_element(sorted.begin(), sorted.begin() + n / 2, sorted.end());
  const double median_path = sorted[n / 2];
  for (std::size_t i = 0; i < n; ++i) {
    // wheel = (truth − drift − noise) / (1 + scale): the inverse of the model.
    const double root = std::sqrt(path[i] + median_path);
    Eigen::Vector3d w;
    w[0] = (truth[i][0] - s_xy * root * normal(rng)) / (1.0 + k_s);
    w[1] = (truth[i][1] - s_xy * root * normal(rng)) / (1.0 + k_s);
    w[2] = (truth[i][2] - b * w[0] - s_th * root * normal(rng)) / (1.0 + k_t);
    wheel[i] = w;
  }
  const std::vector<IncrementSource> source(n, IncrementSource::matched);
  const WheelCheckOptions options;
  const WheelCheckResult check = check_against_wheels(wheel, truth, source, options);
  const WheelModel model = fit_wheel_model(wheel, truth, check, options);
  ASSERT_GT(model.used, n * 99 / 100);
  EXPECT_NEAR(model.scale, k_s, 0.002);
  EXPECT_NEAR(model.turn_scale, k_t, 0.003);
  EXPECT_NEAR(model.bias_per_m, b, 0.02 * std::numbers::pi / 180.0);
  EXPECT_NEAR(model.sigma_xy / s_xy, 1.0, 0.1);
  EXPECT_NEAR(model.sigma_theta / s_th, 1.0, 0.1);
  // The variance rates: the planted noise has variance s²·(d + |θ| + L̄) per
  // axis (d the true distance, close to the wheels' for 2 % scale).
  EXPECT_NEAR(model.xy_rates.per_m / (s_xy * s_xy), 1.0, 0.15);
  EXPECT_NEAR(model.xy_rates.per_rad / (s_xy * s_xy), 1.0, 0.25);
  EXPECT_NEAR(model.xy_rates.floor / (s_xy * s_xy * median_path), 1.0, 0.3);
  EXPECT_NEAR(model.theta_rates.per_m / (s_th * s_th), 1.0, 0.15);
  EXPECT_NEAR(model.theta_rates.per_rad / (s_th * s_th), 1.0, 0.25);
  // The correction is the model: 1 m straight on gains the drift as heading.
  const Eigen::Vector3d straight(1.0, 0.0, 0.0);
  EXPECT_NEAR(model.correct(straight)[0], 1.0 + model.scale, 1e-15);
  EXPECT_NEAR(model.correct(straight)[2], model.bias_per_m, 1e-15);

  // Too few matched increments: no model, no covariance.
  std::vector<IncrementSource> few(n, IncrementSource::failed);
  for (std::size_t i = 0; i < 10; ++i) few[i] = IncrementSource::matched;
  const WheelModel none = fit_wheel_model(wheel, truth, check_against_wheels(wheel, truth, few, options), options);
  EXPECT_EQ(none.used, 0u);
  EXPECT_TRUE(none.covariance(straight, 1.0).isZero());
}

TEST(WheelModel, CovarianceOfALongIncrementIsTheComposedRandomWalk) {
  // Monte Carlo: a 20 m drive with a slow turn, as sub-steps each with the
  // model's random walk (variance per metre driven and per radian turned),
  // after the per-increment floor, composed; the empirical covariance of the
  // end pose in the start frame must match WheelModel::covariance. The
  // lateral σ grows faster than √L (heading error times distance).
  WheelModel model;
  model.xy_rates = {0.005 * 0.005, 0.002 * 0.002, 0.001 * 0.001};
  const double deg = std::numbers::pi / 180.0;
  model.theta_rates = {std::pow(0.5 * deg, 2), std::pow(0.8 * deg, 2), std::pow(0.1 * deg, 2)};
  model.median_path = 0.4;
  model.used = 100;
  const Eigen::Vector3d total(20.0, 3.0, 0.6);
  const double path = model.path_of(total);
  const int K = static_cast<int>(std::ceil(path / model.median_path));  // sub-steps of about L̄ (53)
  const Eigen::Vector3d u = total / K;
  const double d = u.head<2>().norm(), turn = std::abs(u[2]);
  const double q_xy = model.xy_rates.per_m * d + model.xy_rates.per_rad * turn;
  const double q_th = model.theta_rates.per_m * d + model.theta_rates.per_rad * turn;
  std::mt19937_64 rng(3);
  std::normal_distribution<double> normal;
  const int trials = 20000;
  std::vector<Eigen::Vector3d> ends(trials);
  Eigen::Vector3d mean = Eigen::Vector3d::Zero();
  for (int t = 0; t < trials; ++t) {
    Eigen::Vector3d p(std::sqrt(model.xy_rates.floor) * normal(rng), std::sqrt(model.xy_rates.floor) * normal(rng),
                      std::sqrt(model.theta_rates.floor) * normal(rng));
    for (int k = 0; k < K; ++k) {
      const Eigen::Vector3d step =
          u + Eigen::Vector3d(std::sqrt(q_xy) * normal(rng), std::sqrt(q_xy) * normal(rng), std::sqrt(q_th) * normal(rng));
      const double c = std::cos(p[2]), s = std::sin(p[2]);
      p += Eigen::Vector3d(c * step[0] - s * step[1], s * step[0] + c * step[1], step[2]);
    }
    ends[static_cast<std::size_t>(t)] = p;
    mean += p / trials;
  }
  Eigen::Matrix3d empirical = Eigen::Matrix3d::Zero();
  for (const Eigen::Vector3d& p : ends) empirical += (p - mean) * (p - mean).transpose() / (trials - 1);
  const Eigen::Matrix3d C = model.covariance(total, path);
  for (int i = 0; i < 3; ++i) EXPECT_NEAR(C(i, i) / empirical(i, i), 1.0, 0.06) << i;
  EXPECT_NEAR(C(1, 2) / std::sqrt(C(1, 1) * C(2, 2)), empirical(1, 2) / std::sqrt(empirical(1, 1) * empirical(2, 2)),
              0.03);
  // The same increment given as its sub-steps (no systematic uncertainty): the same covariance.
  EXPECT_TRUE(model.covariance_along(std::vector<Eigen::Vector3d>(static_cast<std::size_t>(K), u)).isApprox(C, 1e-12));
  // Lateral σ over 20 m far beyond the √d random walk of translation alone.
  EXPECT_GT(std::sqrt(C(1, 1)), 5.0 * std::sqrt(model.xy_rates.per_m * 20.0));
  // A longer path over the same increment (a robot that wandered in a gap): more uncertainty.
  EXPECT_GT(model.covariance(total, 3.0 * path).trace(), 2.0 * C.trace());
  // Uncertain parameters add a systematic part: a 1 % turn-scale uncertainty
  // over 0.6 rad of turning is 0.006 rad more heading σ, at least.
  WheelModel uncertain = model;
  uncertain.parameter_covariance(1, 1) = 0.01 * 0.01;
  const Eigen::Matrix3d Cu = uncertain.covariance_along(std::vector<Eigen::Vector3d>(static_cast<std::size_t>(K), u));
  EXPECT_NEAR(Cu(2, 2) - C(2, 2), std::pow(0.01 * 0.6, 2), 1e-9);
}

// Two estimates combined by their covariances (scan_match_fuse_wheels):
// a match weak along x (a corridor) and sure across it, wheels equally sure
// in x and y. The result takes x from the wheels and y from the match, with
// the covariance of the combination; a disagreement beyond both is refused.
TEST(WheelCheck, CombinedIncrementsTakeEachWhereItIsStronger) {
  const Eigen::Vector3d w(1.00, 0.00, 0.0), m(1.10, 0.004, 0.0);
  const Eigen::Matrix3d C_w = Eigen::Vector3d(1e-4, 1e-4, 1e-6).asDiagonal();  // 1 cm, 1 cm
  const Eigen::Matrix3d C_m = Eigen::Vector3d(1.0, 1e-6, 1e-6).asDiagonal();   // 1 m along, 1 mm across
  const auto c = combine_increments(w, C_w, m, C_m, 25.9);
  ASSERT_TRUE(c);
  // x: (1.00/1e-4 + 1.10/1) / (1/1e-4 + 1); y: (0/1e-4 + 0.004/1e-6) / (1/1e-4 + 1/1e-6); θ: equal weights.
  EXPECT_NEAR(c->increment[0], (1.00 / 1e-4 + 1.10) / (1e4 + 1.0), 1e-12);
  EXPECT_NEAR(c->increment[1], (0.004 / 1e-6) / (1e4 + 1e6), 1e-12);
  EXPECT_NEAR(c->increment[2], 0.0, 1e-15);
  EXPECT_NEAR(c->covariance(0, 0), 1.0 / (1e4 + 1.0), 1e-15);
  EXPECT_NEAR(c->covariance(1, 1), 1.0 / (1e4 + 1e6), 1e-15);
  EXPECT_NEAR(c->covariance(2, 2), 0.5e-6, 1e-15);
  // Headings a turn apart are the same heading.
  const auto wrapped = combine_increments(w, C_w, Eigen::Vector3d(1.0, 0.0, 2.0 * std::numbers::pi), C_m, 25.9);
  ASSERT_TRUE(wrapped);
  EXPECT_NEAR(wrapped->increment[2], 0.0, 1e-12);
  // 5 cm across the corridor is 5σ of the two together: beyond a gate of 16.
  EXPECT_FALSE(combine_increments(w, C_w, Eigen::Vector3d(1.0, 0.05, 0.0), C_m, 16.0));
}

}  // namespace
