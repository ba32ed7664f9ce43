// mspace/transform.hpp — the generic transformation of feature coordinates
// into the sensor frame, x_o = T(x_f | x_ms), T-RO eqs. 7–9 and 18, for every
// block kind of a CoordLayout, with its Jacobians
//   J_of = ∂x_o/∂x_mf  (block diagonal, eq. 19)
//   J_os = ∂x_o/∂x_ms  (eq. 19).
// 3-D points use R_ms^T (eq. 7); 2-D points (vertical lines) use the
// pseudo-rotation R^2D of eq. 34, which is the exact intersection of the
// vertical line with the sensor's x–y plane for a tilted sensor; scalars are
// unchanged (eq. 9). Nothing here knows a feature type.
#pragma once

#include <Eigen/Core>

#include "mspace/coords.hpp"
#include "mspace/pose.hpp"

namespace mspace {

using Mat2 = Eigen::Matrix2d;
using Vec2 = Eigen::Vector2d;

/// R^2D_{m,s} of eq. 34 for the sensor pose x_ms (map → sensor, 2-D points).
/// Throws std::domain_error when cos φ or cos ψ is ~0 (sensor looks along z).
Mat2 rotation2d(const Pose6& x_ms);
/// ∂R^2D/∂θ, ∂R^2D/∂φ, ∂R^2D/∂ψ.
void rotation2d_derivatives(const Pose6& x_ms, Mat2& dTheta, Mat2& dPhi, Mat2& dPsi);

/// x_o = T(x_f | x_ms) for all blocks of `layout` (eqs. 7–9, 34).
/// J_of (n×n) and J_os (n×6) are filled when non-null.
Eigen::VectorXd to_sensor_frame(const CoordLayout& layout, const Eigen::VectorXd& x_mf,
                                const Pose6& x_ms, Eigen::MatrixXd* J_of = nullptr,
                                Eigen::MatrixXd* J_os = nullptr);

/// The inverse transform: map-frame coordinates of coordinates given in the
/// sensor frame (a 2-D point is taken in the sensor's x–y plane). J_fo (n×n)
/// = ∂x_mf/∂x_o and J_fs (n×6) = ∂x_mf/∂x_ms when non-null. Used to place
/// new features from a measurement.
Eigen::VectorXd to_map_frame(const CoordLayout& layout, const Eigen::VectorXd& x_o,
                             const Pose6& x_ms, Eigen::MatrixXd* J_fo = nullptr,
                             Eigen::MatrixXd* J_fs = nullptr);

}  // namespace mspace
