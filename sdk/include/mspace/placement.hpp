// mspace/placement.hpp — placing a new feature in the map from one
// measurement, for any coordinate layout: the generic part of the standard
// EKF landmark initialisation, shared by feature types (point, pole, …).
//
// A feature type supplies the sensor-frame coordinates x_o(v) of a measurement
// v with J_ov = ∂x_o/∂v. Then x_f = g(v, x_ms) = to_map_frame(x_o(v), x_ms) and
//   δx_f = J_v δv + J_s δx_ms,  J_v = J_fo J_ov,  J_s = J_fs   (inverse of eqs. 7–9, 34).
#pragma once

#include <Eigen/Core>

#include "mspace/coords.hpp"
#include "mspace/feature.hpp"
#include "mspace/measurement.hpp"

namespace mspace::placement {

/// A measurement placed in the map frame, with its Jacobians.
struct Placement {
  Eigen::VectorXd x_f;  ///< map-frame coordinates (layout size n)
  Eigen::MatrixXd J_v;  ///< n × dim v: ∂x_f/∂v
  Eigen::MatrixXd J_s;  ///< n × 6: ∂x_f/∂x_ms
};

/// x_f = to_map_frame(layout, x_o, x_ms) with J_v = J_fo · J_ov and J_s = J_fs.
Placement place(const CoordLayout& layout, const Eigen::VectorXd& x_o, const Eigen::MatrixXd& J_ov,
                const Pose6& x_ms);

/// First-order covariance of x_f when v and x_ms are independent:
/// J_v C_v J_vᵀ + J_s C_ms J_sᵀ (symmetrised). Used to gate tentative features.
Eigen::MatrixXd covariance(const Placement& p, const Eigen::MatrixXd& C_v, const Mat6& C_ms);

/// The Extension that initialises a feature whose M-space is all of x_f
/// (B = I): δx_p = J_s δx_ms + w with w ~ N(0, J_v C_v J_vᵀ), no old dimensions.
Extension full_extension(const Placement& p, const Eigen::MatrixXd& C_v, int sensor);

}  // namespace mspace::placement
