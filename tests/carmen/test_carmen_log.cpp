// Tests of the `carmen_log` data source: FLASER/ODOM/ROBOTLASER1 in CLF and
// GMapping logs, the merged Intel table, no-return ranges, odometry
// increments, malformed lines (error or counted skip) and the real file.
#include <gtest/gtest.h>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <numbers>
#include <sstream>
#include <string>
#include <vector>

#include "carmen_log.hpp"
#include "carmen_reader.hpp"

namespace mspace::carmen_log {
namespace {

constexpr double kPi = std::numbers::pi;

std::filesystem::path write_temp(const std::string& name, const std::string& text) {
  const auto path = std::filesystem::temp_directory_path() / name;
  std::ofstream(path) << text;
  return path;
}

/// "r r r r" with n copies of r.
std::string ranges(int n, const std::string& r) {
  std::string out;
  for (int i = 0; i < n; ++i) out += r + " ";
  return out;
}

PluginArgs args_for(const std::filesystem::path& file, const std::string& on_malformed = "error") {
  PluginArgs a;
  a.instance_name = "source";
  a.params = Params::defaults(CarmenLogSource::param_specs());
  a.params.set("file", file.string());
  a.params.set("on_malformed", on_malformed);
  return a;
}

TEST(CarmenReader, OdometryIncrementIsInThePreviousFrame) {
  const Eigen::Vector3d d = odometry_increment(Pose2(1.0, 1.0, kPi / 2), Pose2(1.0, 3.0, -3.0));
  EXPECT_NEAR(d[0], 2.0, 1e-12);  // straight ahead
  EXPECT_NEAR(d[1], 0.0, 1e-12);
  EXPECT_NEAR(d[2], std::remainder(-3.0 - kPi / 2, 2 * kPi), 1e-12);
}

TEST(CarmenLog, ClfFlaserAndRobotlaser) {
  const std::string flaser1 = "FLASER 4 1.0 81.83 2.0 3.0 9 9 9 0.0 0.0 0.0 100.0 host 100.0\n";
  const std::string flaser2 = "FLASER 4 1.0 1.0 1.0 1.0 9 9 9 1.0 0.0 0.5 101.0 host 101.0\n";
  const std::string robot =
      "ROBOTLASER1 0 -1.5 3.0 1.0 8.0 0.01 0 4 1 9 2 3 0 0 0 0 1.0 1.0 0.5 0 0 0 0 0 102.0 host 102.0\n";
  const auto file = write_temp("mspace_test.clf", "# CLF\nPARAM x y\nODOM 0 0 0 0 0 0 99.9 host 99.9\n" +
                                                     flaser1 + flaser2 + robot);
  CarmenLogSource source(args_for(file));
  EXPECT_EQ(source.size_hint(), 3u);
  EXPECT_EQ(source.contents().variant, Variant::Clf);
  DataStep s;
  ASSERT_TRUE(source.next(s));
  EXPECT_DOUBLE_EQ(s.t, 100.0);
  EXPECT_EQ(s.odometry.size(), 0);
  EXPECT_FALSE(s.ground_truth);
  ASSERT_EQ(s.readings.size(), 1u);
  const Eigen::MatrixXd& v = s.readings[0].values;
  ASSERT_EQ(v.rows(), 4);
  EXPECT_DOUBLE_EQ(v(1, 0), 0.0);           // 81.83: no return
  EXPECT_NEAR(v(0, 1), -kPi / 2, 1e-12);   // 4 beams over 180°: −90°, −45°, 0°, 45°
  EXPECT_NEAR(v(3, 1), kPi / 4, 1e-12);
  ASSERT_TRUE(source.next(s));
  EXPECT_NEAR(s.odometry[0], 1.0, 1e-12);
  EXPECT_NEAR(s.odometry[2], 0.5, 1e-12);
  ASSERT_TRUE(source.next(s));  // ROBOTLASER1: robot pose (1, 1, 0.5), own angles, max range 8
  EXPECT_NEAR(s.odometry[0], std::sin(0.5), 1e-12);  // (0, 1) seen from heading 0.5
  EXPECT_NEAR(s.odometry[1], std::cos(0.5), 1e-12);
  EXPECT_NEAR(s.readings[0].values(0, 1), -1.5, 1e-12);
  EXPECT_NEAR(s.readings[0].values(3, 1), 1.5, 1e-12);
  EXPECT_DOUBLE_EQ(s.readings[0].values(3, 0), 3.0);
  EXPECT_FALSE(source.next(s));
}

TEST(CarmenLog, GMappingVariantUsesCorrectedPoseAsGroundTruth) {
  const auto file = write_temp(
      "mspace_test.gfs.log",
      "ODOM 1 0 0 0 0 0 1.0 pippo 1.0\nFLASER 2 1 1 5 6 0.1 5 6 0.1 1.5 pippo 1.5\nNEFF 30 1.5 pippo 1.5\n"
      "ODOM 2 0 0 0 0 0 2.0 pippo 2.0\nFLASER 2 1 1 7 6 0.2 7 6 0.2 2.5 pippo 2.5\n");
  PluginArgs a = args_for(file);
  a.params.set("time_offset", 1000.0);
  CarmenLogSource source(a);
  EXPECT_EQ(source.contents().variant, Variant::GMapping);
  DataStep s;
  ASSERT_TRUE(source.next(s));
  EXPECT_DOUBLE_EQ(s.t, 1001.5);
  ASSERT_TRUE(s.ground_truth);
  EXPECT_DOUBLE_EQ((*s.ground_truth)[kX], 5.0);
  EXPECT_DOUBLE_EQ(source.initial_pose()[kX], 5.0);
  ASSERT_TRUE(source.next(s));
  EXPECT_NEAR(s.odometry[0], 1.0, 1e-12);  // from the ODOM lines
}

TEST(CarmenLog, MalformedLineIsAnErrorOrACountedSkip) {
  const std::string good = "1.0 0 0 0 0 0 0 " + ranges(180, "2.0") + "\n";
  const std::string bad = "2.0 0 0 0 0 0 0 " + ranges(179, "2.0") + "oops\n";
  const auto file = write_temp("mspace_test_table.txt", "# table\n" + good + bad + good);
  try {
    CarmenLogSource source(args_for(file));
    FAIL() << "expected an error";
  } catch (const std::runtime_error& e) {
    EXPECT_NE(std::string(e.what()).find("mspace_test_table.txt:3: "), std::string::npos) << e.what();
    EXPECT_NE(std::string(e.what()).find("'oops'"), std::string::npos) << e.what();
  }
  CarmenLogSource skipping(args_for(file, "skip"));
  EXPECT_EQ(skipping.contents().skipped, 1u);
  EXPECT_EQ(skipping.size_hint(), 2u);
  const auto truncated = write_temp("mspace_test.clf2", "FLASER 180 1 2 3\n");
  EXPECT_THROW(CarmenLogSource{args_for(truncated)}, std::runtime_error);
}

TEST(CarmenLog, IntelTable) {
  const std::filesystem::path file =
      std::filesystem::path(MSPACE_SOURCE_DIR) / "../shared/datasets/intel_lab/intel_910_scans.txt";
  if (!std::filesystem::exists(file)) GTEST_SKIP() << file << " not found; skipping";
  CarmenLogSource source(args_for(file));
  EXPECT_EQ(source.size_hint(), 910u);
  EXPECT_EQ(source.contents().format, Format::Table);
  // Starts at the first GMapping pose (0.600266, −0.0320327, −0.354665).
  EXPECT_NEAR(source.initial_pose()[kX], 0.600266, 1e-9);
  EXPECT_NEAR(source.initial_pose()[kTheta], -0.354665, 1e-9);
  DataStep s;
  Pose2 odo(0.698, -0.015, -0.463373);  // first odometry pose
  int steps = 0, no_returns = 0;
  while (source.next(s)) {
    ++steps;
    ASSERT_TRUE(s.ground_truth);
    const Eigen::MatrixXd& v = s.readings.at(0).values;
    ASSERT_EQ(v.rows(), 180);
    EXPECT_NEAR(v(90, 1), 0.0, 1e-12);  // beam 90 straight ahead
    no_returns += static_cast<int>((v.col(0).array() == 0.0).count());
    if (s.odometry.size() == 3) {  // re-integrating the increments gives the odometry back
      const double c = std::cos(odo[2]), sn = std::sin(odo[2]);
      odo = Pose2(odo[0] + c * s.odometry[0] - sn * s.odometry[1], odo[1] + sn * s.odometry[0] + c * s.odometry[1],
                  odo[2] + s.odometry[2]);
    }
  }
  EXPECT_EQ(steps, 910);
  EXPECT_GT(no_returns, 0);
  const Scan& last = source.contents().scans.back();
  EXPECT_NEAR(odo[0], last.odometry[0], 1e-9);
  EXPECT_NEAR(odo[1], last.odometry[1], 1e-9);
  EXPECT_NEAR(std::remainder(odo[2] - last.odometry[2], 2 * kPi), 0.0, 1e-9);
}


// The source against the file itself, read here independently: every step's
// time stamp is the table's t_abs, and dead reckoning the delivered
// increments (⊖pose(k−1) ⊕ pose(k), in the previous pose's frame) gives back
// the table's raw odometry pose at every scan, not only the last.
TEST(CarmenLog, IntelTableTimesAndOdometryMatchTheFile) {
  const std::filesystem::path file =
      std::filesystem::path(MSPACE_SOURCE_DIR) / "../shared/datasets/intel_lab/intel_910_scans.txt";
  if (!std::filesystem::exists(file)) GTEST_SKIP() << file << " not found; skipping";
  std::vector<Eigen::Vector4d> rows;  // t, odom x, y, θ
  std::ifstream in(file);
  for (std::string line; std::getline(in, line);) {
    if (line.empty() || line[0] == '#') continue;
    std::istringstream fields(line);
    Eigen::Vector4d r;
    fields >> r[0] >> r[1] >> r[2] >> r[3];
    rows.push_back(r);
  }
  ASSERT_EQ(rows.size(), 910u);
  EXPECT_NEAR(rows.front()[0], 976052890.244, 1e-3);
  EXPECT_NEAR(rows.back()[0], 976055541.103, 1e-3);

  CarmenLogSource source(args_for(file));
  DataStep s;
  Pose2 odo = rows.front().tail<3>();
  double prev_t = -1.0;
  for (std::size_t k = 0; source.next(s); ++k) {
    ASSERT_LT(k, rows.size());
    EXPECT_DOUBLE_EQ(s.t, rows[k][0]) << "scan " << k;
    EXPECT_GT(s.t, prev_t) << "scan " << k;
    prev_t = s.t;
    if (k == 0) {
      EXPECT_EQ(s.odometry.size(), 0);
      continue;
    }
    ASSERT_EQ(s.odometry.size(), 3);
    const double c = std::cos(odo[2]), sn = std::sin(odo[2]);
    odo = Pose2(odo[0] + c * s.odometry[0] - sn * s.odometry[1], odo[1] + sn * s.odometry[0] + c * s.odometry[1],
                std::remainder(odo[2] + s.odometry[2], 2 * kPi));
    ASSERT_NEAR(odo[0], rows[k][1], 1e-9) << "scan " << k;
    ASSERT_NEAR(odo[1], rows[k][2], 1e-9) << "scan " << k;
    ASSERT_NEAR(std::remainder(odo[2] - rows[k][3], 2 * kPi), 0.0, 1e-9) << "scan " << k;
  }
}

}  // namespace
}  // namespace mspace::carmen_log
