// mspace/motion_model.hpp — robot motion models (T-RO eqs. 25–27).
#pragma once

#include <vector>

#include <Eigen/Core>

#include "mspace/plugin.hpp"
#include "mspace/pose.hpp"

namespace mspace {

/// Result of one prediction x_r(t) = f(x_r(t−1), x_d(t, t−1)) (eq. 25).
/// Matrices are over the model's estimated pose coordinates (k of the 6).
struct MotionPrediction {
  Pose6 pose;          ///< predicted full 6-DoF pose
  Eigen::MatrixXd J_rr;  ///< k × k, ∂f/∂x_r
  Eigen::MatrixXd J_rd;  ///< k × d, ∂f/∂x_d
  Eigen::MatrixXd C_d;   ///< d × d, covariance of the increment x_d
};

class MotionModel : public PluginObject {
 public:
  /// The pose coordinates (PoseIndex values, ascending) the estimator holds
  /// for the robot, e.g. {kX, kY, kTheta} for a planar robot. The others are
  /// kept exactly as the model sets them.
  virtual std::vector<int> estimated_dofs() const = 0;
  /// Predicts from the previous pose and the increment x_d over dt seconds.
  virtual MotionPrediction predict(const Pose6& x_r, const Eigen::VectorXd& x_d, double dt) const = 0;

  /// Conformance support (`mspace check`): the length d of the increment x_d
  /// predict() expects. The default assumes an increment of the estimated
  /// pose coordinates (e.g. odometry (dx, dy, dθ) for a planar robot).
  virtual int increment_size() const { return static_cast<int>(estimated_dofs().size()); }
};

}  // namespace mspace
