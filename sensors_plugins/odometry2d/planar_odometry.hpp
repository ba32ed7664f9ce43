// planar_odometry.hpp — planar dead reckoning shared by the `odometry2d` motion
// model and the `sim_world` simulator.
//
// It holds the two things both must agree on:
//   - f of T-RO eq. 25 for a planar robot: how an increment x_d = (dx, dy, dθ),
//     the motion expressed in the frame of the previous pose, moves the pose;
//   - the noise model C_d(x_d) of that increment (the C_d of eq. 26) and the
//     YAML parameters that set it.
// The simulator moves its robot with exactly this f and draws its odometry
// noise from exactly this C_d, so the data obey the model the estimator assumes.
#pragma once

#include <Eigen/Core>
#include <cmath>
#include <numbers>
#include <vector>

#include "mspace/params.hpp"
#include "mspace/pose.hpp"

namespace mspace::planar_odometry {

/// x_d = (dx, dy, dθ): translation in the previous pose's frame (m) and turn (rad).
using Increment = Eigen::Vector3d;

/// f of eq. 25: x' = x + R(θ)·(dx, dy), θ' = wrap(θ + dθ); z, φ and ψ are copied.
inline Pose6 apply_increment(const Pose6& x_r, const Increment& x_d) {
  const double c = std::cos(x_r[kTheta]);
  const double s = std::sin(x_r[kTheta]);
  Pose6 moved = x_r;
  moved[kX] = x_r[kX] + c * x_d[0] - s * x_d[1];
  moved[kY] = x_r[kY] + s * x_d[0] + c * x_d[1];
  moved[kTheta] = wrap_angle(x_r[kTheta] + x_d[2]);
  return moved;
}

/// C_d = diag(σ_x², σ_y², σ_θ²) with, for the distance d = √(dx² + dy²),
///   σ_x = σ_y = xy_per_m·d + xy_floor,
///   σ_θ      = theta_per_rad·|dθ| + theta_per_m·d + theta_floor.
/// All members in SI units (m, rad).
struct NoiseModel {
  double xy_per_m = 0.0;       ///< m of σ_xy per m travelled
  double xy_floor = 0.0;       ///< m
  double theta_per_rad = 0.0;  ///< rad of σ_θ per rad turned
  double theta_per_m = 0.0;    ///< rad of σ_θ per m travelled
  double theta_floor = 0.0;    ///< rad

  /// (σ_x, σ_y, σ_θ) for the increment x_d.
  Eigen::Vector3d sigmas(const Increment& x_d) const {
    const double d = std::hypot(x_d[0], x_d[1]);
    const double sigma_xy = xy_per_m * d + xy_floor;
    const double sigma_theta = theta_per_rad * std::abs(x_d[2]) + theta_per_m * d + theta_floor;
    return {sigma_xy, sigma_xy, sigma_theta};
  }

  /// C_d(x_d) of eq. 26.
  Eigen::Matrix3d covariance(const Increment& x_d) const {
    return sigmas(x_d).array().square().matrix().asDiagonal();
  }
};

constexpr double kDegree = std::numbers::pi / 180.0;

/// The YAML parameters of the noise model, declared once for both plugins so a
/// run can give the simulator and the motion model the same values. Angles in
/// degrees (they read better); NoiseModel holds radians.
inline std::vector<ParamSpec> noise_param_specs() {
  return {
      param_double("xy_noise_per_m", 0.02, "odometry: std of dx and dy per metre travelled (m/m)",
                   0.0),
      param_double("xy_noise_floor", 0.001,
                   "odometry: std of dx and dy per step, constant part (m)", 0.0),
      param_double("theta_noise_per_rad", 0.02,
                   "odometry: std of dtheta per radian turned (rad/rad, i.e. deg/deg)", 0.0),
      param_double("theta_noise_per_m", 0.5,
                   "odometry: std of dtheta per metre travelled (DEGREES per m)", 0.0),
      param_double("theta_noise_floor", 0.01,
                   "odometry: std of dtheta per step, constant part (DEGREES)", 0.0),
  };
}

/// The noise model from parameters declared by noise_param_specs().
inline NoiseModel noise_from_params(const Params& params) {
  NoiseModel noise;
  noise.xy_per_m = params.get_double("xy_noise_per_m");
  noise.xy_floor = params.get_double("xy_noise_floor");
  noise.theta_per_rad = params.get_double("theta_noise_per_rad");
  noise.theta_per_m = params.get_double("theta_noise_per_m") * kDegree;
  noise.theta_floor = params.get_double("theta_noise_floor") * kDegree;
  return noise;
}

}  // namespace mspace::planar_odometry
