// evaluation.hpp — trajectory accuracy against a reference (ground truth).
#pragma once

#include <cstddef>
#include <vector>

#include <Eigen/Core>

#include "mspace/pose.hpp"

namespace mspace::kernel {

struct StampedPose {
  double t = 0.0;
  Pose6 pose;
};

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
  double final_heading = 0.0;      ///< |heading error| of the last paired pose (rad)
};

/// Pairs each reference pose with the estimate closest in time (within
/// max_dt seconds) and computes the absolute trajectory error (ATE) after
/// SE(2) alignment, plus the final pose error in the map frame.
TrajectoryErrors evaluate_trajectory(const std::vector<StampedPose>& estimate,
                                     const std::vector<StampedPose>& reference, double max_dt);

}  // namespace mspace::kernel
