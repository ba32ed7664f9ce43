// Generic coordinate transforms between the map and a sensor frame, T-RO
// eqs. 7–9 (one rule per block kind) with the 2-D pseudo-rotation of eq. 34,
// and their analytic Jacobians J_of, J_os (eq. 19).
//
// Notation: the sensor pose x_ms has translation t, Euler angles e and
// rotation R (sensor axes in the map frame). A small change δe of the angles
// turns the sensor by ω = E(e)·δe on the left (see pose.cpp), so for any
// fixed vector v: δ(R v) = ω × (R v).
#include "mspace/transform.hpp"

#include <Eigen/Dense>

#include <cmath>
#include <stdexcept>
#include <string>

namespace mspace {
namespace {

/// Below this |cos φ| or |cos ψ| eq. 34 is undefined: the sensor's x–y plane
/// is vertical and does not cut a vertical line in a single point.
constexpr double kTiltCos = 1e-9;

using Vec = Eigen::VectorXd;
using Mat = Eigen::MatrixXd;

/// Sines, cosines and tangents of the sensor angles that eq. 34 needs.
struct TiltTrig {
  double st, ct, sp, cp, tp, ss, cs, ts;

  explicit TiltTrig(const Pose6& x_ms)
      : st(std::sin(x_ms[kTheta])), ct(std::cos(x_ms[kTheta])),
        sp(std::sin(x_ms[kPhi])), cp(std::cos(x_ms[kPhi])),
        ss(std::sin(x_ms[kPsi])), cs(std::cos(x_ms[kPsi])) {
    if (std::abs(cp) < kTiltCos || std::abs(cs) < kTiltCos) {
      throw std::domain_error(
          "mspace: 2-D pseudo-rotation (eq. 34) undefined: cos φ or cos ψ ≈ 0, the sensor's "
          "x–y plane is vertical (φ = " + std::to_string(x_ms[kPhi]) +
          ", ψ = " + std::to_string(x_ms[kPsi]) + ")");
    }
    tp = sp / cp;
    ts = ss / cs;
  }
};

/// ∂(R v)/∂(θ, φ, ψ) for a fixed vector v: column i is E_i × (R v), where
/// E_i is column i of the Euler rate matrix.
Mat3 d_rotated_d_angles(const Pose6& x_ms, const Vec3& Rv) {
  const Mat3 E = euler_rate_matrix(x_ms.tail<3>());
  Mat3 J;
  for (int i = 0; i < 3; ++i) J.col(i) = E.col(i).cross(Rv);
  return J;
}

bool has_point2d_block(const CoordLayout& layout) {
  for (BlockKind kind : layout.blocks()) {
    if (kind == BlockKind::Point2D) return true;
  }
  return false;
}

void check_size(const CoordLayout& layout, const Vec& x, const char* what) {
  if (x.size() != layout.size()) {
    throw std::invalid_argument(std::string("mspace: ") + what + " has " + std::to_string(x.size()) +
                                " coordinates but layout " + layout.describe() + " needs " +
                                std::to_string(layout.size()));
  }
}

/// Everything about the sensor pose the block rules need, computed once.
struct SensorFrame {
  Pose6 pose;
  Vec3 t;
  Mat3 R;
  // Eq. 34 and its derivatives; only filled when need_2d (they may be undefined).
  Mat2 R2D = Mat2::Zero();
  Mat2 dR2D[3] = {Mat2::Zero(), Mat2::Zero(), Mat2::Zero()};  // ∂/∂θ, ∂/∂φ, ∂/∂ψ

