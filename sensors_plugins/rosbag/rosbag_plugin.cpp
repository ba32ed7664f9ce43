// The plugin export of `rosbag` (the one MSPACE_EXPORT_PLUGIN of this library).
#include <memory>

#include "mspace/plugin_export.hpp"
#include "rosbag_source.hpp"

namespace {

mspace::PluginDescriptor describe() {
  mspace::PluginDescriptor d;
  d.name = "rosbag";
  d.kind = mspace::PluginKind::Source;
  d.description =
      "ROS 1 bags (rosbag_storage): one step per sensor_msgs/LaserScan on scan_topic, the odometry of "
      "odometry_topic (nav_msgs/Odometry or /tf) at the scan stamp, the laser mount from /tf_static, optional "
      "ground truth; readings and odometry as carmen_log's (laser odometry included). With image_topic: one "
      "step per sensor_msgs/Image instead, delivered as image_sequence delivers a folder's frames (camera_yaml "
      "gives the intrinsics and mount)";
  d.params = mspace::rosbag_source::RosbagSource::param_specs();
  d.factory = [](const mspace::PluginArgs& args) -> std::unique_ptr<mspace::PluginObject> {
    return std::make_unique<mspace::rosbag_source::RosbagSource>(args);
  };
  return d;
}

}  // namespace

MSPACE_EXPORT_PLUGIN(describe)
