// bag_reader.cpp — see bag_reader.hpp.
#include "bag_reader.hpp"

#include <geometry_msgs/PoseStamped.h>
#include <nav_msgs/Odometry.h>
#include <rosbag/bag.h>
#include <rosbag/view.h>
#include <sensor_msgs/Image.h>
#include <sensor_msgs/LaserScan.h>
#include <tf2_msgs/TFMessage.h>

#include <algorithm>
#include <cmath>
#include <map>
#include <sstream>
#include <stdexcept>

namespace mspace::rosbag_source {
namespace {

constexpr double kTwoPi = 6.283185307179586476925;  // this file is C++17 (no <numbers>), see CMakeLists.txt

double yaw_of(const geometry_msgs::Quaternion& q) {
  return std::atan2(2.0 * (q.w * q.z + q.x * q.y), 1.0 - 2.0 * (q.y * q.y + q.z * q.z));
}

Eigen::Vector3d planar(const geometry_msgs::Pose& p) { return {p.position.x, p.position.y, yaw_of(p.orientation)}; }
Eigen::Vector3d planar(const geometry_msgs::Transform& p) {
  return {p.translation.x, p.translation.y, yaw_of(p.rotation)};
}

/// "  /scan (sensor_msgs/LaserScan)\n…" for every topic of the bag.
std::string topic_list(const std::map<std::string, std::string>& types) {
  std::ostringstream out;
  for (const auto& [topic, type] : types) out << "\n  " << topic << " (" << type << ")";
  return types.empty() ? std::string(" (none)") : out.str();
}

StaticTransform transform3d(const geometry_msgs::Transform& p) {
  StaticTransform out;
  out.translation = {p.translation.x, p.translation.y, p.translation.z};
  out.rotation = {p.rotation.x, p.rotation.y, p.rotation.z, p.rotation.w};
  return out;
}

/// Bytes per pixel of an encoding of kImageEncodings; 0 for any other.
std::size_t bytes_per_pixel(const std::string& encoding) {
  if (encoding == "mono8") return 1;
  if (encoding == "mono16") return 2;
  if (encoding == "bgr8" || encoding == "rgb8") return 3;
  return 0;
}

/// "run.bag: image_topic /camera: message 3 (stamp 12.500000000 s)" — ros::Time
/// prints seconds and nanoseconds exactly.
std::string image_at(const std::string& file, const std::string& topic, std::size_t index, const ros::Time& stamp) {
  std::ostringstream out;
  out << file << ": image_topic " << topic << ": message " << index << " (stamp " << stamp << " s)";
  return out.str();
}

/// An Image the camera pipeline can take: a supported encoding, and pixel
/// data exactly step × height bytes with rows of at least width pixels.
void check_image(const sensor_msgs::Image& image, const std::string& file, const std::string& topic,
                 std::size_t index) {
  const std::size_t bytes = bytes_per_pixel(image.encoding);
  if (bytes == 0) {
    throw std::runtime_error(image_at(file, topic, index, image.header.stamp) + " has encoding '" + image.encoding +
                             "'; supported: " + kImageEncodings);
  }
  const std::string corrupt = image_at(file, topic, index, image.header.stamp) + " is corrupt: ";
  if (image.width == 0 || image.height == 0) {
    throw std::runtime_error(corrupt + "it is " + std::to_string(image.width) + "x" + std::to_string(image.height) +
                             " pixels");
  }
  if (std::size_t{image.step} < std::size_t{image.width} * bytes) {
    throw std::runtime_error(corrupt + "step " + std::to_string(image.step) +
                             " bytes is less than width x bytes per pixel = " + std::to_string(image.width) + " x " +
                             std::to_string(bytes) + " (" + image.encoding + ")");
  }
  const std::size_t expected = std::size_t{image.step} * std::size_t{image.height};
  if (image.data.size() != expected) {
    throw std::runtime_error(corrupt + "data holds " + std::to_string(image.data.size()) +
                             " bytes, step x height = " + std::to_string(image.step) + " x " +
                             std::to_string(image.height) + " = " + std::to_string(expected));
  }
}

/// Checks the stamps of one topic: each at least the previous one.
class StampOrder {
 public:
  StampOrder(const std::string& file, const std::string& topic) : file_(file), topic_(topic) {}
  std::size_t index() const { return index_; }
  void check(double t) {
    ++index_;
    if (index_ > 1 && t < last_) {
      std::ostringstream out;
      out.precision(17);
      out << file_ << ": topic " << topic_ << ": message " << index_ << " has header stamp " << t
          << " s, before the previous message's " << last_ << " s (stamps out of order)";
      throw std::runtime_error(out.str());
    }
    last_ = t;
  }

