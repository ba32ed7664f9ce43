// Tests of the per-sensor health report: the expected NIS under the gate, a
// consistent stream of innovations reads ≈ 1, an overconfident or
// over-cautious one is warned about only when it persists, and a silent
// sensor is named.
#include "sensor_health.hpp"

#include <gtest/gtest.h>

#include <random>

#include "chi2.hpp"

namespace {

using mspace::kernel::chi2_quantile;
using mspace::kernel::SensorHealth;

constexpr double kGate = 0.99;

/// NIS of consistent m-row innovations inside the gate (χ²_m draws below the
/// gate's quantile), scaled by `scale` (the filter's S off by that factor).
double draw_nis(std::mt19937_64& rng, int m, double scale) {
  std::normal_distribution<double> normal;
  const double q = chi2_quantile(kGate, m);
  for (;;) {
    double x = 0.0;
    for (int i = 0; i < m; ++i) {
      const double z = normal(rng);
      x += z * z;
    }
    if (x <= q) return scale * x;
  }
}

TEST(SensorHealth, ConsistentInnovationsUnderTheGateReadOne) {
  SensorHealth health("laser", "plugin 'x'", 200, 200, kGate);
  std::mt19937_64 rng(7);
  for (int i = 0; i < 20000; ++i) health.record_update(draw_nis(rng, 1 + i % 3, 1.0), 1 + i % 3);
  const auto report = health.report();
  EXPECT_EQ(report.updates, 20000);
  EXPECT_NEAR(report.nis_ratio, 1.0, 0.03);
  // The truncated mean is below the untruncated one (1 per row).
  EXPECT_LT(report.expected_nis_per_row, 1.0);
  EXPECT_GT(report.expected_nis_per_row, 0.9);
  EXPECT_TRUE(report.warnings.empty());
}

TEST(SensorHealth, PersistentOverconfidenceIsWarnedAboutOnce) {
  SensorHealth health("laser", "plugin 'x'", 200, 200, kGate);
  std::mt19937_64 rng(8);
  // Two bad windows, then a good one: not persistent.
  for (int i = 0; i < 400; ++i) health.record_update(draw_nis(rng, 2, 5.0), 2);
  for (int i = 0; i < 200; ++i) health.record_update(draw_nis(rng, 2, 1.0), 2);
  EXPECT_TRUE(health.take_new_warnings().empty());
  // Three bad windows in a row.
  for (int i = 0; i < 600; ++i) health.record_update(draw_nis(rng, 2, 5.0), 2);
  const std::vector<std::string> warnings = health.take_new_warnings();
  ASSERT_EQ(warnings.size(), 1u);
  EXPECT_NE(warnings[0].find("sensor laser"), std::string::npos) << warnings[0];
  EXPECT_NE(warnings[0].find("overconfident"), std::string::npos) << warnings[0];
  for (int i = 0; i < 2000; ++i) health.record_update(draw_nis(rng, 2, 5.0), 2);
  EXPECT_TRUE(health.take_new_warnings().empty());  // once
  EXPECT_EQ(health.report().warnings.size(), 1u);
}

// Small NIS is a note, not a warning (noise may be inflated on purpose for
// errors correlated from reading to reading).
TEST(SensorHealth, NoiseSetTooLargeIsANote) {
  SensorHealth health("camera", "plugin 'x'", 200, 100, kGate);
  std::mt19937_64 rng(9);
  for (int i = 0; i < 300; ++i) health.record_update(draw_nis(rng, 2, 0.05), 2);
  EXPECT_TRUE(health.take_new_warnings().empty());
  const std::vector<std::string> notes = health.take_new_notes();
  ASSERT_EQ(notes.size(), 1u);
  EXPECT_NE(notes[0].find("set larger than these innovations show"), std::string::npos) << notes[0];
  EXPECT_EQ(health.report().notes.size(), 1u);
  EXPECT_TRUE(health.report().warnings.empty());
}

TEST(SensorHealth, ASilentSensorIsNamedWithItsExtractor) {
  SensorHealth health("camera_lamps", "sensors.camera_lamps.extractor, plugin 'lamps'", 100, 200, kGate);
  for (int i = 0; i < 99; ++i) health.record_reading(0, 0, 0.001);
  EXPECT_TRUE(health.take_new_warnings().empty());
  health.record_reading(0, 0, 0.001);
  const std::vector<std::string> warnings = health.take_new_warnings();
  ASSERT_EQ(warnings.size(), 1u);
  EXPECT_EQ(warnings[0],
            "sensor camera_lamps: 0 measurements in 100 readings — check the extractor's parameters "
            "(sensors.camera_lamps.extractor, plugin 'lamps')");
}

TEST(SensorHealth, MeasurementsThatNeverMatchAreWarnedAbout) {
  SensorHealth health("laser", "plugin 'x'", 50, 200, kGate);
  for (int i = 0; i < 49; ++i) health.record_reading(5, 0, 0.0);
  EXPECT_TRUE(health.take_new_warnings().empty());
  health.record_reading(5, 0, 0.0);
  const std::vector<std::string> warnings = health.take_new_warnings();
  ASSERT_EQ(warnings.size(), 1u);
  EXPECT_NE(warnings[0].find("none of its 250 measurements in 50 readings matched"), std::string::npos)
      << warnings[0];
  // Once something matches, that warning never comes (and this one stays).
  health.record_reading(5, 3, 0.0);
  EXPECT_EQ(health.report().matched, 3);
  EXPECT_EQ(health.report().warnings.size(), 1u);
}

TEST(SensorHealth, SilentSpanZeroNeverWarns) {
  SensorHealth health("laser", "plugin 'x'", 0, 200, kGate);
  for (int i = 0; i < 1000; ++i) health.record_reading(0, 0, 0.0);
  EXPECT_TRUE(health.report().warnings.empty());
}

}  // namespace
