// 6-DoF pose maths: rotations, Euler angles and the compound operators of
// T-RO eqs. 17–18 with analytic Jacobians (eq. 20).
//
// How the Jacobians are derived. A small change δe of the Euler angles
// rotates the frame on the left: R(e + δe) ≈ exp([ω]×)·R(e) with
// ω = E(e)·δe (euler_rate_matrix). So every Jacobian splits into
//   - how the output's rotation moves (an angular velocity ω_out, linear in
//     the input's ω_in), mapped back to output angles with E(e_out)⁻¹, and
//   - how translations move, using δ(R v) = ω × (R v) = −[R v]× ω.
#include "mspace/pose.hpp"

#include <Eigen/Dense>

#include <cmath>
#include <numbers>
#include <stdexcept>

namespace mspace {
namespace {

constexpr double kPi = std::numbers::pi;
/// Below this |cos φ| the Euler angles are at gimbal lock: θ and ψ are no
/// longer separable and E(e) is singular.
constexpr double kGimbalCos = 1e-9;

Vec3 translation_of(const Pose6& pose) { return pose.head<3>(); }
Vec3 angles_of(const Pose6& pose) { return pose.tail<3>(); }

/// The pose whose frame has origin t and axes R (in the parent frame).
Pose6 pose_from(const Vec3& t, const Mat3& R) {
  Pose6 pose;
  pose << t, euler_from_rotation(R);
  return pose;
}

/// [v]×, so that [v]× w = v × w.
Mat3 skew(const Vec3& v) {
  Mat3 S;
  S << 0.0, -v.z(), v.y(),  //
      v.z(), 0.0, -v.x(),   //
      -v.y(), v.x(), 0.0;
  return S;
}

/// E(e)⁻¹: angular velocity in the parent frame → Euler-angle rates.
/// Divides by cos φ, so it is undefined at gimbal lock.
Mat3 inverse_euler_rate_matrix(const Vec3& euler) {
  const double cphi = std::cos(euler[1]);
  if (std::abs(cphi) < kGimbalCos) {
    throw std::domain_error(
        "mspace: Euler-angle Jacobian undefined at gimbal lock (pitch φ = ±π/2, cos φ ≈ 0)");
  }
  const double ct = std::cos(euler[0]);
  const double st = std::sin(euler[0]);
  const double tphi = std::sin(euler[1]) / cphi;
  Mat3 Einv;
  Einv << ct * tphi, st * tphi, 1.0,  //
      -st, ct, 0.0,                   //
      ct / cphi, st / cphi, 0.0;
  return Einv;
}

/// ∂e_out/∂e_in when the output frame turns by ω_out = M·ω_in whenever the
/// input frame turns by ω_in: E(e_out)⁻¹ · M · E(e_in).
Mat3 angle_jacobian(const Vec3& e_out, const Mat3& M, const Vec3& e_in) {
  return inverse_euler_rate_matrix(e_out) * M * euler_rate_matrix(e_in);
}

}  // namespace

Pose6 make_pose(double x, double y, double z, double theta, double phi, double psi) {
  Pose6 pose;
  pose << x, y, z, theta, phi, psi;
  return pose;
}

Pose6 make_pose2d(double x, double y, double theta) { return make_pose(x, y, 0.0, theta, 0.0, 0.0); }

Mat3 rotation(const Pose6& pose) {
  const Vec3 e = angles_of(pose);
  const double ct = std::cos(e[0]), st = std::sin(e[0]);
  const double cp = std::cos(e[1]), sp = std::sin(e[1]);
  const double cs = std::cos(e[2]), ss = std::sin(e[2]);
  // Rz(θ)·Ry(φ)·Rx(ψ) multiplied out.
  Mat3 R;
  R << ct * cp, ct * sp * ss - st * cs, ct * sp * cs + st * ss,  //
      st * cp, st * sp * ss + ct * cs, st * sp * cs - ct * ss,   //
      -sp, cp * ss, cp * cs;
  return R;
}

Vec3 euler_from_rotation(const Mat3& R) {
  // R(2,0) = −sin φ and (R(0,0), R(1,0)) = cos φ·(cos θ, sin θ),
  // (R(2,1), R(2,2)) = cos φ·(sin ψ, cos ψ).
  const double cphi = std::hypot(R(0, 0), R(1, 0));
  const double phi = std::atan2(-R(2, 0), cphi);
  if (cphi < kGimbalCos) {
    // Gimbal lock: only θ ∓ ψ is defined. Choose ψ = 0; then
    // R(0,1) = −sin θ and R(1,1) = cos θ.
    return {wrap_angle(std::atan2(-R(0, 1), R(1, 1))), phi, 0.0};
  }
  return {wrap_angle(std::atan2(R(1, 0), R(0, 0))), phi, wrap_angle(std::atan2(R(2, 1), R(2, 2)))};
}

Mat3 euler_rate_matrix(const Vec3& euler) {
  // ω = θ̇·ẑ + φ̇·Rz(θ)ŷ + ψ̇·Rz(θ)Ry(φ)x̂ : each angle turns about its own
  // axis as seen in the parent frame.
  const double ct = std::cos(euler[0]), st = std::sin(euler[0]);
  const double cp = std::cos(euler[1]), sp = std::sin(euler[1]);
  Mat3 E;
  E << 0.0, -st, ct * cp,  //
      0.0, ct, st * cp,    //
      1.0, 0.0, -sp;
  return E;
}

double wrap_angle(double a) {
  // IEEE remainder is exact: a − n·2π with n the integer nearest a / 2π, ties
  // to even. For |a| ≤ π (2π is 2·kPi exactly, so π is kPi) n = 0 and it
  // returns a itself; so does this early return, for (−π, π], without the
  // library call (angle differences are mostly there: the innovations).
  if (a > -kPi && a <= kPi) return a;
  double w = std::remainder(a, 2.0 * kPi);  // in [−π, π]
  if (w <= -kPi) w += 2.0 * kPi;
  return w;
}

// T-RO eq. 17: t_c = t_a + R_a t_b, R_c = R_a R_b. Jacobians J_sr, J_ss of eq. 20.
Pose6 compound(const Pose6& a, const Pose6& b, Mat6* J_a, Mat6* J_b) {
  const Mat3 Ra = rotation(a);
  const Vec3 Ra_tb = Ra * translation_of(b);
  const Pose6 c = pose_from(translation_of(a) + Ra_tb, Ra * rotation(b));
  if (J_a != nullptr) {
    // Turning a by ω turns c by ω and moves t_c by ω × (R_a t_b).
    J_a->setZero();
    J_a->topLeftCorner<3, 3>().setIdentity();
    J_a->topRightCorner<3, 3>() = -skew(Ra_tb) * euler_rate_matrix(angles_of(a));
    J_a->bottomRightCorner<3, 3>() = angle_jacobian(angles_of(c), Mat3::Identity(), angles_of(a));
  }
  if (J_b != nullptr) {
    // Turning b by ω (in a's frame) turns c by R_a ω; t_c moves with R_a t_b.
    J_b->setZero();
    J_b->topLeftCorner<3, 3>() = Ra;
    J_b->bottomRightCorner<3, 3>() = angle_jacobian(angles_of(c), Ra, angles_of(b));
  }
  return c;
}

// ⊖a = ⊖a ⊕ 0 (the origin of the parent frame, seen from a).
Pose6 inverse(const Pose6& a, Mat6* J) { return relative(a, Pose6::Zero(), J, nullptr); }

// ⊖a ⊕ b (the form of T-RO eq. 18): t_c = R_aᵀ (t_b − t_a), R_c = R_aᵀ R_b.
Pose6 relative(const Pose6& a, const Pose6& b, Mat6* J_a, Mat6* J_b) {
  const Mat3 Ra_T = rotation(a).transpose();
  const Vec3 d = translation_of(b) - translation_of(a);
  const Pose6 c = pose_from(Ra_T * d, Ra_T * rotation(b));
  if (J_a != nullptr) {
    // Turning a by ω: R_c → R_aᵀ exp(−[ω]×) R_b = exp(−[R_aᵀω]×) R_c and
    // t_c → R_aᵀ (d − ω × d) = t_c + R_aᵀ [d]× ω.
    J_a->setZero();
    J_a->topLeftCorner<3, 3>() = -Ra_T;
    J_a->topRightCorner<3, 3>() = Ra_T * skew(d) * euler_rate_matrix(angles_of(a));
    J_a->bottomRightCorner<3, 3>() = angle_jacobian(angles_of(c), -Ra_T, angles_of(a));
  }
  if (J_b != nullptr) {
    // Turning b by ω turns c by R_aᵀ ω; t_c moves with R_aᵀ t_b.
    J_b->setZero();
    J_b->topLeftCorner<3, 3>() = Ra_T;
    J_b->bottomRightCorner<3, 3>() = angle_jacobian(angles_of(c), Ra_T, angles_of(b));
  }
  return c;
}

Eigen::Vector4d quaternion_xyzw(const Pose6& pose) {
  // q = q_z(θ) ⊗ q_y(φ) ⊗ q_x(ψ), multiplied out with half angles.
  const Vec3 half = angles_of(pose) / 2.0;
  const double ct = std::cos(half[0]), st = std::sin(half[0]);
  const double cp = std::cos(half[1]), sp = std::sin(half[1]);
  const double cs = std::cos(half[2]), ss = std::sin(half[2]);
  Eigen::Vector4d q(ct * cp * ss - st * sp * cs,  // x
                    ct * sp * cs + st * cp * ss,  // y
                    st * cp * cs - ct * sp * ss,  // z
                    ct * cp * cs + st * sp * ss);  // w
  return q[3] < 0.0 ? Eigen::Vector4d(-q) : q;
}

Pose6 pose_difference(const Pose6& a, const Pose6& b) {
  Pose6 d = a - b;
  for (int i = kTheta; i <= kPsi; ++i) d[i] = wrap_angle(d[i]);
  return d;
}

}  // namespace mspace