 private:
  std::string file_, topic_;
  std::size_t index_ = 0;
  double last_ = 0.0;
};

}  // namespace

std::optional<Eigen::Vector3d> interpolate(const std::vector<StampedPose2>& poses, double t) {
  const auto later = std::lower_bound(poses.begin(), poses.end(), t,
                                      [](const StampedPose2& p, double value) { return p.t < value; });
  if (later == poses.end()) return std::nullopt;
  if (later->t == t) return later->pose;
  if (later == poses.begin()) return std::nullopt;
  const StampedPose2& a = *std::prev(later);
  const double u = (t - a.t) / (later->t - a.t);
  Eigen::Vector3d p = a.pose + u * (later->pose - a.pose);
  p[2] = std::remainder(a.pose[2] + u * std::remainder(later->pose[2] - a.pose[2], kTwoPi),
                        kTwoPi);
  return p;
}

BagContents read_bag(const BagRequest& request) {
  const std::string& file = request.file;
  BagContents out;
  try {
    rosbag::Bag bag;
    bag.open(file, rosbag::bagmode::Read);
    std::map<std::string, std::string> types;
    {
      rosbag::View all(bag);
      for (const rosbag::ConnectionInfo* c : all.getConnections()) types[c->topic] = c->datatype;
    }
    // Each requested topic must exist with one of the types it may carry.
    auto require = [&](const std::string& key, const std::string& topic, const std::vector<std::string>& allowed) {
      const auto found = types.find(topic);
      if (found == types.end())
        throw std::runtime_error(file + ": " + key + " " + topic + " is not in the bag; its topics:" +
                                 topic_list(types));
      if (std::find(allowed.begin(), allowed.end(), found->second) == allowed.end()) {
        std::string expected;
        for (const std::string& a : allowed) expected += (expected.empty() ? "" : " or ") + a;
        throw std::runtime_error(file + ": " + key + " " + topic + " carries " + found->second + ", expected " +
                                 expected);
      }
      return found->second;
    };
    const bool camera = !request.image_topic.empty();
    if (camera) require("image_topic", request.image_topic, {"sensor_msgs/Image"});
    else require("scan_topic", request.scan_topic, {"sensor_msgs/LaserScan"});
    const std::string odometry_type =
        require("odometry_topic", request.odometry_topic, {"nav_msgs/Odometry", "tf2_msgs/TFMessage"});
    std::string truth_type;
    if (!request.ground_truth_topic.empty())
      truth_type = require("ground_truth_topic", request.ground_truth_topic,
                           {"nav_msgs/Odometry", "geometry_msgs/PoseStamped"});

    StampOrder scan_order(file, request.scan_topic), odometry_order(file, request.odometry_topic),
        truth_order(file, request.ground_truth_topic), image_order(file, request.image_topic);
    std::vector<std::string> topics{camera ? request.image_topic : request.scan_topic, request.odometry_topic};
    if (!truth_type.empty()) topics.push_back(request.ground_truth_topic);
    const bool has_static = types.count("/tf_static") > 0 && types["/tf_static"] == "tf2_msgs/TFMessage";
    if (has_static) topics.push_back("/tf_static");
    std::map<std::string, Eigen::Vector3d> static_children;  // base_frame -> child on /tf_static
    std::map<std::string, StaticTransform> static_children3d;
    rosbag::View view(bag, rosbag::TopicQuery(topics));
    for (const rosbag::MessageInstance& m : view) {
      const std::string& topic = m.getTopic();
      if (camera && topic == request.image_topic) {
        // The pixels are checked here, before the run, and read again when
        // their step is delivered (BagImageReader).
        const auto image = m.instantiate<sensor_msgs::Image>();
        if (!image) {  // a topic with connections of two types (rosbag's own writer cannot make one)
          throw std::runtime_error(file + ": image_topic " + request.image_topic + ": message " +
                                   std::to_string(image_order.index() + 1) + " carries " + m.getDataType() +
                                   ", expected sensor_msgs/Image");
        }
        image_order.check(image->header.stamp.toSec());
        check_image(*image, file, request.image_topic, image_order.index());
        if (out.images.empty()) out.image_frame = image->header.frame_id;
        out.images.push_back({image->header.stamp.toSec(), static_cast<int>(image->width),
                              static_cast<int>(image->height)});
      } else if (!camera && topic == request.scan_topic) {
        const auto scan = m.instantiate<sensor_msgs::LaserScan>();
        const double t = scan->header.stamp.toSec();
        scan_order.check(t);
        if (out.scans.empty()) {
          out.laser_frame = scan->header.frame_id;
          out.no_return = scan->range_max;
        }
        BagScan s;
        s.t = t;
        s.ranges.reserve(scan->ranges.size());
        for (std::size_t i = 0; i < scan->ranges.size(); ++i) {
          const double r = scan->ranges[i];
          const bool valid = std::isfinite(r) && r >= scan->range_min && r < scan->range_max;
          s.ranges.push_back(valid ? r : 0.0);
          s.bearings.push_back(double(scan->angle_min) + double(i) * double(scan->angle_increment));
        }
        out.scans.push_back(std::move(s));
      } else if (topic == request.odometry_topic && odometry_type == "nav_msgs/Odometry") {
        const auto odom = m.instantiate<nav_msgs::Odometry>();
        odometry_order.check(odom->header.stamp.toSec());
        out.odometry.push_back({odom->header.stamp.toSec(), planar(odom->pose.pose)});
      } else if (topic == request.odometry_topic) {  // /tf: the odom → base transforms
        const auto message = m.instantiate<tf2_msgs::TFMessage>();  // kept alive while its transforms are read
        for (const auto& tf : message->transforms) {
          if (tf.header.frame_id != request.odom_frame || tf.child_frame_id != request.base_frame) continue;
          odometry_order.check(tf.header.stamp.toSec());
          out.odometry.push_back({tf.header.stamp.toSec(), planar(tf.transform)});
        }
      } else if (topic == request.ground_truth_topic && truth_type == "nav_msgs/Odometry") {
        const auto odom = m.instantiate<nav_msgs::Odometry>();
        truth_order.check(odom->header.stamp.toSec());
        out.ground_truth.push_back({odom->header.stamp.toSec(), planar(odom->pose.pose)});
      } else if (topic == request.ground_truth_topic) {
        const auto pose = m.instantiate<geometry_msgs::PoseStamped>();
        truth_order.check(pose->header.stamp.toSec());
        out.ground_truth.push_back({pose->header.stamp.toSec(), planar(pose->pose)});
      } else if (topic == "/tf_static") {
        const auto message = m.instantiate<tf2_msgs::TFMessage>();
        for (const auto& tf : message->transforms) {
          if (tf.header.frame_id != request.base_frame) continue;
          static_children[tf.child_frame_id] = planar(tf.transform);
          static_children3d[tf.child_frame_id] = transform3d(tf.transform);
        }
      }
    }
    if (camera) {
      const auto mount = static_children3d.find(out.image_frame);
      if (mount != static_children3d.end()) out.static_camera_mount = mount->second;
    } else {
      const auto mount = static_children.find(out.laser_frame);
      if (mount != static_children.end()) out.static_mount = mount->second;
    }
    bag.close();
  } catch (const rosbag::BagException& e) {
    throw std::runtime_error(file + ": cannot read the bag (truncated or corrupt?): " + e.what());
  } catch (const ros::Exception& e) {
    throw std::runtime_error(file + ": cannot decode a message of the bag: " + e.what());
  }
  if (!request.image_topic.empty() && out.images.empty())
    throw std::runtime_error(file + ": image_topic " + request.image_topic + " has no messages");
  if (request.image_topic.empty() && out.scans.empty())
    throw std::runtime_error(file + ": topic " + request.scan_topic + " has no messages");
  if (out.odometry.empty())
    throw std::runtime_error(file + ": topic " + request.odometry_topic + " has no odometry (" + request.odom_frame +
                             " -> " + request.base_frame + ")");
  return out;
}

struct BagImageReader::Impl {
  std::string file, topic;
  // Declared in the order they depend on each other (destroyed in reverse).
  rosbag::Bag bag;
  std::unique_ptr<rosbag::View> view;
  rosbag::View::iterator at;
  std::size_t index = 1;  ///< the message index of `at`
};

BagImageReader::BagImageReader(const std::string& file, const std::string& topic) : impl_(std::make_unique<Impl>()) {
  impl_->file = file;
  impl_->topic = topic;
  try {
    impl_->bag.open(file, rosbag::bagmode::Read);
    impl_->view = std::make_unique<rosbag::View>(impl_->bag, rosbag::TopicQuery(topic));
    impl_->at = impl_->view->begin();
  } catch (const rosbag::BagException& e) {
    throw std::runtime_error(file + ": cannot read the bag (truncated or corrupt?): " + e.what());
  }
}

BagImageReader::~BagImageReader() = default;

BagImage BagImageReader::read(std::size_t index) {
  Impl& r = *impl_;
  if (index < r.index) {
    throw std::logic_error(r.file + ": image_topic " + r.topic + ": message " + std::to_string(index) +
                           " asked for after message " + std::to_string(r.index) + " (the bag is read forward)");
  }
  try {
    for (; r.index < index && r.at != r.view->end(); ++r.index) ++r.at;
    if (r.at == r.view->end()) {
      throw std::runtime_error(r.file + ": image_topic " + r.topic + " has no message " + std::to_string(index) +
                               " (did the file change while it was read?)");
    }
    const auto image = r.at->instantiate<sensor_msgs::Image>();
    if (!image) throw std::runtime_error(r.file + ": image_topic " + r.topic + " carries " + r.at->getDataType() +
                                         ", expected sensor_msgs/Image");
    check_image(*image, r.file, r.topic, index);
    BagImage out;
    out.t = image->header.stamp.toSec();
    out.width = static_cast<int>(image->width);
    out.height = static_cast<int>(image->height);
    out.encoding = image->encoding;
    out.step = image->step;
    out.big_endian = image->is_bigendian != 0;
    out.data = std::move(image->data);
    return out;
  } catch (const rosbag::BagException& e) {
    throw std::runtime_error(r.file + ": cannot read the bag (truncated or corrupt?): " + e.what());
  } catch (const ros::Exception& e) {
    throw std::runtime_error(r.file + ": cannot decode a message of the bag: " + e.what());
  }
}

}  // namespace mspace::rosbag_source
