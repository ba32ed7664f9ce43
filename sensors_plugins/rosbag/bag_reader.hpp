// bag_reader.hpp — reads the laser scans, odometry and ground truth of a ROS 1
// bag with ROS's own library (librosbag_storage), checking what a run needs:
// every named topic exists (else the error lists the bag's topics and types),
// has the expected message type, and its header stamps do not go backwards.
// No ROS header appears here: the plugin's other files stay free of them.
#pragma once

#include <Eigen/Core>
#include <optional>
#include <string>
#include <vector>

namespace mspace::rosbag_source {

/// A planar pose (x, y, θ) at a time stamp (header stamp, seconds).
struct StampedPose2 {
  double t = 0.0;
  Eigen::Vector3d pose = Eigen::Vector3d::Zero();
};

/// One sensor_msgs/LaserScan as (range, bearing) per beam; range 0 = no
/// return (NaN, ±inf, below range_min or at/above range_max).
struct BagScan {
  double t = 0.0;
  std::vector<double> ranges;
  std::vector<double> bearings;
};

struct BagRequest {
  std::string file;
  std::string scan_topic;
  std::string odometry_topic;      ///< nav_msgs/Odometry, or tf2_msgs/TFMessage (/tf)
  std::string odom_frame = "odom";
  std::string base_frame = "base_link";
  std::string ground_truth_topic;  ///< empty: none; nav_msgs/Odometry or geometry_msgs/PoseStamped
};

struct BagContents {
  std::vector<BagScan> scans;
  std::vector<StampedPose2> odometry;
  std::vector<StampedPose2> ground_truth;
  std::string laser_frame;  ///< the scans' header frame_id
  double no_return = 0.0;   ///< the first scan's range_max: ranges at or beyond it were stored as 0
  /// The laser's pose on the robot from /tf_static (base_frame → laser_frame), when recorded.
  std::optional<Eigen::Vector3d> static_mount;
};

/// Reads the bag; throws std::runtime_error naming the file (and topic,
/// message index and stamp where they matter).
BagContents read_bag(const BagRequest& request);

/// The pose at time t, linear between the poses around it (the angle the short
/// way round); none outside [first, last].
std::optional<Eigen::Vector3d> interpolate(const std::vector<StampedPose2>& poses, double t);

}  // namespace mspace::rosbag_source
