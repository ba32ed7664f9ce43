// Tests of the `victoria_park` source on small files written here: clocks,
// the merged step sequence with held controls, bearing conversion, GPS as
// position-only ground truth, and errors that name file and line.
#include <gtest/gtest.h>

#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <numbers>
#include <string>

#include "build_path.hpp"
#include "victoria_park.hpp"

namespace mspace::victoria_park {
namespace {

namespace fs = std::filesystem;

class VictoriaParkFiles : public ::testing::Test {
 protected:
  void SetUp() override {
    // One folder per test: CTest runs the cases as parallel processes.
    dir_ = fs::path(MSPACE_BINARY_DIR) / "test-output" / "victoria_park_source" /
           ::testing::UnitTest::GetInstance()->current_test_info()->name();
    fs::remove_all(dir_);
    fs::create_directories(dir_ / "text");
    fs::create_directories(dir_ / "rfs_slam");
    // Vehicle clock in ms (origin 20967 ms); .dat file in s since the origin.
    write("text/aa3_dr.txt", "# comment\n21967 1.0 0.1\r\n21992 2.0 0.2\n22017 3.0 0.3\n");
    write("text/aa3_gpsx.txt", "# comment\n20967 -67.6 -41.7\n22000 -66.0 -40.0\n");
    write("rfs_slam/measurements.dat",
          "  1.010 10.0 1.5707963267948966 0.3\n  1.010 20.0 0.0 0.5\n  1.040 5.0 3.0 0.2\n");
  }
  void write(const std::string& name, const std::string& text) { std::ofstream(dir_ / name) << text; }
  fs::path dir_;
};

TEST_F(VictoriaParkFiles, StepsMergeAllClocksWithHeldControls) {
  VictoriaParkSource source(dir_, "laser");
  // Step times: GPS 0.0, DR 1.0, scan 1.01, DR 1.025, GPS 1.033, scan 1.04, DR 1.05.
  EXPECT_EQ(source.size_hint(), 7u);
  DataStep step;
  ASSERT_TRUE(source.next(step));
  EXPECT_DOUBLE_EQ(step.t, 0.0);
  EXPECT_EQ(step.odometry.size(), 0);  // before the first dead-reckoning sample
  ASSERT_TRUE(step.ground_truth.has_value());
  EXPECT_DOUBLE_EQ((*step.ground_truth)[kX], -67.6);
  EXPECT_EQ(step.ground_truth_known, (1u << kX) | (1u << kY));

  ASSERT_TRUE(source.next(step));
  EXPECT_DOUBLE_EQ(step.t, 1.0);
  EXPECT_EQ(step.odometry.size(), 0);  // the first sample only starts here

  ASSERT_TRUE(source.next(step));
  EXPECT_DOUBLE_EQ(step.t, 1.01);
  EXPECT_EQ(step.odometry, Eigen::Vector2d(1.0, 0.1));
  ASSERT_EQ(step.readings.size(), 1u);
  EXPECT_EQ(step.readings[0].channel, "laser");
  ASSERT_EQ(step.readings[0].values.rows(), 2);
  // Bearing π/2 (straight ahead in the file) → 0; bearing 0 (right) → −π/2.
  EXPECT_NEAR(step.readings[0].values(0, 1), 0.0, 1e-15);
  EXPECT_NEAR(step.readings[0].values(1, 1), -std::numbers::pi / 2, 1e-15);
  EXPECT_EQ(step.readings[0].values(1, 2), 0.5);
  EXPECT_FALSE(step.ground_truth.has_value());

  ASSERT_TRUE(source.next(step));  // 1.025: still the controls of the sample at 1.0
  EXPECT_DOUBLE_EQ(step.t, 1.025);
  EXPECT_EQ(step.odometry, Eigen::Vector2d(1.0, 0.1));
  ASSERT_TRUE(source.next(step));  // 1.033: GPS, controls of the sample at 1.025
  EXPECT_DOUBLE_EQ(step.t, 1.033);
  EXPECT_EQ(step.odometry, Eigen::Vector2d(2.0, 0.2));
  EXPECT_TRUE(step.ground_truth.has_value());
  ASSERT_TRUE(source.next(step));
  EXPECT_DOUBLE_EQ(step.t, 1.04);
  ASSERT_TRUE(source.next(step));
  EXPECT_DOUBLE_EQ(step.t, 1.05);
  EXPECT_EQ(step.odometry, Eigen::Vector2d(2.0, 0.2));
  EXPECT_FALSE(source.next(step));
}

TEST_F(VictoriaParkFiles, MalformedLinesNameFileAndLine) {
  write("text/aa3_dr.txt", "21967 1.0 0.1\n21992 2.0\n");
  try {
    VictoriaParkSource source(dir_, "laser");
    FAIL() << "no error";
  } catch (const std::runtime_error& e) {
    EXPECT_EQ(std::string(e.what()),
              (dir_ / "text" / "aa3_dr.txt").string() +
                  ":2: expected 3 numbers (time_ms speed_mps steering_rad), found 2 fields");
  }
  write("text/aa3_dr.txt", "21967 1.0 0.1\n");
  write("rfs_slam/measurements.dat", "1.0 10 1.0 0.3\n0.5 10 1.0 abc\n");
  EXPECT_THROW(
      {
        try {
          VictoriaParkSource source(dir_, "laser");
        } catch (const std::runtime_error& e) {
          EXPECT_NE(std::string(e.what()).find("measurements.dat:2: field 4 'abc' is not a finite number"),
                    std::string::npos)
              << e.what();
          throw;
        }
      },
      std::runtime_error);
  write("rfs_slam/measurements.dat", "1.0 10 1.0 0.3\n0.5 10 1.0 0.3\n");
  EXPECT_THROW(VictoriaParkSource(dir_, "laser"), std::runtime_error);  // time goes backwards
  EXPECT_THROW(VictoriaParkSource(dir_ / "missing", "laser"), std::runtime_error);
}

TEST(VictoriaParkGps, IsolatedFixesAreLeftOut) {
  // Fixes at 0, 1, 5 (alone: 4 s either side), 9, 9.5, 20 (alone).
  const std::vector<GpsFix> fixes{{0, 0, 0}, {1, 1, 0}, {5, 140, 0}, {9, 2, 0}, {9.5, 3, 0}, {20, 4, 0}};
  const std::vector<GpsFix> kept = without_isolated_fixes(fixes, 2.0);
  ASSERT_EQ(kept.size(), 4u);
  EXPECT_EQ(kept[0].t, 0.0);
  EXPECT_EQ(kept[1].t, 1.0);
  EXPECT_EQ(kept[2].t, 9.0);
  EXPECT_EQ(kept[3].t, 9.5);
  EXPECT_EQ(without_isolated_fixes(fixes, 4.0).size(), 5u);  // 5 s now has neighbours; 20 s has not
}

TEST_F(VictoriaParkFiles, IsolatedGpsFixesAreNotDelivered) {
  // The two fixes of the files are 1.033 s apart: both kept with a 2 s gap, both isolated with 1 s.
  EXPECT_EQ(VictoriaParkSource(dir_, "laser", 2.0).gps().size(), 2u);
  const VictoriaParkSource strict(dir_, "laser", 1.0);
  EXPECT_EQ(strict.gps().size(), 0u);
  EXPECT_EQ(strict.isolated_fixes(), 2u);
}

TEST(VictoriaParkPaths, EnvironmentDefaultsExpand) {
  ::unsetenv("MSPACE_TEST_UNSET_VAR");
  EXPECT_EQ(expand_environment("${MSPACE_TEST_UNSET_VAR:-../shared}/vp"), "../shared/vp");
  ::setenv("MSPACE_TEST_SET_VAR", "/data", 1);
  EXPECT_EQ(expand_environment("${MSPACE_TEST_SET_VAR:-../shared}/vp"), "/data/vp");
  EXPECT_THROW(expand_environment("${MSPACE_TEST_UNSET_VAR}/vp"), std::invalid_argument);
}

}  // namespace
}  // namespace mspace::victoria_park
