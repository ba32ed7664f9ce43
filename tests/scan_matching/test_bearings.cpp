// Bearings of laser points (sensors_plugins/scan_matching/bearings.hpp): the
// approximation's error bound, and every comparison, wrap and index look-up
// giving exactly what std::atan2, std::remainder and std::lower_bound give.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <numbers>
#include <random>
#include <vector>

#include "bearings.hpp"

namespace sm = mspace::scan_matching;
namespace {

constexpr double kPi = std::numbers::pi;

/// Points in every direction at ranges 1 mm – 100 m, the axes and the
/// diagonals (±0 included).
std::vector<std::pair<double, double>> points(int count, std::mt19937_64& rng) {
  std::uniform_real_distribution<double> angle(-kPi, kPi), log_range(-3.0, 2.0);
  std::vector<std::pair<double, double>> out;
  for (int i = 0; i < count; ++i) {
    const double a = angle(rng), r = std::pow(10.0, log_range(rng));
    out.emplace_back(r * std::cos(a), r * std::sin(a));
  }
  for (double x : {-1.0, -0.0, 0.0, 1.0})
    for (double y : {-1.0, -0.0, 0.0, 1.0})
      if (x != 0.0 || y != 0.0) out.emplace_back(x, y);
  return out;
}

TEST(ScanBearings, ApproximationIsWithinAQuarterOfTheMarginItIsTrustedTo) {
  std::mt19937_64 rng(1);
  double worst = 0.0;
  for (const auto& [x, y] : points(1000000, rng))
    worst = std::max(worst, std::abs(sm::approximate_atan2(y, x) - std::atan2(y, x)));
  std::printf("approximate atan2: largest error %.3g rad (margin %.3g)\n", worst,
              sm::Bearing::kApproximationMargin);
  EXPECT_LE(worst, 0.25 * sm::Bearing::kApproximationMargin);
  EXPECT_TRUE(std::isnan(sm::approximate_atan2(0.0, 0.0)));
}

TEST(ScanBearings, ComparisonsAreStdAtan2sEvenAtTheThreshold) {
  std::mt19937_64 rng(2);
  std::uniform_real_distribution<double> offset(-1e-4, 1e-4);
  const std::vector<double> tiny{0.0, 1e-16, -1e-16, 4e-16, -4e-16, 1e-12, -1e-12};
  int cases = 0;
  for (const auto& [x, y] : points(20000, rng)) {
    const double b = std::atan2(y, x);
    std::vector<double> thresholds{b, std::nextafter(b, 4.0), std::nextafter(b, -4.0), b + offset(rng)};
    for (double t : tiny) thresholds.push_back(b + t);
    for (double c : thresholds) {
      const sm::Bearing bearing(x, y);
      EXPECT_EQ(bearing.below(c), b < c);
      EXPECT_EQ(bearing.above(c), b > c);
      EXPECT_EQ(bearing.at_least(c), b >= c);
      EXPECT_EQ(bearing.at_most(c), b <= c);
      const double limit = std::abs(offset(rng)) * 50.0;  // up to 5e-3 rad, a 0.25° beam
      for (double other : {c + limit, c - limit, c + limit + 1e-15, c - limit - 1e-15, c + kPi, c - 2.0 * kPi + limit})
        EXPECT_EQ(bearing.farther_than(other, limit), std::abs(sm::wrap(other - b)) > limit);
      EXPECT_EQ(bearing.exact(), b);
      ++cases;
    }
    const sm::Bearing far(x, y);  // far from the threshold
    EXPECT_TRUE(far.below(b + 1e-3));
    EXPECT_TRUE(far.above(b - 1e-3));
  }
  EXPECT_GT(cases, 0);
}

TEST(ScanBearings, WrapIsStdRemainder) {
  std::mt19937_64 rng(3);
  std::uniform_real_distribution<double> a(-20.0, 20.0);
  std::vector<double> values{kPi, -kPi, std::nextafter(kPi, 4.0), std::nextafter(-kPi, -4.0), 0.0, -0.0,
                             2.0 * kPi, -2.0 * kPi, 3.0 * kPi};
  for (int i = 0; i < 100000; ++i) values.push_back(a(rng));
  for (double v : values) {
    const double expected = std::remainder(v, 2.0 * kPi), got = sm::wrap(v);
    EXPECT_EQ(got, expected) << v;
    EXPECT_EQ(std::signbit(got), std::signbit(expected)) << v;
  }
}

TEST(ScanBearings, IndexLookUpIsStdLowerBound) {
  std::mt19937_64 rng(4);
  std::uniform_real_distribution<double> angle(-kPi, kPi), jitter(-2e-3, 2e-3);
  auto check = [&](std::vector<double> bearings, const char* what) {
    std::sort(bearings.begin(), bearings.end());
    const sm::BearingIndex index(bearings);
    std::vector<std::pair<double, double>> queries = points(20000, rng);
    for (double b : bearings)  // points exactly on (and just beside) each bearing
      for (double d : {0.0, 1e-9, -1e-9}) queries.emplace_back(std::cos(b + d), std::sin(b + d));
    for (const auto& [x, y] : queries) {
      const double b = std::atan2(y, x);
      const auto expected = static_cast<std::size_t>(std::lower_bound(bearings.begin(), bearings.end(), b) -
                                                     bearings.begin());
      ASSERT_EQ(index.first_not_below(sm::Bearing(x, y)), expected) << what << " at " << b;
    }
  };
  std::vector<double> laser;  // 1080 beams, 0.25°, 270°, some dropped
  for (int i = 0; i < 1080; ++i)
    if (i % 7 != 3) laser.push_back(std::atan2(std::sin(-0.75 * kPi + i * kPi / 720), std::cos(-0.75 * kPi + i * kPi / 720)));
  check(laser, "laser");
  std::vector<double> interleaved;  // 1° beams from three start angles 0.25° apart, each start twice (duplicates)
  for (int i = 0; i < 181; ++i)
    for (int k = 0; k < 6; ++k) interleaved.push_back(-0.5 * kPi + i * kPi / 180 + (k % 3) * kPi / 720);
  check(interleaved, "interleaved");
  std::vector<double> random;
  for (int i = 0; i < 300; ++i) random.push_back(i < 150 ? angle(rng) : 0.3 + jitter(rng));
  check(random, "random, clustered");
  check({0.5}, "one beam");
  check({}, "no beam");
}

}  // namespace
