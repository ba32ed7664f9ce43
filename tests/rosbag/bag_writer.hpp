// bag_writer.hpp — writes test bags with ROS's own library (rosbag_storage):
// the scans of a CARMEN log as sensor_msgs/LaserScan, its odometry as
// nav_msgs/Odometry or /tf, its ground truth as geometry_msgs/PoseStamped and
// the laser mount on /tf_static.
#pragma once

#include <Eigen/Core>
#include <filesystem>
#include <optional>
#include <string>
#include <vector>

#include "carmen_reader.hpp"

namespace mspace::rosbag_test {

struct WriteOptions {
  bool odometry_on_tf = false;                 ///< /tf odom -> base_link instead of /odom
  std::optional<Eigen::Vector3d> static_mount;  ///< written on /tf_static base_link -> laser
  bool ground_truth = false;                   ///< /ground_truth (PoseStamped) from the scans' ground truth
};

/// One LaserScan per scan (no return: +inf, range_max = the log's no-return
/// value), the odometry pose at each scan stamp.
void write_bag(const carmen_log::LogContents& log, const std::filesystem::path& file, const WriteOptions& options);

/// Scans (2 beams) and odometry on /scan and /odom recorded in this order
/// with these header stamps (out of order when the list is).
void write_stamped_scans(const std::filesystem::path& file, const std::vector<double>& stamps);

}  // namespace mspace::rosbag_test
