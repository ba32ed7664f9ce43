// ackermann.cpp — see ackermann.hpp.
#include "ackermann.hpp"

#include <cmath>
#include <numbers>
#include <stdexcept>
#include <string>

namespace mspace::ackermann {
namespace {

/// Below this value of 1 − tan(α)·H/L the encoder model is meaningless.
constexpr double kMinEncoderFactor = 0.05;
constexpr double kDegree = std::numbers::pi / 180.0;

}  // namespace

double centre_speed(const AckermannConfig& config, double v_e, double alpha, double* d_ve, double* d_alpha) {
  const double k = config.encoder_offset / config.wheelbase;
  const double t = std::tan(alpha);
  const double factor = 1.0 - t * k;
  if (factor <= kMinEncoderFactor) {
    throw std::invalid_argument("ackermann: steering angle " + std::to_string(alpha) +
                                " rad is outside the model (1 - tan(alpha) H/L = " + std::to_string(factor) + ")");
  }
  const double v_c = v_e / factor;
  if (d_ve != nullptr) *d_ve = 1.0 / factor;
  if (d_alpha != nullptr) *d_alpha = v_c * k * (1.0 + t * t) / factor;  // d tan α = sec²α dα
  return v_c;
}

// eq. 25: one Euler step of ẋ = v_c cos θ, ẏ = v_c sin θ, θ̇ = v_c tan α / L.
Pose6 motion(const AckermannConfig& config, const Pose6& x_r, const Eigen::Vector2d& x_d, double dt,
             Eigen::Matrix3d* J_rr, Eigen::Matrix<double, 3, 2>* J_rd) {
  const double v_e = x_d[0], alpha = x_d[1];
  double dvc_dve = 0.0, dvc_dalpha = 0.0;
  const double v_c = centre_speed(config, v_e, alpha, &dvc_dve, &dvc_dalpha);
  const double t = std::tan(alpha);
  const double omega = v_c * t / config.wheelbase;
  const double c = std::cos(x_r[kTheta]), s = std::sin(x_r[kTheta]);

  Pose6 moved = x_r;
  moved[kX] += dt * v_c * c;
  moved[kY] += dt * v_c * s;
  moved[kTheta] = wrap_angle(x_r[kTheta] + dt * omega);

  if (J_rr != nullptr) {
    *J_rr << 1.0, 0.0, -dt * v_c * s,  //
        0.0, 1.0, dt * v_c * c,        //
        0.0, 0.0, 1.0;
  }
  if (J_rd != nullptr) {
    // eq. 26: columns ∂f/∂v_e and ∂f/∂α through v_c(v_e, α) and ω = v_c tan α / L.
    const double domega_dve = dvc_dve * t / config.wheelbase;
    const double domega_dalpha = (dvc_dalpha * t + v_c * (1.0 + t * t)) / config.wheelbase;
    *J_rd << dt * c * dvc_dve, dt * c * dvc_dalpha,  //
        dt * s * dvc_dve, dt * s * dvc_dalpha,       //
        dt * domega_dve, dt * domega_dalpha;
  }
  return moved;
}

Eigen::Matrix2d increment_covariance(const AckermannConfig& config, const Eigen::Vector2d& x_d, double dt) {
  const double sigma_v = config.speed_sigma + config.speed_sigma_rel * std::abs(x_d[0]);
  const double scale = dt > 0.0 ? config.noise_period / dt : 1.0;  // dt = 0: J_rd = 0 anyway
  return Eigen::Vector2d(sigma_v * sigma_v * scale, config.steering_sigma * config.steering_sigma * scale)
      .asDiagonal();
}

// ---------------------------------------------------------------- AckermannModel

std::vector<ParamSpec> AckermannModel::param_specs() {
  return {
      param_double("wheelbase", 2.83, "L: distance between the axles (m)", 0.1),
      param_double("encoder_offset", 0.76, "H: the speed-encoder wheel is this far left of the rear-axle centre (m)",
                   0.0),
      param_double("speed_sigma", 0.05, "std of the encoder speed per noise_period, constant part (m/s)", 0.0),
      param_double("speed_sigma_rel", 0.0, "std of the encoder speed per noise_period, fraction of |speed|", 0.0),
      param_double("steering_sigma_deg", 0.5, "std of the steering angle per noise_period (DEGREES)", 0.0),
      param_double("noise_period", 0.025,
                   "time step the sigmas refer to (s); other steps are scaled so noise grows linearly in time",
                   1e-6),
      param_double("steering_offset_deg", 0.0,
                   "added to every steering sample: the steering encoder's zero error (DEGREES, positive = left)", -10.0,
                   10.0),
  };
}

AckermannModel::AckermannModel(const PluginArgs& args) {
  const Params& p = args.params;
  config_.wheelbase = p.get_double("wheelbase");
  config_.encoder_offset = p.get_double("encoder_offset");
  config_.speed_sigma = p.get_double("speed_sigma");
  config_.speed_sigma_rel = p.get_double("speed_sigma_rel");
  config_.steering_sigma = p.get_double("steering_sigma_deg") * kDegree;
  config_.noise_period = p.get_double("noise_period");
  config_.steering_offset = p.get_double("steering_offset_deg") * kDegree;
}

std::vector<int> AckermannModel::estimated_dofs() const { return {kX, kY, kTheta}; }

MotionPrediction AckermannModel::predict(const Pose6& x_r, const Eigen::VectorXd& x_d, double dt) const {
  if (x_d.size() != 2) {
    throw std::invalid_argument("ackermann: the increment must be (speed, steering), got " +
                                std::to_string(x_d.size()) + " values");
  }
  if (dt < 0.0) throw std::invalid_argument("ackermann: negative time step " + std::to_string(dt) + " s");
  const Eigen::Vector2d increment(x_d[0], x_d[1] + config_.steering_offset);
  Eigen::Matrix3d J_rr;
  Eigen::Matrix<double, 3, 2> J_rd;
  MotionPrediction prediction;
  prediction.pose = motion(config_, x_r, increment, dt, &J_rr, &J_rd);
  prediction.J_rr = J_rr;
  prediction.J_rd = J_rd;
  prediction.C_d = increment_covariance(config_, increment, dt);
  return prediction;
}

}  // namespace mspace::ackermann
