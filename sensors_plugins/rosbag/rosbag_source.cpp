// rosbag_source.cpp — see rosbag_source.hpp.
#include "rosbag_source.hpp"

#include <algorithm>
#include <numbers>
#include <set>
#include <sstream>
#include <stdexcept>

#include "bag_camera.hpp"
#include "bag_reader.hpp"
#include "carmen_log.hpp"
#include "image_sequence/image_sequence.hpp"

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

/// The keys a camera bag (image_topic set) reads. Every other key applies to
/// scans only, and a camera bag refuses it at any value but its default
/// rather than ignore it.
const std::set<std::string>& camera_keys() {
  static const std::set<std::string> keys{"file",       "image_topic", "camera_yaml", "camera_channel",
                                          "odometry_topic", "odom_frame", "base_frame",  "ground_truth_topic"};
  return keys;
}

BagRequest request_from(const Params& p) {
  BagRequest r;
  r.file = p.get_string("file");
  r.image_topic = p.get_string("image_topic");
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
      param_string("image_topic", "",
                   "sensor_msgs/Image topic (mono8, mono16, bgr8 or rgb8): one step per image for the camera "
                   "pipeline, time = the image's header stamp; empty: a laser bag (scan_topic)"),
      param_string("camera_yaml", "",
                   "with image_topic: the camera's intrinsics and mount, a camera.yaml as in an image_sequence "
                   "folder (the mount is reported as the camera's recorded mount; /tf_static base_frame -> the "
                   "images' frame_id, when recorded, must agree with it)"),
      param_string("camera_channel", "camera", "with image_topic: channel of the image readings"),
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
  Logger& out = args.log();
  if (!request.image_topic.empty()) {
    const std::string camera_yaml = args.params.get_string("camera_yaml");
    if (camera_yaml.empty())
      throw std::runtime_error(request.file + ": image_topic " + request.image_topic +
                               " needs camera_yaml (the camera's intrinsics and mount, as an image_sequence "
                               "folder's camera.yaml)");
    for (const ParamSpec& spec : param_specs()) {
      const auto given = args.params.values().find(spec.name);
      if (!camera_keys().count(spec.name) && given != args.params.values().end() &&
          given->second != spec.default_value)
        throw std::runtime_error(request.file + ": '" + spec.name + "' applies to scans; with image_topic " +
                                 request.image_topic + " the steps are the images (camera keys: camera_yaml, "
                                 "camera_channel)");
    }
    const BagContents bag = read_bag(request);
    frame_files_ = std::make_unique<BagFrameFiles>(request.file, request.image_topic);
    images_ = std::make_unique<image_sequence::ImageSequence>(
        sequence_from_bag(bag, request, camera_yaml, *frame_files_), args.params.get_string("camera_channel"), out);
    out.info("read ", bag.images.size(), " images on ", request.image_topic, " and ", bag.odometry.size(),
             " odometry poses on ", request.odometry_topic, " from ", request.file, "; camera ", camera_yaml);
    return;
  }
  const BagContents bag = read_bag(request);
  std::size_t left_out = 0;
  carmen_log::LogContents log = to_log(bag, request, left_out);
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
  scans_ = std::make_unique<carmen_log::CarmenLogSource>(carmen, std::move(log));
}

RosbagSource::~RosbagSource() = default;

DataSource& RosbagSource::steps() const {
  if (images_) return *images_;
  return *scans_;
}

bool RosbagSource::next(DataStep& step) {
  if (!steps().next(step)) return false;
  if (images_) {
    // The sequence's frame (and so its message) of this step; its image file
    // is written now, the step's reading already names it.
    const image_sequence::Frame& frame = images_->frames().at(images_delivered_++);
    frame_files_->write(static_cast<std::size_t>(frame.line));
  }
  return true;
}

std::size_t RosbagSource::size_hint() const { return steps().size_hint(); }
Pose6 RosbagSource::initial_pose() const { return steps().initial_pose(); }
std::vector<RecordedMount> RosbagSource::recorded_mounts() const { return steps().recorded_mounts(); }

}  // namespace mspace::rosbag_source
