// evaluation.hpp — trajectory accuracy against a reference (ground truth).
#pragma once

#include <cstddef>
#include <cstdint>
#include <optional>
#include <vector>

#include <Eigen/Core>

#include "mspace/pose.hpp"

namespace mspace::kernel {

struct StampedPose {
  double t = 0.0;
  Pose6 pose;
  std::uint8_t known = 0x3F;  ///< which coordinates are meaningful (bits 1 << PoseIndex)
};

/// The pose at time t, interpolated linearly between the two poses of the
/// (time-ordered) trajectory around t (angles along the shorter way);
/// std::nullopt when t is outside it or the bracketing poses are more than
/// max_gap seconds apart.
std::optional<Pose6> interpolate(const std::vector<StampedPose>& trajectory, double t, double max_gap);

/// Rigid planar transform ref ≈ R(θ)·est + t.
struct Se2Alignment {
  double theta = 0.0;
  Eigen::Vector2d t = Eigen::Vector2d::Zero();
  Eigen::Vector2d apply(const Eigen::Vector2d& p) const;
};

/// Least-squares SE(2) alignment of corresponding points (closed form:
/// centroids + the angle of the cross-covariance, Umeyama without scale).
Se2Alignment align_se2(const std::vector<Eigen::Vector2d>& est, const std::vector<Eigen::Vector2d>& ref);

struct TrajectoryErrors {
  std::size_t matched = 0;        ///< reference poses paired with an estimate
  double ate_rmse = 0.0;          ///< after SE(2) alignment (m)
  double ate_median = 0.0;
  double ate_max = 0.0;
  double final_translation = 0.0;  ///< last paired pose, without alignment (m)
  /// |heading error| of the last paired pose (rad), when the reference knows headings.
  std::optional<double> final_heading;
};

/// Pairs each reference pose with the estimate interpolated at its time (see
/// interpolate(); max_gap in seconds) and computes the absolute trajectory
/// error (ATE) after SE(2) alignment, plus the final pose error in the map frame.
TrajectoryErrors evaluate_trajectory(const std::vector<StampedPose>& estimate,
                                     const std::vector<StampedPose>& reference, double max_gap);

}  // namespace mspace::kernel
