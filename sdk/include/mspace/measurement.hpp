// mspace/measurement.hpp — what extractors produce and features consume: the
// measurement v of T-RO eq. 16 and the sensor pose x_ms (eq. 17) it was taken from.
#pragma once

#include <cstdint>
#include <string>

#include <Eigen/Core>

#include "mspace/pose.hpp"

namespace mspace {

/// One typed measurement v (T-RO §V-A) extracted from one sensor reading.
/// `kind` names the measurement model (e.g. "range_bearing_elevation",
/// "line2d"); a feature type rejects kinds it does not understand.
struct Measurement {
  std::string kind;
  Eigen::VectorXd v;    ///< the measurement vector
  Eigen::MatrixXd C_v;  ///< its covariance
  /// Optional dense evidence in the sensor frame, one column per sample
  /// (e.g. the inlier scan points of a line segment, 2×N).
  Eigen::MatrixXd dense;
  /// Extractor-specific flags (e.g. which segment ends are real ends).
  std::uint32_t flags = 0;
};

/// Where and when a measurement was taken, as the kernel knows it at the
/// moment it hands the measurement to a feature.
struct SensorView {
  double t = 0.0;          ///< data time stamp (s)
  int sensor = 0;          ///< index of the sensor in the run configuration
  Pose6 x_ms;              ///< sensor pose in the map frame, eq. 17
  Mat6 C_ms;               ///< covariance of x_ms (from the robot pose covariance)
  double path_distance = 0.0;  ///< the robot's path "distance" (translation + weighted rotation) so far
};

}  // namespace mspace
