// mspace/pose.hpp — 6-DoF poses in the papers' convention and the compound
// operators of Smith, Self & Cheeseman used in T-RO eqs. 17–18.
//
// A pose is x = (x, y, z, θ, φ, ψ): translation of the frame origin in the
// parent frame and Euler angles θ (yaw, about z), φ (pitch, about y),
// ψ (roll, about x). The frame's axes expressed in the parent frame are the
// columns of R = Rz(θ)·Ry(φ)·Rx(ψ). This is the convention for which the 2-D
// pseudo-rotation of the Appendix (eq. 34) is exact (checked in the tests), so
// a point p given in the frame is R·p + t in the parent.
//
// Jacobians are analytic and taken with respect to the 6 pose coordinates in
// the order above.
#pragma once

#include <Eigen/Core>

namespace mspace {

using Vec3 = Eigen::Vector3d;
using Mat3 = Eigen::Matrix3d;
using Pose6 = Eigen::Matrix<double, 6, 1>;
using Mat6 = Eigen::Matrix<double, 6, 6>;

enum PoseIndex : int { kX = 0, kY = 1, kZ = 2, kTheta = 3, kPhi = 4, kPsi = 5 };

/// Pose with the given components (angles in radians).
Pose6 make_pose(double x, double y, double z, double theta, double phi, double psi);
/// Planar pose (z = φ = ψ = 0).
Pose6 make_pose2d(double x, double y, double theta);

/// R = Rz(θ)·Ry(φ)·Rx(ψ): frame axes in the parent frame.
Mat3 rotation(const Pose6& pose);
/// Euler angles (θ, φ, ψ) of a rotation matrix, θ and ψ in (-π, π], φ in [-π/2, π/2].
Vec3 euler_from_rotation(const Mat3& R);
/// E(θ, φ, ψ) maps Euler-angle rates to the angular velocity ω expressed in
/// the parent frame: ω = E · (θ̇, φ̇, ψ̇). A small change of the angles rotates
/// the frame by exp([ω]×) on the left.
Mat3 euler_rate_matrix(const Vec3& euler);

/// Wraps an angle to (-π, π].
double wrap_angle(double a);

/// Compound a ⊕ b: the pose of frame b (given in frame a) in a's parent
/// frame. T-RO eq. 17, x_ms = x_mr ⊕ x_rs. Optional Jacobians
/// J_a = ∂(a⊕b)/∂a (J_sr in eq. 20) and J_b = ∂(a⊕b)/∂b (J_ss).
Pose6 compound(const Pose6& a, const Pose6& b, Mat6* J_a = nullptr, Mat6* J_b = nullptr);

/// Inverse compound ⊖a: the parent frame's pose seen from frame a.
/// Optional Jacobian J = ∂(⊖a)/∂a.
Pose6 inverse(const Pose6& a, Mat6* J = nullptr);

/// ⊖a ⊕ b: pose b expressed in frame a (relative pose), with optional
/// Jacobians with respect to a and b.
Pose6 relative(const Pose6& a, const Pose6& b, Mat6* J_a = nullptr, Mat6* J_b = nullptr);

/// Unit quaternion (qx, qy, qz, qw) of the pose's rotation, qw ≥ 0 (TUM order).
Eigen::Vector4d quaternion_xyzw(const Pose6& pose);

/// Difference a − b with angles wrapped to (-π, π] (for errors and NEES).
Pose6 pose_difference(const Pose6& a, const Pose6& b);

}  // namespace mspace
