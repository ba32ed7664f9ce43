// The wheels' veto on laser odometry (sensors_plugins/scan_matching/wheel_check.hpp):
// logging gaps found relative to the log's own scan rate, the spread of the
// match−wheel difference measured back from synthetic increments with a known
// random-walk error, and exactly the planted wrong matches flagged.
#include "wheel_check.hpp"

#include <gtest/gtest.h>

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

}  // namespace
