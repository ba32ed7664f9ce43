// bag_camera.hpp — a bag's sensor_msgs/Image topic as the steps of an
// `image_sequence`: the steps (odometry at each image stamp, ground truth,
// the camera reading's intrinsics row and mount) are made by the
// image_sequence source's code, and the images reach the ceiling extractors
// as they do from a sequence folder: as an image file named by the reading's
// `file` (camera_model.hpp). Each image is written, when its step is
// delivered, as a lossless PNG holding the message's pixels (mono8, mono16,
// bgr8; rgb8 turned into bgr order) into a folder of this source under the
// system's temporary folder; the previous image's file is deleted then, and
// the folder when the source is destroyed. The extractors therefore decode
// exactly what a folder with the same PNGs gives them.
// No OpenCV or ROS header here (see bag_camera.cpp and bag_reader.cpp).
#pragma once

#include <cstddef>
#include <filesystem>
#include <memory>
#include <string>

#include "bag_reader.hpp"
#include "image_sequence/image_sequence.hpp"

namespace mspace::rosbag_source {

/// Writes the images of one topic to PNG files as their steps are delivered.
class BagFrameFiles {
 public:
  /// Creates this source's folder under the system's temporary folder.
  BagFrameFiles(const std::string& bag_file, const std::string& image_topic);
  ~BagFrameFiles();  ///< removes the folder and its files
  BagFrameFiles(const BagFrameFiles&) = delete;
  BagFrameFiles& operator=(const BagFrameFiles&) = delete;

  /// The file the image of message `index` (1-based, on the topic) is written to.
  std::string path(std::size_t index) const;
  /// Writes message `index`'s image to path(index) and deletes the one
  /// written before (its step has been processed: the kernel asks for one
  /// step at a time).
  void write(std::size_t index);

 private:
  BagImageReader reader_;
  std::filesystem::path folder_;
  std::string previous_;
};

/// The bag's images, odometry and ground truth as an image sequence with the
/// camera of `camera_yaml` (image_sequence's camera.yaml: intrinsics and
/// mount). Throws std::runtime_error naming the bag, topic, message and
/// camera.yaml when an image's size is not the camera's, and when the bag's
/// /tf_static places the camera elsewhere than camera.yaml's mount.
image_sequence::SequenceContents sequence_from_bag(const BagContents& bag, const BagRequest& request,
                                                   const std::string& camera_yaml, const BagFrameFiles& files);

}  // namespace mspace::rosbag_source
