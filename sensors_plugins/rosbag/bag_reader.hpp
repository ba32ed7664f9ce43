// bag_reader.hpp — reads the laser scans (or the camera images), odometry and
// ground truth of a ROS 1 bag with ROS's own library (librosbag_storage),
// checking what a run needs: every named topic exists (else the error lists
// the bag's topics and types), has the expected message type, and its header
// stamps do not go backwards.
// No ROS header appears here: the plugin's other files stay free of them.
#pragma once

#include <Eigen/Core>
#include <array>
#include <cstddef>
#include <cstdint>
#include <memory>
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

/// What read_bag keeps of one sensor_msgs/Image (the pixels are read again,
/// one image at a time, by BagImageReader when the step is delivered).
struct BagImageInfo {
  double t = 0.0;  ///< header stamp (s)
  int width = 0;
  int height = 0;
};

/// A 3-D transform of /tf_static: translation (x, y, z) and rotation
/// quaternion (x, y, z, w).
struct StaticTransform {
  Eigen::Vector3d translation = Eigen::Vector3d::Zero();
  std::array<double, 4> rotation{0.0, 0.0, 0.0, 1.0};
};

struct BagRequest {
  std::string file;
  /// Non-empty: a camera bag — sensor_msgs/Image on this topic, scan_topic not read.
  std::string image_topic;
  std::string scan_topic;
  std::string odometry_topic;      ///< nav_msgs/Odometry, or tf2_msgs/TFMessage (/tf)
  std::string odom_frame = "odom";
  std::string base_frame = "base_link";
  std::string ground_truth_topic;  ///< empty: none; nav_msgs/Odometry or geometry_msgs/PoseStamped
};

struct BagContents {
  std::vector<BagScan> scans;
  /// One per message on image_topic, in bag order (message index = position + 1);
  /// each checked by check_image's rules.
  std::vector<BagImageInfo> images;
  std::string image_frame;  ///< the first image's header frame_id
  /// The camera's pose on the robot from /tf_static (base_frame → image_frame), when recorded.
  std::optional<StaticTransform> static_camera_mount;
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

/// The image encodings read (sensor_msgs/image_encodings names), for messages.
inline constexpr const char* kImageEncodings = "mono8, mono16, bgr8, rgb8";

/// The pixels of one sensor_msgs/Image whose encoding is one of
/// kImageEncodings and whose data holds step × height bytes, step ≥ width ×
/// the encoding's bytes per pixel (rows may be padded).
struct BagImage {
  double t = 0.0;
  int width = 0;
  int height = 0;
  std::string encoding;
  std::size_t step = 0;     ///< bytes per row
  bool big_endian = false;  ///< byte order of mono16 pixels
  std::vector<std::uint8_t> data;
};

/// Reads the images of one topic forward, one message at a time (a bag's
/// images need not fit in memory). Errors name the file, topic, message index
/// and stamp.
class BagImageReader {
 public:
  BagImageReader(const std::string& file, const std::string& topic);
  ~BagImageReader();
  BagImageReader(const BagImageReader&) = delete;
  BagImageReader& operator=(const BagImageReader&) = delete;

  /// The message with the 1-based `index` on the topic; indices must increase
  /// from call to call.
  BagImage read(std::size_t index);

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

/// The pose at time t, linear between the poses around it (the angle the short
/// way round); none outside [first, last].
std::optional<Eigen::Vector3d> interpolate(const std::vector<StampedPose2>& poses, double t);

}  // namespace mspace::rosbag_source
