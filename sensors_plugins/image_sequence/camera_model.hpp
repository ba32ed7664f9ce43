// camera_model.hpp — the pinhole camera with OpenCV's lens distortion, shared
// by the `image_sequence` source, the ceiling renderer and the `ceiling_lines`
// and `lamps` extractors (header-only, Eigen only: no OpenCV here).
//
// Frames (issue 6): the camera frame has z along the optical axis, x along the
// image u axis (columns) and y along the image v axis (rows). A point
// (X, Y, Z) in the camera frame with Z > 0 has the normalised coordinates
// (x, y) = (X/Z, Y/Z); lens distortion (OpenCV's model, coefficients
// k1, k2, p1, p2, k3) moves them to (x_d, y_d) and the pixel is
//   u = fx·x_d + cx,  v = fy·y_d + cy.
//
// How the intrinsics reach the extractors: the `image_sequence` source puts
// them into every camera SensorReading as `values`, one row of 11 numbers
//   [width, height, fx, fy, cx, cy, k1, k2, p1, p2, k3]
// (reading_row() / camera_from_reading()), and the image path into `file`.
// camera.yaml stays the one place where a camera is described.
#pragma once

#include <Eigen/Core>
#include <array>
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <stdexcept>
#include <string>

#include "mspace/extractor.hpp"
#include "mspace/pose.hpp"

namespace mspace::camera {

/// A read-only view of an 8-bit grey image (row-major, `step` bytes per row),
/// so extractor and renderer interfaces need no OpenCV types.
struct GreyView {
  int width = 0;
  int height = 0;
  const std::uint8_t* data = nullptr;
  std::size_t step = 0;
};

/// Number of values in the intrinsics row of a camera reading.
inline constexpr Eigen::Index kReadingRowSize = 11;

struct CameraModel {
  int width = 0;   ///< pixels
  int height = 0;  ///< pixels
  double fx = 0.0, fy = 0.0;  ///< focal lengths (pixels)
  double cx = 0.0, cy = 0.0;  ///< principal point (pixels)
  std::array<double, 5> distortion{};  ///< k1, k2, p1, p2, k3 (OpenCV order)
  /// Camera pose in the robot frame (x_rs of T-RO eq. 17), from camera.yaml's
  /// `mount`. Not part of the reading row: the run configuration's
  /// sensors.<name>.mount must give the same pose.
  Pose6 mount = Pose6::Zero();

  /// The one focal length used for the ceiling-line measurement (eq. 18's v4).
  double focal() const { return 0.5 * (fx + fy); }

  /// OpenCV's distortion of normalised coordinates (x, y) → (x_d, y_d).
  Eigen::Vector2d distort(const Eigen::Vector2d& xy) const {
    const auto [k1, k2, p1, p2, k3] = distortion;
    const double x = xy.x(), y = xy.y();
    const double r2 = x * x + y * y;
    const double radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3));
    return {x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x),
            y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y};
  }

  /// Inverse of distort() by fixed-point iteration (as cv::undistortPoints);
  /// converges for the mild distortion of ordinary lenses.
  Eigen::Vector2d undistort(const Eigen::Vector2d& xy_d) const {
    Eigen::Vector2d xy = xy_d;
    for (int i = 0; i < 20; ++i) xy += xy_d - distort(xy);
    return xy;
  }

  /// Distorted pixel (u, v) → undistorted normalised coordinates (x, y).
  Eigen::Vector2d normalised_from_pixel(const Eigen::Vector2d& uv) const {
    return undistort({(uv.x() - cx) / fx, (uv.y() - cy) / fy});
  }

  /// Undistorted normalised (x, y) → distorted pixel (u, v).
  Eigen::Vector2d pixel_from_normalised(const Eigen::Vector2d& xy) const {
    const Eigen::Vector2d d = distort(xy);
    return {fx * d.x() + cx, fy * d.y() + cy};
  }

  /// Pixel of a point in the camera frame; false when it is behind the camera.
  bool project(const Eigen::Vector3d& p_camera, Eigen::Vector2d& uv) const {
    if (!(p_camera.z() > 0.0)) return false;
    uv = pixel_from_normalised(p_camera.head<2>() / p_camera.z());
    return true;
  }

  bool inside(const Eigen::Vector2d& uv) const {
    return uv.x() >= 0.0 && uv.y() >= 0.0 && uv.x() <= width - 1.0 && uv.y() <= height - 1.0;
  }
};

/// The intrinsics as the row a camera reading carries (see the file comment).
inline Eigen::RowVectorXd reading_row(const CameraModel& c) {
  Eigen::RowVectorXd row(kReadingRowSize);
  row << c.width, c.height, c.fx, c.fy, c.cx, c.cy, c.distortion[0], c.distortion[1],
      c.distortion[2], c.distortion[3], c.distortion[4];
  return row;
}

/// The intrinsics of a camera reading (mount left zero). Throws
/// std::runtime_error naming the channel when the row is malformed.
inline CameraModel camera_from_reading(const SensorReading& reading) {
  const Eigen::MatrixXd& m = reading.values;
  if (m.rows() != 1 || m.cols() != kReadingRowSize || !m.allFinite() || !(m(0, 2) > 0.0) ||
      !(m(0, 3) > 0.0) || !(m(0, 0) >= 1.0) || !(m(0, 1) >= 1.0)) {
    throw std::runtime_error("camera reading on channel '" + reading.channel +
                             "': expected one row [width, height, fx, fy, cx, cy, k1, k2, p1, "
                             "p2, k3] with positive sizes and focal lengths (got " +
                             std::to_string(m.rows()) + " x " + std::to_string(m.cols()) + ")");
  }
  CameraModel c;
  c.width = static_cast<int>(m(0, 0));
  c.height = static_cast<int>(m(0, 1));
  c.fx = m(0, 2);
  c.fy = m(0, 3);
  c.cx = m(0, 4);
  c.cy = m(0, 5);
  for (int i = 0; i < 5; ++i) c.distortion[static_cast<std::size_t>(i)] = m(0, 6 + i);
  return c;
}

}  // namespace mspace::camera
