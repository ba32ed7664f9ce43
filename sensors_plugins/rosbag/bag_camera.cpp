// bag_camera.cpp — see bag_camera.hpp.
#include "bag_camera.hpp"

#include <stdlib.h>  // mkdtemp

#include <Eigen/Geometry>
#include <cerrno>
#include <cmath>
#include <cstring>
#include <iomanip>
#include <numbers>
#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>
#include <sstream>
#include <stdexcept>
#include <system_error>

namespace mspace::rosbag_source {
namespace {

namespace fs = std::filesystem;

/// The pixels of a checked message as an image cv::imwrite stores losslessly:
/// 8-bit grey, 16-bit grey or 8-bit BGR (mono8 and bgr8 are wrapped, not
/// copied; imwrite skips the rows' padding).
cv::Mat png_pixels(BagImage& image) {
  const int w = image.width, h = image.height;
  std::uint8_t* data = image.data.data();
  if (image.encoding == "mono8") return cv::Mat(h, w, CV_8UC1, data, image.step);
  if (image.encoding == "bgr8") return cv::Mat(h, w, CV_8UC3, data, image.step);
  if (image.encoding == "rgb8") {
    cv::Mat bgr;
    cv::cvtColor(cv::Mat(h, w, CV_8UC3, data, image.step), bgr, cv::COLOR_RGB2BGR);
    return bgr;
  }
  // mono16: byte by byte, so that neither the message's byte order nor an odd
  // row padding depends on the host.
  cv::Mat deep(h, w, CV_16UC1);
  const int high = image.big_endian ? 0 : 1;
  for (int r = 0; r < h; ++r) {
    const std::uint8_t* row = data + static_cast<std::size_t>(r) * image.step;
    auto* out = deep.ptr<std::uint16_t>(r);
    for (int c = 0; c < w; ++c) {
      const std::uint8_t* p = row + 2 * static_cast<std::size_t>(c);
      out[c] = static_cast<std::uint16_t>((p[high] << 8) | p[1 - high]);
    }
  }
  return deep;
}

/// "12.500000000": a stamp as ROS prints it.
std::string stamp_text(double t) {
  std::ostringstream out;
  out << std::fixed << std::setprecision(9) << t;
  return out.str();
}

/// A mount in camera.yaml's order and units: [x, y, z, roll, pitch, yaw] (m, deg).
std::string mount_text(const Pose6& m) {
  constexpr double deg = 180.0 / std::numbers::pi;
  std::ostringstream out;
  out.precision(6);
  const auto v = [](double x) { return x + 0.0; };  // -0 prints as 0
  out << "[" << v(m[kX]) << ", " << v(m[kY]) << ", " << v(m[kZ]) << ", " << v(m[kPsi] * deg) << ", "
      << v(m[kPhi] * deg) << ", " << v(m[kTheta] * deg) << "]";
  return out.str();
}

/// Poses with a stamp after the previous one's: the bag allows equal stamps,
/// image_sequence's interpolation needs them increasing (the first is kept).
std::vector<image_sequence::StampedPose2> increasing(const std::vector<StampedPose2>& poses) {
  std::vector<image_sequence::StampedPose2> out;
  for (const StampedPose2& p : poses)
    if (out.empty() || p.t > out.back().t) out.push_back({p.t, p.pose});
  return out;
}

/// Within 1 µm and 1 µrad: the same mount written in two places.
bool same_mount(const Pose6& a, const Pose6& b) {
  const Eigen::AngleAxisd between(rotation(a).transpose() * rotation(b));
  return (a.head<3>() - b.head<3>()).norm() <= 1e-6 && std::abs(between.angle()) <= 1e-6;
}

}  // namespace

BagFrameFiles::BagFrameFiles(const std::string& bag_file, const std::string& image_topic)
    : reader_(bag_file, image_topic) {
  std::string pattern = (fs::temp_directory_path() / "mspace-rosbag-XXXXXX").string();
  if (::mkdtemp(pattern.data()) == nullptr) {
    throw std::runtime_error(pattern + ": cannot create a folder for the images of " + bag_file + " " + image_topic +
                             ": " + std::strerror(errno));
  }
  folder_ = pattern;
}

BagFrameFiles::~BagFrameFiles() {
  std::error_code ignored;  // nothing to do about a folder that cannot be removed while unwinding
  fs::remove_all(folder_, ignored);
}

std::string BagFrameFiles::path(std::size_t index) const {
  std::ostringstream name;
  name << "message-" << std::setw(6) << std::setfill('0') << index << ".png";
  return (folder_ / name.str()).string();
}

void BagFrameFiles::write(std::size_t index) {
  BagImage image = reader_.read(index);
  const std::string file = path(index);
  // Compression level 1: the files live for one step, speed matters more than size.
  if (!cv::imwrite(file, png_pixels(image), {cv::IMWRITE_PNG_COMPRESSION, 1}))
    throw std::runtime_error(file + ": cannot write the image of message " + std::to_string(index));
  if (!previous_.empty() && previous_ != file) {
    std::error_code ignored;  // already gone is fine
    fs::remove(previous_, ignored);
  }
  previous_ = file;
}

image_sequence::SequenceContents sequence_from_bag(const BagContents& bag, const BagRequest& request,
                                                   const std::string& camera_yaml, const BagFrameFiles& files) {
  image_sequence::SequenceContents c;
  c.camera = image_sequence::read_camera_yaml(camera_yaml);
  c.camera_origin = camera_yaml;
  c.frames_origin = request.file + ": image_topic " + request.image_topic;
  c.odometry_origin = request.file + ": odometry_topic " + request.odometry_topic;

  if (bag.static_camera_mount) {
    const StaticTransform& tf = *bag.static_camera_mount;
    const auto& q = tf.rotation;  // x, y, z, w
    const Eigen::Matrix3d R = Eigen::Quaterniond(q[3], q[0], q[1], q[2]).normalized().toRotationMatrix();
    Pose6 recorded;
    recorded << tf.translation, euler_from_rotation(R);
    if (!same_mount(recorded, c.camera.mount)) {
      throw std::runtime_error(request.file + ": /tf_static " + request.base_frame + " -> " + bag.image_frame +
                               " places the camera at " + mount_text(recorded) + ", " + camera_yaml +
                               " gives mount " + mount_text(c.camera.mount) +
                               " ([x, y, z, roll, pitch, yaw], m and deg): they must agree");
    }
  }

  for (std::size_t i = 0; i < bag.images.size(); ++i) {
    const BagImageInfo& image = bag.images[i];
    const std::size_t index = i + 1;
    if (image.width != c.camera.width || image.height != c.camera.height) {
      throw std::runtime_error(c.frames_origin + ": message " + std::to_string(index) + " (stamp " +
                               stamp_text(image.t) + " s) is " + std::to_string(image.width) + "x" +
                               std::to_string(image.height) + ", " + camera_yaml + " says " +
                               std::to_string(c.camera.width) + "x" + std::to_string(c.camera.height));
    }
    c.frames.push_back({image.t, files.path(index), static_cast<int>(index)});
  }
  c.odometry = increasing(bag.odometry);
  for (const image_sequence::StampedPose2& p : increasing(bag.ground_truth))
    c.ground_truth.push_back({p.t, make_pose2d(p.pose[0], p.pose[1], p.pose[2])});
  return c;
}

}  // namespace mspace::rosbag_source
