// odometry2d.hpp — planar odometry motion model (T-RO eqs. 25–26).
//
// The robot's estimated pose coordinates are (x, y, θ); z, φ and ψ are carried
// along unchanged. The increment x_d = (dx, dy, dθ) is the motion in the frame
// of the previous robot pose, as wheel odometry reports it. The noise of x_d is
// the model of planar_odometry.hpp (shared with the sim_world simulator).
#pragma once

#include <Eigen/Core>
#include <vector>

#include "mspace/motion_model.hpp"
#include "planar_odometry.hpp"

namespace mspace::odometry2d {

/// J_rr = ∂f/∂(x, y, θ) and J_rd = ∂f/∂(dx, dy, dθ) of f (eq. 25), as used in eq. 26.
void motion_jacobians(const Pose6& x_r, const planar_odometry::Increment& x_d,
                      Eigen::Matrix3d& J_rr, Eigen::Matrix3d& J_rd);

class Odometry2dModel final : public MotionModel {
 public:
  explicit Odometry2dModel(const planar_odometry::NoiseModel& noise) : noise_(noise) {}
  /// From validated plugin parameters (those of param_specs()).
  explicit Odometry2dModel(const PluginArgs& args);

  /// The plugin's parameters: the shared odometry noise parameters.
  static std::vector<ParamSpec> param_specs();

  /// {kX, kY, kTheta}.
  std::vector<int> estimated_dofs() const override;
  /// Eq. 25 with the Jacobians and C_d of eq. 26. x_d must have 3 elements
  /// (throws std::invalid_argument otherwise); dt is not needed.
  MotionPrediction predict(const Pose6& x_r, const Eigen::VectorXd& x_d, double dt) const override;

  const planar_odometry::NoiseModel& noise() const { return noise_; }

 private:
  planar_odometry::NoiseModel noise_;
};

}  // namespace mspace::odometry2d
