// placement.cpp — see mspace/placement.hpp.
#include "mspace/placement.hpp"

#include "mspace/transform.hpp"

namespace mspace::placement {
namespace {

Eigen::MatrixXd symmetric(const Eigen::MatrixXd& m) { return 0.5 * (m + m.transpose()); }

}  // namespace

Placement place(const CoordLayout& layout, const Eigen::VectorXd& x_o, const Eigen::MatrixXd& J_ov,
                const Pose6& x_ms) {
  Eigen::MatrixXd J_fo;
  Placement p;
  p.x_f = to_map_frame(layout, x_o, x_ms, &J_fo, &p.J_s);
  p.J_v = J_fo * J_ov;  // chain rule through x_o(v)
  return p;
}

Eigen::MatrixXd covariance(const Placement& p, const Eigen::MatrixXd& C_v, const Mat6& C_ms) {
  return symmetric(p.J_v * C_v * p.J_v.transpose() + p.J_s * C_ms * p.J_s.transpose());
}

Extension full_extension(const Placement& p, const Eigen::MatrixXd& C_v, int sensor) {
  const auto n = p.x_f.size();
  Extension ext;
  ext.new_dims = static_cast<int>(n);
  ext.sensor = sensor;
  ext.J_sensor = p.J_s;
  ext.J_own = Eigen::MatrixXd(n, 0);
  ext.C_new = symmetric(p.J_v * C_v * p.J_v.transpose());
  return ext;
}

}  // namespace mspace::placement
