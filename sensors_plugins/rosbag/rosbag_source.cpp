// rosbag_source.cpp — see rosbag_source.hpp.
#include "rosbag_source.hpp"

#include <algorithm>
#include <numbers>
#include <set>
#include <sstream>
#include <stdexcept>

#include "bag_reader.hpp"
#include "carmen_log.hpp"

namespace mspace::rosbag_source {
namespace {

/// The carmen_log parameters that mean nothing for a bag (file format, text
/// parsing, time base, ground truth from a file) and are not offered.
const std::set<std::string>& carmen_only() {
  static const std::set<std::string> keys{"file",           "format",      "variant",
                                          "no_return_range", "flaser_fov_deg", "time_offset",
                                          "on_malformed",   "ground_truth", "ground_truth_max_gap",
                                          "laser_offset"};
  return keys;
}

BagRequest request_from(const Params& p) {
  BagRequest r;
  r.file = p.get_string("file");
  r.scan_topic = p.get_string("scan_topic");
  r.odometry_topic = p.get_string("odometry_topic");
  r.odom_frame = p.get_string("odom_frame");
  r.base_frame = p.get_string("base_frame");
  r.ground_truth_topic = p.get_string("ground_truth_topic");
  return r;
}

/// The bag's scans as a CARMEN log's: odometry (and ground truth) at each
/// scan stamp; scans outside the odometry's time span are left out.
carmen_log::LogContents to_log(const BagContents& bag, const BagRequest& request, std::size_t& left_out) {
  carmen_log::LogContents log;
  left_out = 0;
  for (std::size_t i = 0; i < bag.scans.size(); ++i) {
    const BagScan& s = bag.scans[i];
    const std::optional<Eigen::Vector3d> odometry = interpolate(bag.odometry, s.t);
    if (!odometry) {
      ++left_out;
      continue;
    }
    carmen_log::Scan scan;
    scan.t = s.t;
    scan.line = static_cast<int>(i + 1);  // the message index on scan_topic
    scan.odometry = *odometry;
    if (!bag.ground_truth.empty()) scan.ground_truth = interpolate(bag.ground_truth, s.t);
    scan.ranges = s.ranges;
    scan.bearings = s.bearings;
    log.scans.push_back(std::move(scan));
  }
  if (log.scans.empty())
    throw std::runtime_error(request.file + ": no scan on " + request.scan_topic + " lies within the time span of " +
                             request.odometry_topic + " (wrong topic or clock?)");
  log.laser.no_return = bag.no_return;
  log.laser.no_return_origin = request.file + ": range_max of " + request.scan_topic;
  if (bag.static_mount) {
    log.laser.offset = *bag.static_mount;
    log.laser.offset_origin = request.file + ": /tf_static " + request.base_frame + " -> " + bag.laser_frame;
  }
  return log;
}

}  // namespace

std::vector<ParamSpec> RosbagSource::param_specs() {
  std::vector<ParamSpec> specs{
      required(param_string("file", "", "the ROS 1 bag (.bag), read with ROS's rosbag_storage library")),
      param_string("scan_topic", "/scan", "sensor_msgs/LaserScan topic: one step per scan"),
      param_string("odometry_topic", "/odom",
                   "nav_msgs/Odometry topic, or a tf2_msgs/TFMessage topic (/tf) whose odom_frame -> base_frame "
                   "transforms are the odometry; interpolated at each scan's header stamp"),
      param_string("odom_frame", "odom", "the odometry frame of the /tf transforms (odometry_topic: /tf)"),
      param_string("base_frame", "base_link",
                   "the robot frame: child of odom_frame on /tf, and parent of the laser frame on /tf_static"),
      param_string("ground_truth_topic", "",
                   "nav_msgs/Odometry or geometry_msgs/PoseStamped topic of true poses, interpolated at the scan "
                   "stamps (empty: no ground truth)"),
      param_list("laser_mount", {},
                 "the laser's pose on the robot [x, y, theta_deg] for laser odometry; empty: /tf_static "
                 "base_frame -> the scans' frame_id when the bag has it (then reported as the recorded mount of "
                 "`channel`, so sensors.<name>.mount must agree), else zero"),
  };
  for (ParamSpec& spec : carmen_log::CarmenLogSource::param_specs())
    if (!carmen_only().count(spec.name)) specs.push_back(std::move(spec));
  return specs;
}

RosbagSource::RosbagSource(const PluginArgs& args) {
  const BagRequest request = request_from(args.params);
  const BagContents bag = read_bag(request);
  std::size_t left_out = 0;
  carmen_log::LogContents log = to_log(bag, request, left_out);
  Logger& out = args.log();
  out.info("read ", bag.scans.size(), " scans on ", request.scan_topic, " and ", bag.odometry.size(),
           " odometry poses on ", request.odometry_topic, " from ", request.file);
  if (left_out > 0)
    out.warn(left_out, " scan(s) on ", request.scan_topic, " lie outside the odometry's time span and are left out");

  // The carmen_log code with this source's values and the carmen defaults
  // for what a bag does not need.
  PluginArgs carmen = args;
  carmen.params = Params::defaults(carmen_log::CarmenLogSource::param_specs());
  for (const auto& [key, value] : args.params.values())
    if (carmen.params.has(key) && !carmen_only().count(key)) carmen.params.set(key, value);
  carmen.params.set("file", request.file);
  carmen.params.set("ground_truth", std::string(request.ground_truth_topic.empty() ? "none" : "log"));
  carmen.params.set("laser_offset", args.params.get_list("laser_mount"));
  steps_ = std::make_unique<carmen_log::CarmenLogSource>(carmen, std::move(log));
}

RosbagSource::~RosbagSource() = default;
bool RosbagSource::next(DataStep& step) { return steps_->next(step); }
std::size_t RosbagSource::size_hint() const { return steps_->size_hint(); }
Pose6 RosbagSource::initial_pose() const { return steps_->initial_pose(); }
std::vector<RecordedMount> RosbagSource::recorded_mounts() const { return steps_->recorded_mounts(); }

}  // namespace mspace::rosbag_source
