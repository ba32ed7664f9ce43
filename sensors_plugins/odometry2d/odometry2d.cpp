#include "odometry2d.hpp"

#include <cmath>
#include <stdexcept>
#include <string>

namespace mspace::odometry2d {

using planar_odometry::Increment;

void motion_jacobians(const Pose6& x_r, const Increment& x_d, Eigen::Matrix3d& J_rr,
                      Eigen::Matrix3d& J_rd) {
  const double c = std::cos(x_r[kTheta]);
  const double s = std::sin(x_r[kTheta]);
  // f(x, y, θ; dx, dy, dθ) = (x + c·dx − s·dy, y + s·dx + c·dy, θ + dθ), eq. 25.
  J_rr << 1.0, 0.0, -s * x_d[0] - c * x_d[1],  //
      0.0, 1.0, c * x_d[0] - s * x_d[1],       //
      0.0, 0.0, 1.0;
  J_rd << c, -s, 0.0,  //
      s, c, 0.0,       //
      0.0, 0.0, 1.0;
}

Odometry2dModel::Odometry2dModel(const PluginArgs& args)
    : noise_(planar_odometry::noise_from_params(args.params)) {}

std::vector<ParamSpec> Odometry2dModel::param_specs() {
  return planar_odometry::noise_param_specs();
}

std::vector<int> Odometry2dModel::estimated_dofs() const { return {kX, kY, kTheta}; }

MotionPrediction Odometry2dModel::predict(const Pose6& x_r, const Eigen::VectorXd& x_d,
                                          double /*dt*/) const {
  if (x_d.size() != 3) {
    throw std::invalid_argument(
        "odometry2d: the odometry increment must be (dx, dy, dtheta), got " +
        std::to_string(x_d.size()) + " values");
  }
  const Increment increment = x_d;
  Eigen::Matrix3d J_rr;
  Eigen::Matrix3d J_rd;
  motion_jacobians(x_r, increment, J_rr, J_rd);

  MotionPrediction prediction;
  prediction.pose = planar_odometry::apply_increment(x_r, increment);
  prediction.J_rr = J_rr;
  prediction.J_rd = J_rd;
  prediction.C_d = noise_.covariance(increment);
  return prediction;
}

}  // namespace mspace::odometry2d
