// Tests of the `rosbag` data source: bags written with ROS's own library from
// the Intel log and from a simulated building replay step for step as the
// original files do through `carmen_log` (same readings up to the float32 of
// sensor_msgs/LaserScan, the same odometry), and bad bags get errors naming
// the file and topic.
#include <gtest/gtest.h>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <limits>
#include <numbers>
#include <string>

#include "bag_writer.hpp"
#include "building_log.hpp"
#include "carmen_log.hpp"
#include "carmen_reader.hpp"
#include "rosbag_source.hpp"

namespace mspace::rosbag_test {
namespace {

namespace fs = std::filesystem;

fs::path temp_dir(const std::string& name) {
  const fs::path dir = fs::temp_directory_path() / ("mspace_rosbag_" + name);
  fs::remove_all(dir);
  fs::create_directories(dir);
  return dir;
}

PluginArgs bag_args(const fs::path& bag) {
  PluginArgs a;
  a.instance_name = "source";
  a.params = Params::defaults(rosbag_source::RosbagSource::param_specs());
  a.params.set("file", bag.string());
  return a;
}

PluginArgs carmen_args(const fs::path& file) {
  PluginArgs a;
  a.instance_name = "source";
  a.params = Params::defaults(carmen_log::CarmenLogSource::param_specs());
  a.params.set("file", file.string());
  return a;
}

/// Steps of both sources are the same: time (ros::Time keeps ns), odometry
/// increment, covariance, ground truth; ranges to float32 rounding (the
/// LaserScan message stores float32: relative 2^-24), bearings to the float32
/// rounding of angle_min and angle_increment times the beam count.
void expect_same_steps(DataSource& original, DataSource& bag, double increment_tolerance) {
  EXPECT_EQ(original.size_hint(), bag.size_hint());
  EXPECT_LT((original.initial_pose() - bag.initial_pose()).norm(), 1e-12);
  DataStep a, b;
  std::size_t steps = 0;
  while (original.next(a)) {
    ASSERT_TRUE(bag.next(b)) << "the bag ends at step " << steps;
    ASSERT_NEAR(a.t, b.t, 1e-6) << "step " << steps;
    ASSERT_EQ(a.odometry.size(), b.odometry.size()) << "step " << steps;
    if (a.odometry.size() > 0) {
      ASSERT_LT((a.odometry - b.odometry).cwiseAbs().maxCoeff(), increment_tolerance) << "step " << steps;
    }
    ASSERT_EQ(a.odometry_covariance.size(), b.odometry_covariance.size()) << "step " << steps;
    ASSERT_EQ(a.ground_truth.has_value(), b.ground_truth.has_value()) << "step " << steps;
    if (a.ground_truth) {
      Pose6 d = *a.ground_truth - *b.ground_truth;
      for (int k = 3; k < 6; ++k) d[k] = std::remainder(d[k], 2.0 * std::numbers::pi);  // ±π is one angle
      ASSERT_LT(d.norm(), 1e-9) << "step " << steps;
    }
    ASSERT_EQ(a.readings.size(), 1U);
    ASSERT_EQ(b.readings.size(), 1U);
    const Eigen::MatrixXd& ra = a.readings[0].values;
    const Eigen::MatrixXd& rb = b.readings[0].values;
    ASSERT_EQ(ra.rows(), rb.rows()) << "step " << steps;
    EXPECT_EQ(a.readings[0].channel, b.readings[0].channel);
    for (Eigen::Index i = 0; i < ra.rows(); ++i) {
      ASSERT_NEAR(ra(i, 0), rb(i, 0), ra(i, 0) * 6e-8) << "step " << steps << " beam " << i;
      ASSERT_NEAR(ra(i, 1), rb(i, 1), 1e-7 * double(ra.rows())) << "step " << steps << " beam " << i;
    }
    ++steps;
  }
  EXPECT_FALSE(bag.next(b)) << "the bag has more steps than the original's " << steps;
  EXPECT_GT(steps, 10U);
}

TEST(Rosbag, IntelLogReplaysAsTheTable) {
  const fs::path table = fs::path(MSPACE_SOURCE_DIR) / "../shared/datasets/intel_lab/intel_910_scans.txt";
  if (!fs::exists(table)) GTEST_SKIP() << table << " is absent (the Intel data set): nothing to compare";
  carmen_log::ReaderOptions reader;
  reader.no_return_range = 81.0;
  const carmen_log::LogContents log = carmen_log::read_log(table, reader);
  const fs::path bag = temp_dir("intel") / "intel.bag";
  write_bag(log, bag, {.odometry_on_tf = false, .static_mount = std::nullopt, .ground_truth = true});

  PluginArgs c = carmen_args(table);
  c.params.set("no_return_range", 81.0);
  PluginArgs r = bag_args(bag);
  r.params.set("ground_truth_topic", std::string("/ground_truth"));
  carmen_log::CarmenLogSource original(c);
  rosbag_source::RosbagSource from_bag(r);
  expect_same_steps(original, from_bag, 1e-9);
}

/// A short simulated building (CARMEN log with a laser mount and ground truth).
struct Building {
  fs::path dir;
  carmen_log::LogContents log;
};

/// In a folder of its own per test (CTest runs the tests in parallel).
Building building(const std::string& name) {
  sim_building::GeneratorSettings settings;
  settings.route.length_m = 40.0;
  Building b{temp_dir(name), {}};
  sim_building::write_data_set(sim_building::simulate(settings), b.dir);
  PluginArgs c = carmen_args(b.dir / "building.clf");
  c.params.set("ground_truth", (b.dir / "ground_truth.tum").string());
  b.log = carmen_log::CarmenLogSource(c).contents();
  return b;
}

TEST(Rosbag, SimulatedBuildingOnTfReplaysAsTheClf) {
  const Building b = building("building_tf");
  ASSERT_TRUE(b.log.laser.offset.has_value());
  const fs::path bag = b.dir / "building.bag";
  write_bag(b.log, bag, {.odometry_on_tf = true, .static_mount = b.log.laser.offset, .ground_truth = true});
  PluginArgs c = carmen_args(b.dir / "building.clf");
  c.params.set("ground_truth", (b.dir / "ground_truth.tum").string());
  PluginArgs r = bag_args(bag);
  r.params.set("odometry_topic", std::string("/tf"));
  r.params.set("ground_truth_topic", std::string("/ground_truth"));
  carmen_log::CarmenLogSource original(c);
  rosbag_source::RosbagSource from_bag(r);
  // The mount comes from /tf_static and is reported as the recorded one.
  const std::vector<RecordedMount> mounts = from_bag.recorded_mounts();
  ASSERT_EQ(mounts.size(), 1U);
  EXPECT_LT((mounts[0].mount - original.recorded_mounts().at(0).mount).norm(), 1e-12);
  EXPECT_NE(mounts[0].origin.find("/tf_static"), std::string::npos) << mounts[0].origin;
  expect_same_steps(original, from_bag, 1e-9);
}

TEST(Rosbag, LaserOdometryFromTheBagMatchesTheClfs) {
  const Building b = building("building_scan_matched");
  const fs::path bag = b.dir / "building.bag";
  write_bag(b.log, bag, {.odometry_on_tf = false, .static_mount = b.log.laser.offset, .ground_truth = false});
  PluginArgs c = carmen_args(b.dir / "building.clf");
  c.params.set("ground_truth", std::string("none"));
  c.params.set("odometry", std::string("scan_matched"));
  c.params.set("scan_match_covariance", true);
  PluginArgs r = bag_args(bag);
  r.params.set("odometry", std::string("scan_matched"));
  r.params.set("scan_match_covariance", true);
  carmen_log::CarmenLogSource original(c);
  rosbag_source::RosbagSource from_bag(r);
  // The matches see float32 ranges: increments agree to far below the
  // matcher's own error (mm), not bit for bit.
  expect_same_steps(original, from_bag, 1e-4);
}

// --- bad bags -------------------------------------------------------------

std::string error_of(const fs::path& bag, const std::string& key = "", const std::string& value = "") {
  PluginArgs r = bag_args(bag);
  if (!key.empty()) r.params.set(key, value);
  try {
    rosbag_source::RosbagSource source(r);
  } catch (const std::exception& e) {
    return e.what();
  }
  return "(no error)";
}

/// A bag with n scans on /scan and n odometry messages on /odom, stamps t0 + i.
fs::path small_bag(const std::string& name, int n = 5) {
  carmen_log::LogContents log;
  log.laser.no_return = 30.0;
  for (int i = 0; i < n; ++i) {
    carmen_log::Scan s;
    s.t = 100.0 + i;
    s.odometry = Eigen::Vector3d(0.1 * i, 0.0, 0.0);
    s.ranges = {1.0, 2.0, 0.0};
    s.bearings = {-0.5, 0.0, 0.5};
    log.scans.push_back(s);
  }
  const fs::path bag = temp_dir(name) / (name + ".bag");
  write_bag(log, bag, {});
  return bag;
}

TEST(RosbagErrors, MissingTopicListsTheBagsTopics) {
  const fs::path bag = small_bag("missing");
  const std::string e = error_of(bag, "scan_topic", "/base_scan");
  EXPECT_NE(e.find(bag.string()), std::string::npos) << e;
  EXPECT_NE(e.find("scan_topic /base_scan is not in the bag"), std::string::npos) << e;
  EXPECT_NE(e.find("/scan (sensor_msgs/LaserScan)"), std::string::npos) << e;
  EXPECT_NE(e.find("/odom (nav_msgs/Odometry)"), std::string::npos) << e;
}

TEST(RosbagErrors, WrongMessageTypeNamesExpectedAndFound) {
  const fs::path bag = small_bag("wrong_type");
  const std::string e = error_of(bag, "scan_topic", "/odom");
  EXPECT_NE(e.find(bag.string()), std::string::npos) << e;
  EXPECT_NE(e.find("scan_topic /odom carries nav_msgs/Odometry, expected sensor_msgs/LaserScan"), std::string::npos)
      << e;
}

TEST(RosbagErrors, OutOfOrderStampsNameMessageAndStamp) {
  const fs::path bag = temp_dir("order") / "order.bag";
  write_stamped_scans(bag, {10.0, 11.0, 10.5});
  const std::string e = error_of(bag);
  EXPECT_NE(e.find(bag.string()), std::string::npos) << e;
  EXPECT_NE(e.find("topic /scan: message 3 has header stamp 10.5 s"), std::string::npos) << e;
  EXPECT_NE(e.find("out of order"), std::string::npos) << e;
}

TEST(RosbagErrors, TruncatedFileIsNamed) {
  const fs::path bag = small_bag("truncated", 50);
  fs::resize_file(bag, fs::file_size(bag) / 2);
  const std::string e = error_of(bag);
  EXPECT_NE(e.find(bag.string()), std::string::npos) << e;
  EXPECT_NE(e.find("cannot read the bag"), std::string::npos) << e;
}

TEST(RosbagErrors, NotABagIsNamed) {
  const fs::path file = temp_dir("not_a_bag") / "log.bag";
  std::ofstream(file) << "FLASER 3 1 1 1 0 0 0 0 0 0 1.0 host 1.0\n";
  const std::string e = error_of(file);
  EXPECT_NE(e.find(file.string()), std::string::npos) << e;
  EXPECT_NE(e.find("cannot read the bag"), std::string::npos) << e;
}

}  // namespace
}  // namespace mspace::rosbag_test
