// read_grey.hpp — loads the image of a camera reading as 8-bit grey.
// Internal to the camera extractors (ceiling_lines, lamps): it includes
// OpenCV, so no header that other plugins include may include it.
#pragma once

#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>
#include <stdexcept>
#include <string>

#include "camera_model.hpp"

namespace mspace::camera {

/// The reading's image as grey; throws std::runtime_error naming the file when
/// it cannot be read or is not of the size camera.yaml gives.
inline cv::Mat read_grey(const SensorReading& reading, const CameraModel& camera) {
  if (reading.file.empty()) {
    throw std::runtime_error("camera reading on channel '" + reading.channel +
                             "' has no image file");
  }
  cv::Mat image = cv::imread(reading.file, cv::IMREAD_GRAYSCALE);
  if (image.empty()) throw std::runtime_error(reading.file + ": cannot read image");
  if (image.cols != camera.width || image.rows != camera.height) {
    throw std::runtime_error(reading.file + ": image is " + std::to_string(image.cols) + "x" +
                             std::to_string(image.rows) + ", camera.yaml says " +
                             std::to_string(camera.width) + "x" + std::to_string(camera.height));
  }
  return image;
}

/// A cv::Mat header over a GreyView (no copy).
inline cv::Mat as_mat(const GreyView& view) {
  return {view.height, view.width, CV_8UC1, const_cast<std::uint8_t*>(view.data), view.step};
}

}  // namespace mspace::camera
