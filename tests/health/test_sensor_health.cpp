// Tests of the per-sensor health report: the expected NIS under the gate, a
// consistent stream of innovations reads ≈ 1, an overconfident or
// over-cautious one is warned about only when it persists, and a silent
// sensor is named.
#include "sensor_health.hpp"

#include <gtest/gtest.h>

#include <Eigen/Cholesky>
#include <Eigen/LU>
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

// Noise from data: innovations drawn from S = A + k² R while the filter
// believes S = A + R. The statistics of their kind find k (the σ factor that
// makes them consistent), to within the sampling error of 4000 updates.
TEST(SensorHealth, PerKindStatisticsFindTheSigmaFactorOfTheMeasurementNoise) {
  std::mt19937_64 rng(11);
  std::normal_distribution<double> normal;
  auto draw = [&](const Eigen::MatrixXd& cov) {
    Eigen::VectorXd z(cov.rows());
    for (Eigen::Index i = 0; i < z.size(); ++i) z[i] = normal(rng);
    return Eigen::VectorXd(cov.llt().matrixL() * z);
  };
  for (const double k_true : {0.5, 2.0}) {
    SensorHealth health("camera", "plugin 'x'", 200, 200, 0.999999);
    mspace::kernel::UpdateInnovation u;
    u.kind = "bearing";
    u.robot_columns = 1;
    u.J_state = Eigen::MatrixXd::Identity(2, 3);
    u.J_state(1, 2) = 1.0;  // robot column 0, feature columns 1 and 2
    u.P = Eigen::Vector3d(0.02, 0.01, 0.01).asDiagonal();
    u.R = Eigen::Vector2d(0.04, 0.09).asDiagonal();
    const Eigen::MatrixXd A = u.J_state * u.P * u.J_state.transpose();
    for (int i = 0; i < 4000; ++i) {
      u.eta = draw(A + k_true * k_true * u.R);
      health.record_update(u);
    }
    const auto report = health.report();
    ASSERT_EQ(report.kinds.size(), 1u);
    const mspace::kernel::KindNisReport& k = report.kinds[0];
    EXPECT_EQ(k.kind, "bearing");
    EXPECT_EQ(k.updates, 4000);
    EXPECT_EQ(k.rows, 8000);
    EXPECT_EQ(k.true_pose_updates, 0);  // no robot error given
    EXPECT_EQ(k.sigma_scale_beyond, 0);
    EXPECT_NEAR(k.sigma_scale, k_true, 0.06 * k_true);
    EXPECT_NEAR(k.nis_ratio, report.nis_ratio, 1e-12);  // one kind: the sensor's figure
  }
}

// With the robot's true pose: the robot's error, and the feature's error
// correlated with it, come out of the innovation. A robot error the filter
// does not know of (a bias) inflates the plain NIS but not the one given the
// true pose, which still finds the measurement noise's k.
TEST(SensorHealth, TheTruePoseTakesTheRobotsErrorOut) {
  std::mt19937_64 rng(12);
  std::normal_distribution<double> normal;
  SensorHealth health("camera", "plugin 'x'", 200, 200, 0.999999);
  mspace::kernel::UpdateInnovation u;
  u.kind = "bearing";
  u.robot_columns = 1;
  u.J_state = Eigen::MatrixXd::Identity(2, 3);
  u.J_state(1, 2) = 1.0;
  // Feature error correlated with the robot's (ρ = 0.8 between columns 0 and 1).
  u.P = Eigen::Vector3d(0.02, 0.02, 0.01).asDiagonal();
  u.P(0, 1) = u.P(1, 0) = 0.016;
  u.R = Eigen::Vector2d(0.04, 0.09).asDiagonal();
  const double k_true = 1.5, bias = 0.5;  // robot error N(bias, 0.02): far beyond its σ 0.14
  const Eigen::LLT<Eigen::MatrixXd> P_llt(u.P);
  for (int i = 0; i < 4000; ++i) {
    Eigen::Vector3d e = P_llt.matrixL() * Eigen::Vector3d(normal(rng), normal(rng), normal(rng));
    e[0] += bias;
    e[1] += u.P(0, 1) / u.P(0, 0) * bias;  // the feature's error follows the robot's, as P says
    const Eigen::Vector2d noise(k_true * 0.2 * normal(rng), k_true * 0.3 * normal(rng));
    u.eta = noise - u.J_state * e;  // η(x̂) = η(x) − J e, e = x − x̂
    u.robot_error = e.head<1>();
    health.record_update(u);
  }
  const mspace::kernel::KindNisReport k = health.report().kinds.at(0);
  EXPECT_EQ(k.true_pose_updates, 4000);
  EXPECT_GT(k.nis_ratio, 3.0);  // the bias: overconfident
  EXPECT_NEAR(k.sigma_scale_true_pose, k_true, 0.06 * k_true);
  // Given the robot's error the feature's has P_ff − P_fr P_rr⁻¹ P_rf; with
  // the measurement noise k² R, E[NIS] = tr(S'⁻¹ (A' + k² R)), S' = A' + R.
  const Eigen::MatrixXd J_f = u.J_state.rightCols(2);
  const Eigen::MatrixXd P_f = u.P.bottomRightCorner(2, 2) - u.P.block(1, 0, 2, 1) * u.P.block(0, 1, 1, 2) / u.P(0, 0);
  const Eigen::MatrixXd A = J_f * P_f * J_f.transpose();
  const double expected = (A + u.R).inverse().cwiseProduct(A + k_true * k_true * u.R).sum() / 2.0;
  EXPECT_NEAR(k.nis_ratio_true_pose, expected, 0.06 * expected);
}
