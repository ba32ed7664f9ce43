// bag_writer.cpp — see bag_writer.hpp.
#include "bag_writer.hpp"

#include <geometry_msgs/PoseStamped.h>
#include <nav_msgs/Odometry.h>
#include <rosbag/bag.h>
#include <sensor_msgs/Image.h>
#include <sensor_msgs/LaserScan.h>
#include <tf2_msgs/TFMessage.h>

#include <cmath>
#include <limits>
#include <map>

namespace mspace::rosbag_test {
namespace {

geometry_msgs::Quaternion yaw_quaternion(double yaw) {
  geometry_msgs::Quaternion q;
  q.z = std::sin(yaw / 2.0);
  q.w = std::cos(yaw / 2.0);
  return q;
}

geometry_msgs::TransformStamped transform(const ros::Time& t, const std::string& parent, const std::string& child,
                                          const Eigen::Vector3d& p) {
  geometry_msgs::TransformStamped tf;
  tf.header.stamp = t;
  tf.header.frame_id = parent;
  tf.child_frame_id = child;
  tf.transform.translation.x = p[0];
  tf.transform.translation.y = p[1];
  tf.transform.rotation = yaw_quaternion(p[2]);
  return tf;
}

geometry_msgs::Pose pose(const Eigen::Vector3d& p) {
  geometry_msgs::Pose out;
  out.position.x = p[0];
  out.position.y = p[1];
  out.orientation = yaw_quaternion(p[2]);
  return out;
}

}  // namespace

void write_bag(const carmen_log::LogContents& log, const std::filesystem::path& file, const WriteOptions& options) {
  rosbag::Bag bag(file.string(), rosbag::bagmode::Write);
  const ros::Time first(log.scans.front().t);
  if (options.static_mount) {
    tf2_msgs::TFMessage tf;
    tf.transforms.push_back(transform(first, "base_link", "laser", *options.static_mount));
    bag.write("/tf_static", first, tf);
  }
  for (const carmen_log::Scan& s : log.scans) {
    const ros::Time t(s.t);
    sensor_msgs::LaserScan scan;
    scan.header.stamp = t;
    scan.header.frame_id = "laser";
    scan.angle_min = static_cast<float>(s.bearings.front());
    scan.angle_increment = static_cast<float>(s.bearings[1] - s.bearings[0]);
    scan.angle_max = static_cast<float>(s.bearings.back());
    scan.range_min = 0.0F;
    scan.range_max = static_cast<float>(log.laser.no_return);
    for (double r : s.ranges)
      scan.ranges.push_back(r > 0.0 ? static_cast<float>(r) : std::numeric_limits<float>::infinity());
    if (options.odometry_on_tf) {
      tf2_msgs::TFMessage tf;
      tf.transforms.push_back(transform(t, "odom", "base_link", s.odometry));
      bag.write("/tf", t, tf);
    } else {
      nav_msgs::Odometry odom;
      odom.header.stamp = t;
      odom.header.frame_id = "odom";
      odom.child_frame_id = "base_link";
      odom.pose.pose = pose(s.odometry);
      bag.write("/odom", t, odom);
    }
    if (options.ground_truth && s.ground_truth) {
      geometry_msgs::PoseStamped truth;
      truth.header.stamp = t;
      truth.header.frame_id = "map";
      truth.pose = pose(*s.ground_truth);
      bag.write("/ground_truth", t, truth);
    }
    bag.write("/scan", t, scan);
  }
  bag.close();
}

void write_stamped_scans(const std::filesystem::path& file, const std::vector<double>& stamps) {
  rosbag::Bag bag(file.string(), rosbag::bagmode::Write);
  ros::Time recorded(1.0);
  for (double s : stamps) {
    recorded += ros::Duration(1.0);  // recorded in order, stamped as given
    sensor_msgs::LaserScan scan;
    scan.header.stamp = ros::Time(s);
    scan.range_max = 10.0F;
    scan.angle_increment = 0.1F;
    scan.ranges = {1.0F, 1.0F};
    bag.write("/scan", recorded, scan);
    nav_msgs::Odometry odom;  // in order: only the scans' stamps are wrong
    odom.header.stamp = recorded;
    odom.pose.pose.orientation.w = 1.0;
    bag.write("/odom", recorded, odom);
  }
  bag.close();
}

}  // namespace mspace::rosbag_test

namespace mspace::rosbag_test {

void write_camera_bag(const CameraBag& contents, const std::filesystem::path& file) {
  rosbag::Bag bag(file.string(), rosbag::bagmode::Write);
  // Messages go in by (time, kind): a bag holds them in any order, but a
  // recorder writes them as they arrive.
  enum Kind { kOdometry, kTruth, kImage };
  std::multimap<std::pair<double, int>, std::size_t> order;
  for (std::size_t i = 0; i < contents.odometry.size(); ++i) order.emplace(std::pair{contents.odometry[i].t, kOdometry}, i);
  for (std::size_t i = 0; i < contents.ground_truth.size(); ++i)
    order.emplace(std::pair{contents.ground_truth[i].t, kTruth}, i);
  for (std::size_t i = 0; i < contents.frames.size(); ++i) order.emplace(std::pair{contents.frames[i].t, kImage}, i);
  const ros::Duration latency(1.0);
  if (contents.mount) {
    const ros::Time first(order.empty() ? 1.0 : order.begin()->first.first);
    tf2_msgs::TFMessage tf;
    geometry_msgs::TransformStamped mount;
    mount.header.stamp = first;
    mount.header.frame_id = "base_link";
    mount.child_frame_id = contents.frame_id;
    mount.transform.translation.x = contents.mount->first.x();
    mount.transform.translation.y = contents.mount->first.y();
    mount.transform.translation.z = contents.mount->first.z();
    const std::array<double, 4>& q = contents.mount->second;
    mount.transform.rotation.x = q[0];
    mount.transform.rotation.y = q[1];
    mount.transform.rotation.z = q[2];
    mount.transform.rotation.w = q[3];
    tf.transforms.push_back(mount);
    bag.write("/tf_static", first + latency, tf);
  }
  for (const auto& [key, i] : order) {
    const ros::Time t(key.first);
    const ros::Time recorded = t + latency;
    if (key.second == kOdometry) {
      nav_msgs::Odometry odom;
      odom.header.stamp = t;
      odom.header.frame_id = "odom";
      odom.child_frame_id = "base_link";
      odom.pose.pose = pose(contents.odometry[i].pose);
      bag.write("/odom", recorded, odom);
    } else if (key.second == kTruth) {
      geometry_msgs::PoseStamped truth;
      truth.header.stamp = t;
      truth.header.frame_id = "map";
      truth.pose = pose(contents.ground_truth[i].pose);
      bag.write("/ground_truth", recorded, truth);
    } else {
      const CameraFrame& f = contents.frames[i];
      sensor_msgs::Image image;
      image.header.stamp = t;
      image.header.frame_id = contents.frame_id;
      image.width = f.width;
      image.height = f.height;
      image.step = f.step;
      image.encoding = f.encoding;
      image.is_bigendian = f.big_endian ? 1 : 0;
      image.data = f.data;
      bag.write(contents.image_topic, recorded, image);
    }
  }
  bag.close();
}

}  // namespace mspace::rosbag_test
