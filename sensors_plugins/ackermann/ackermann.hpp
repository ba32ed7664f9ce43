// ackermann.hpp — the `ackermann` motion model: ACFR's car model of the
// Victoria Park vehicle (T-RO eqs. 25–26).
//
// The estimated robot pose is (x, y, θ) of the centre of the rear axle (z, φ,
// ψ are carried along). The increment x_d = (v_e, α) is the speed measured by
// the encoder on the rear-left wheel (m/s) and the front-wheel steering angle
// (rad, positive = left turn), held over the step's dt seconds. The encoder
// wheel is H to the left of the rear-axle centre, so on a turn it runs faster
// than the centre:
//   v_c = v_e / (1 − tan(α)·H/L)                 (L: wheelbase)
//   ẋ = v_c cos θ,  ẏ = v_c sin θ,  θ̇ = v_c tan(α) / L.
// f of eq. 25 is one Euler step of these over dt. The laser (and the GPS
// antenna) sit at (L + a, b) in the vehicle frame: that is the sensor mount
// x_rs of the run configuration, not a parameter here. Composing the mount
// with this model gives exactly the laser-point kinematics of the data set's
// README, whose `a` is the distance from the rear axle to the laser, L + a.
//
// Calibration: the steering encoder reads α − `steering_offset` (its zero is
// off by that much; the model adds it back to every sample). For the Victoria
// Park log it is measured from the odometry's disagreement with the motion the
// trees show (README, "Victoria Park").
//
// Noise (the C_d of eq. 26): independent errors on v_e and α with
//   σ_v = speed_sigma + speed_sigma_rel·|v_e|,  σ_α = steering_sigma,
// stated for one dead-reckoning period `noise_period` (25 ms for the ACFR
// log). A step of another length dt gets C_d·(noise_period/dt), so that the
// pose noise J_rd C_d J_rdᵀ (J_rd ∝ dt) grows linearly with time however the
// data source splits the intervals (e.g. at laser and GPS time stamps).
#pragma once

#include <Eigen/Core>
#include <vector>

#include "mspace/motion_model.hpp"

namespace mspace::ackermann {

/// Vehicle constants and noise, SI units (angles in radians).
struct AckermannConfig {
  double wheelbase = 2.83;       ///< L (m)
  double encoder_offset = 0.76;  ///< H (m), encoder wheel left of the rear-axle centre
  double speed_sigma = 0.05;     ///< m/s per noise_period
  double speed_sigma_rel = 0.0;  ///< fraction of |v_e|
  double steering_sigma = 0.01;  ///< rad per noise_period
  double noise_period = 0.025;   ///< s
  double steering_offset = 0.0;  ///< rad, added to every steering sample
};

/// Speed of the rear-axle centre v_c for encoder speed v_e and steering α,
/// with ∂v_c/∂v_e and ∂v_c/∂α (if non-null). Throws std::invalid_argument
/// when 1 − tan(α)·H/L ≤ 0.05 (a steering angle no car reaches).
double centre_speed(const AckermannConfig& config, double v_e, double alpha, double* d_ve = nullptr,
                    double* d_alpha = nullptr);

/// f of eq. 25 with J_rr = ∂f/∂(x, y, θ) and J_rd = ∂f/∂(v_e, α) (eq. 26).
Pose6 motion(const AckermannConfig& config, const Pose6& x_r, const Eigen::Vector2d& x_d, double dt,
             Eigen::Matrix3d* J_rr = nullptr, Eigen::Matrix<double, 3, 2>* J_rd = nullptr);

/// C_d for increment x_d over dt (see the file comment).
Eigen::Matrix2d increment_covariance(const AckermannConfig& config, const Eigen::Vector2d& x_d, double dt);

class AckermannModel final : public MotionModel {
 public:
  explicit AckermannModel(const AckermannConfig& config) : config_(config) {}
  /// From validated plugin parameters (those of param_specs()).
  explicit AckermannModel(const PluginArgs& args);

  /// wheelbase, encoder_offset, speed_sigma, speed_sigma_rel,
  /// steering_sigma_deg, noise_period, steering_offset_deg.
  static std::vector<ParamSpec> param_specs();

  /// {kX, kY, kTheta}.
  std::vector<int> estimated_dofs() const override;
  /// x_d = (v_e, α): 2.
  int increment_size() const override { return 2; }
  /// x_d = (v_e, α − steering_offset); throws std::invalid_argument for another size or a
  /// negative dt. dt = 0 (the first step) leaves the pose unchanged.
  MotionPrediction predict(const Pose6& x_r, const Eigen::VectorXd& x_d, double dt) const override;

  const AckermannConfig& config() const { return config_; }

 private:
  AckermannConfig config_;
};

}  // namespace mspace::ackermann
