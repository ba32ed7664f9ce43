// bag_writer.hpp — writes test bags with ROS's own library (rosbag_storage):
// the scans of a CARMEN log as sensor_msgs/LaserScan, its odometry as
// nav_msgs/Odometry or /tf, its ground truth as geometry_msgs/PoseStamped and
// the laser mount on /tf_static; and camera recordings: sensor_msgs/Image
// with odometry, ground truth and the camera mount.
#pragma once

#include <Eigen/Core>
#include <array>
#include <cstdint>
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

/// One sensor_msgs/Image as written (the fields the message carries; a test
/// may make them inconsistent on purpose).
struct CameraFrame {
  double t = 0.0;
  std::uint32_t width = 0, height = 0, step = 0;
  std::string encoding = "mono8";
  bool big_endian = false;
  std::vector<std::uint8_t> data;
};

/// A planar pose (x, y, θ) at a time.
struct StampedPlanar {
  double t = 0.0;
  Eigen::Vector3d pose = Eigen::Vector3d::Zero();
};

struct CameraBag {
  std::string image_topic = "/camera/image_raw";
  std::string frame_id = "camera";
  std::vector<CameraFrame> frames;
  std::vector<StampedPlanar> odometry;      ///< on /odom (nav_msgs/Odometry)
  std::vector<StampedPlanar> ground_truth;  ///< on /ground_truth (geometry_msgs/PoseStamped) when not empty
  /// base_link -> frame_id on /tf_static when set: translation and quaternion (x, y, z, w).
  std::optional<std::pair<Eigen::Vector3d, std::array<double, 4>>> mount;
};

/// Writes the camera recording, messages in time order (ties: odometry
/// first), each recorded 1 s after its header stamp (a bag's record times
/// must be positive; a rendered sequence starts at 0).
void write_camera_bag(const CameraBag& contents, const std::filesystem::path& file);

/// One LaserScan per scan (no return: +inf, range_max = the log's no-return
/// value), the odometry pose at each scan stamp.
void write_bag(const carmen_log::LogContents& log, const std::filesystem::path& file, const WriteOptions& options);

/// Scans (2 beams) and odometry on /scan and /odom recorded in this order
/// with these header stamps (out of order when the list is).
void write_stamped_scans(const std::filesystem::path& file, const std::vector<double>& stamps);

}  // namespace mspace::rosbag_test