  SensorFrame(const Pose6& x_ms, bool need_2d)
      : pose(x_ms), t(x_ms.head<3>()), R(rotation(x_ms)) {
    if (need_2d) {
      R2D = rotation2d(x_ms);
      rotation2d_derivatives(x_ms, dR2D[0], dR2D[1], dR2D[2]);
    }
  }
};

/// Output vector and optional Jacobians of one transform call; each block
/// rule writes its rows.
struct BlockOutput {
  Vec& x;
  Mat* J_coords;  // n×n, block diagonal
  Mat* J_pose;    // n×6
};

// --- map → sensor ----------------------------------------------------------

// Eq. 7: x_o = Rᵀ (x_f − t). Turning the sensor by ω gives
// δx_o = −Rᵀ (ω × (x_f − t)).
void point3d_to_sensor(const SensorFrame& s, const Vec3& x_f, int row, BlockOutput& out) {
  const Vec3 d = x_f - s.t;
  out.x.segment<3>(row) = s.R.transpose() * d;
  if (out.J_coords != nullptr) out.J_coords->block<3, 3>(row, row) = s.R.transpose();
  if (out.J_pose != nullptr) {
    out.J_pose->block<3, 3>(row, kX) = -s.R.transpose();
    out.J_pose->block<3, 3>(row, kTheta) = -s.R.transpose() * d_rotated_d_angles(s.pose, d);
  }
}

// Eq. 8 with R^2D of eq. 34: x_o = R^2D (x_f − t_xy). Independent of z.
void point2d_to_sensor(const SensorFrame& s, const Vec2& x_f, int row, BlockOutput& out) {
  const Vec2 d = x_f - s.t.head<2>();
  out.x.segment<2>(row) = s.R2D * d;
  if (out.J_coords != nullptr) out.J_coords->block<2, 2>(row, row) = s.R2D;
  if (out.J_pose != nullptr) {
    out.J_pose->block<2, 2>(row, kX) = -s.R2D;
    for (int i = 0; i < 3; ++i) out.J_pose->block<2, 1>(row, kTheta + i) = s.dR2D[i] * d;
  }
}

// --- sensor → map ----------------------------------------------------------

// Inverse of eq. 7: x_f = R x_o + t.
void point3d_to_map(const SensorFrame& s, const Vec3& x_o, int row, BlockOutput& out) {
  const Vec3 Rx = s.R * x_o;
  out.x.segment<3>(row) = Rx + s.t;
  if (out.J_coords != nullptr) out.J_coords->block<3, 3>(row, row) = s.R;
  if (out.J_pose != nullptr) {
    out.J_pose->block<3, 3>(row, kX).setIdentity();
    out.J_pose->block<3, 3>(row, kTheta) = d_rotated_d_angles(s.pose, Rx);
  }
}

// Inverse of eq. 8: the point (x_o, 0) of the sensor's x–y plane, in the map,
// projected along z: x_f = R[0:2,0:2] x_o + t_xy. R^2D is the Schur complement
// of Rᵀ(2,2) in Rᵀ, so R[0:2,0:2] = (R^2D)⁻¹ and this inverts eq. 34 exactly.
void point2d_to_map(const SensorFrame& s, const Vec2& x_o, int row, BlockOutput& out) {
  const Vec3 Rx = s.R.leftCols<2>() * x_o;
  out.x.segment<2>(row) = Rx.head<2>() + s.t.head<2>();
  if (out.J_coords != nullptr) out.J_coords->block<2, 2>(row, row) = s.R.topLeftCorner<2, 2>();
  if (out.J_pose != nullptr) {
    out.J_pose->block<2, 2>(row, kX).setIdentity();
    out.J_pose->block<2, 3>(row, kTheta) = d_rotated_d_angles(s.pose, Rx).topRows<2>();
  }
}

// Eq. 9: scalars are the same in every frame.
void scalar_copy(double value, int row, BlockOutput& out) {
  out.x[row] = value;
  if (out.J_coords != nullptr) (*out.J_coords)(row, row) = 1.0;
}

using Point3Rule = void (*)(const SensorFrame&, const Vec3&, int, BlockOutput&);
using Point2Rule = void (*)(const SensorFrame&, const Vec2&, int, BlockOutput&);

/// Applies one rule per block of `layout` to `in`; shared by both directions.
Vec transform_blocks(const CoordLayout& layout, const Vec& in, const SensorFrame& frame,
                     Mat* J_coords, Mat* J_pose, Point3Rule point3d, Point2Rule point2d) {
  const int n = layout.size();
  Vec x(n);
  if (J_coords != nullptr) J_coords->setZero(n, n);
  if (J_pose != nullptr) J_pose->setZero(n, 6);
  BlockOutput out{x, J_coords, J_pose};
  for (int b = 0; b < layout.num_blocks(); ++b) {
    const int row = layout.offset(b);
    switch (layout.kind(b)) {
      case BlockKind::Point3D: point3d(frame, in.segment<3>(row), row, out); break;
      case BlockKind::Point2D: point2d(frame, in.segment<2>(row), row, out); break;
      case BlockKind::Scalar: scalar_copy(in[row], row, out); break;
    }
  }
  return x;
}

}  // namespace

// T-RO eq. 34, the pseudo-rotation taking a vertical line's map (x, y) to
// where it cuts the tilted sensor's x–y plane.
Mat2 rotation2d(const Pose6& x_ms) {
  const TiltTrig c(x_ms);
  Mat2 R2D;
  R2D << (c.ct + c.st * c.sp * c.ts) / c.cp, (c.st - c.ct * c.sp * c.ts) / c.cp,  //
      -c.st / c.cs, c.ct / c.cs;
  return R2D;
}

// Derivatives of eq. 34 written as
//   a11 = cos θ / cos φ + sin θ tan φ tan ψ,   a12 = sin θ / cos φ − cos θ tan φ tan ψ,
//   a21 = −sin θ / cos ψ,                      a22 = cos θ / cos ψ.
void rotation2d_derivatives(const Pose6& x_ms, Mat2& dTheta, Mat2& dPhi, Mat2& dPsi) {
  const TiltTrig c(x_ms);
  const double cp2 = c.cp * c.cp;
  const double cs2 = c.cs * c.cs;
  // ∂/∂θ maps (a11, a12) → (−a12, a11) and (a21, a22) → (−a22, a21).
  dTheta << (-c.st + c.ct * c.sp * c.ts) / c.cp, (c.ct + c.st * c.sp * c.ts) / c.cp,  //
      -c.ct / c.cs, -c.st / c.cs;
  dPhi << (c.ct * c.sp + c.st * c.ts) / cp2, (c.st * c.sp - c.ct * c.ts) / cp2,  //
      0.0, 0.0;
  dPsi << c.st * c.tp / cs2, -c.ct * c.tp / cs2,  //
      -c.st * c.ss / cs2, c.ct * c.ss / cs2;
}

// Eqs. 7–9 block by block; J_of is block diagonal (eq. 19).
Eigen::VectorXd to_sensor_frame(const CoordLayout& layout, const Eigen::VectorXd& x_mf,
                                const Pose6& x_ms, Eigen::MatrixXd* J_of,
                                Eigen::MatrixXd* J_os) {
  check_size(layout, x_mf, "x_mf");
  const SensorFrame frame(x_ms, has_point2d_block(layout));
  return transform_blocks(layout, x_mf, frame, J_of, J_os, point3d_to_sensor, point2d_to_sensor);
}

Eigen::VectorXd to_map_frame(const CoordLayout& layout, const Eigen::VectorXd& x_o,
                             const Pose6& x_ms, Eigen::MatrixXd* J_fo, Eigen::MatrixXd* J_fs) {
  check_size(layout, x_o, "x_o");
  // The inverse uses R directly, not eq. 34, so it is defined for any tilt.
  const SensorFrame frame(x_ms, /*need_2d=*/false);
  return transform_blocks(layout, x_o, frame, J_fo, J_fs, point3d_to_map, point2d_to_map);
}

}  // namespace mspace
