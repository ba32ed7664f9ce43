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

/// 16-bit grey as 8-bit. Cameras with 10, 12 or 14 bits store them in 16-bit
/// files in the low bits (0–4095 for 12 bits), which OpenCV's plain 8-bit
/// conversion (÷ 256) would squeeze into 16 grey levels. The full scale is
/// therefore the smallest of 2^10 − 1, 2^12 − 1, 2^14 − 1, 2^16 − 1 that holds
/// the image's brightest pixel, and that maps to 255. (A frame of a 12-bit
/// camera with nothing above 1023 is then read 4× brighter; the extractors'
/// relative thresholds do not depend on the exposure.)
inline cv::Mat eight_bit_from_16(const cv::Mat& deep) {
  double max_value = 0.0;
  cv::minMaxLoc(deep, nullptr, &max_value);
  double full_scale = 65535.0;
  for (const double candidate : {1023.0, 4095.0, 16383.0}) {
    if (max_value <= candidate) {
      full_scale = candidate;
      break;
    }
  }
  cv::Mat grey;
  deep.convertTo(grey, CV_8U, 255.0 / full_scale);
  return grey;
}

/// The reading's image as 8-bit grey (colour images are converted to grey,
/// 16-bit ones by eight_bit_from_16); throws std::runtime_error naming the
/// file when it cannot be read or is not of the size camera.yaml gives.
inline cv::Mat read_grey(const SensorReading& reading, const CameraModel& camera) {
  if (reading.file.empty()) {
    throw std::runtime_error("camera reading on channel '" + reading.channel +
                             "' has no image file");
  }
  cv::Mat image = cv::imread(reading.file, cv::IMREAD_GRAYSCALE | cv::IMREAD_ANYDEPTH);
  if (image.empty()) throw std::runtime_error(reading.file + ": cannot read image");
  if (image.depth() == CV_16U) image = eight_bit_from_16(image);
  else if (image.depth() != CV_8U) image.convertTo(image, CV_8U);
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
