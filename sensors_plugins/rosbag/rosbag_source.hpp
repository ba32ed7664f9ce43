// rosbag_source.hpp — the `rosbag` data source: a ROS 1 bag's
// sensor_msgs/LaserScan topic replayed one scan per step, with the odometry
// (nav_msgs/Odometry, or the odom → base transforms of /tf) interpolated at
// each scan's header stamp. The steps are made by the `carmen_log` source's
// code (its sources are compiled into this plugin), so the readings' layout
// ((range, bearing) per beam, 0 = no return), the odometry increments, laser
// odometry (`odometry: scan_matched`), ground truth and initial pose are
// exactly those of a CARMEN log holding the same scans.
//
// With `image_topic` set the bag is a camera recording instead: one step per
// sensor_msgs/Image, made by the `image_sequence` source's code (its sources
// are compiled in too) with the camera of `camera_yaml`; see bag_camera.hpp
// for how the images reach the extractors. Scans are not read then.
#pragma once

#include <memory>
#include <vector>

#include "mspace/params.hpp"
#include "mspace/source.hpp"

namespace mspace::carmen_log {
class CarmenLogSource;
}
namespace mspace::image_sequence {
class ImageSequence;
}

namespace mspace::rosbag_source {

class BagFrameFiles;

class RosbagSource final : public DataSource {
 public:
  static std::vector<ParamSpec> param_specs();
  explicit RosbagSource(const PluginArgs& args);
  ~RosbagSource() override;

  bool next(DataStep& step) override;
  std::size_t size_hint() const override;
  Pose6 initial_pose() const override;
  std::vector<RecordedMount> recorded_mounts() const override;

 private:
  /// The scans' steps (laser bags) or …
  std::unique_ptr<carmen_log::CarmenLogSource> scans_;
  /// … the images' (camera bags, image_topic set), whose files `frame_files_` writes.
  std::unique_ptr<image_sequence::ImageSequence> images_;
  std::unique_ptr<BagFrameFiles> frame_files_;
  std::size_t images_delivered_ = 0;
  DataSource& steps() const;
};

}  // namespace mspace::rosbag_source
