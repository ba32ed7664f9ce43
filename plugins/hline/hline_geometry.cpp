// hline_geometry.cpp — see hline_geometry.hpp.
#include "hline_geometry.hpp"

#include <Eigen/Dense>
#include <algorithm>
#include <cmath>
#include <limits>
#include <numbers>

namespace mspace::hline {
namespace {

const double kSqrt2 = std::numbers::sqrt2;

Mat3 skew(const Vec3& v) {
  Mat3 S;
  S << 0.0, -v.z(), v.y(),  //
      v.z(), 0.0, -v.x(),   //
      -v.y(), v.x(), 0.0;
  return S;
}

/// ∂(a/|a|)/∂a = (I − â âᵀ)/|a|.
Mat3 normalisation_jacobian(const Vec3& a) {
  const double norm = a.norm();
  const Vec3 unit = a / norm;
  return (Mat3::Identity() - unit * unit.transpose()) / norm;
}

/// E(θ, φ, ψ) of the sensor pose: δ(angles) → the angular velocity ω.
Mat3 rate_matrix(const Pose6& x_ms) { return euler_rate_matrix(x_ms.tail<3>()); }

/// ∂o/∂x_ms for a camera centre o that moves rigidly with the sensor at x_ms:
/// δo = δs + ω × (o − s).
Eigen::Matrix<double, 3, 6> move_with_sensor(const Vec3& o, const Pose6& x_ms) {
  Eigen::Matrix<double, 3, 6> J = turn_with_sensor(o - x_ms.head<3>(), x_ms);
  J.leftCols<3>().setIdentity();
  return J;
}

/// Angle offset of the plane normal c's horizontal line from α_ref, modulo π
/// (a line has no sense of direction), in (−π/2, π/2].
double line_angle_offset(const Vec3& c, double alpha_ref) {
  double d = wrap_angle(std::atan2(c.x(), -c.y()) - alpha_ref);
  if (d > 0.5 * std::numbers::pi) d -= std::numbers::pi;
  if (d <= -0.5 * std::numbers::pi) d += std::numbers::pi;
  return d;
}

/// g of the plane (0 for a horizontal plane, which holds every direction).
Vec3 direction_gradient(const Vec3& c) {
  const double h2 = c.x() * c.x() + c.y() * c.y();
  return h2 > 1e-12 ? Vec3(Vec3(-c.y(), c.x(), 0.0) / h2) : Vec3::Zero();
}

constexpr int kParams = 7;  ///< the six sensor pose coordinates, then α
using RowParams = Eigen::Matrix<double, 1, kParams>;

/// The line's frame: horizontal T (direction), N (normal), and P_t = I − TTᵀ.
struct LineFrame {
  Vec3 T, N;
  Mat3 Pt;
  explicit LineFrame(const Vec2& t)
      : T(horizontal(t)), N(horizontal(normal_of(t))), Pt(Mat3::Identity() - T * T.transpose()) {}
};

/// One plane as a row A x = b of a least-squares problem in two unknowns,
/// with weight w: (o, z) for fit_position, (s, ρ) for estimate_ray.
struct CrossSectionRow {
  Eigen::RowVector2d A = Eigen::RowVector2d::Zero();
  double b = 0.0;
  double w = 0.0;
};

/// Whether the plane holds a line of direction t (c̃ is defined) and counts.
bool usable(const PlaneObservation& p, double w, const LineFrame& f) { return w > 0.0 && (f.Pt * p.c).norm() > 1e-9; }

// P = pivot + o N + z Z, so c̃·(P − o_i) = 0 reads (c̃·N) o + (c̃·Z) z = c̃·(o_i − pivot):
// the residual b − A x is c̃·(P − o_i).
CrossSectionRow cross_section_row(const PlaneObservation& p, double w, const LineFrame& f, const Vec3& pivot) {
  const Vec3 ct = (f.Pt * p.c).normalized();
  CrossSectionRow row;
  row.A << ct.dot(f.N), ct.z();
  row.b = ct.dot(p.o - pivot);
  row.w = w;
  return row;
}

/// The derivatives of a row's A and b with respect to the parameters.
struct RowDerivatives {
  Eigen::Matrix<double, 2, kParams> dA;  ///< column j: ∂Aᵀ/∂param_j
  RowParams db;
};

// Residual r = c̃·(P − o), c̃ = P_t c/|P_t c|. The parameters move c
// (δc = ω × c) and o (δo = δs + ω × (o − s)) for the sensor pose, and
// T (δT = −N δα) and N (δN = T δα) for α, so δ(P_t c) = N (T·c) + T (N·c).
RowDerivatives row_derivatives(const PlaneObservation& p, const LineFrame& f, const Vec3& pivot, const Pose6& x_ms) {
  const Vec3 Z = Vec3::UnitZ();
  const Vec3 pc = f.Pt * p.c;
  const Vec3 ct = pc.normalized();
  const Mat3 Q = normalisation_jacobian(pc);
  Eigen::Matrix<double, 3, kParams> d_pc, d_o = Eigen::Matrix<double, 3, kParams>::Zero();
  d_pc.leftCols<6>() = f.Pt * turn_with_sensor(p.c, x_ms);
  d_pc.col(6) = f.N * f.T.dot(p.c) + f.T * f.N.dot(p.c);
  d_o.leftCols<6>() = move_with_sensor(p.o, x_ms);
  const Eigen::Matrix<double, 3, kParams> d_ct = Q * d_pc;
  RowDerivatives d;
  d.dA.row(0) = f.N.transpose() * d_ct;  // + c̃·δN, which is 0 (c̃ ⟂ T)
  d.dA.row(1) = Z.transpose() * d_ct;
  d.db = (p.o - pivot).transpose() * d_ct + ct.transpose() * d_o;
  return d;
}

/// The weighted least squares of rows: x = H⁻¹ Σ w Aᵀb, H = Σ w AᵀA.
/// std::nullopt with fewer than two rows or when H is (nearly) singular.
struct RowSolution {
  Vec2 x = Vec2::Zero();
  Mat2 H_inv = Mat2::Zero();
};
std::optional<RowSolution> solve_rows(const std::vector<CrossSectionRow>& rows) {
  if (rows.size() < 2) return std::nullopt;
  Mat2 H = Mat2::Zero();
  Vec2 g = Vec2::Zero();
  for (const CrossSectionRow& r : rows) {
    H += r.w * r.A.transpose() * r.A;
    g += r.w * r.A.transpose() * r.b;
  }
  const Eigen::SelfAdjointEigenSolver<Mat2> eig(H);
  if (!(eig.eigenvalues()[0] > 1e-12 * eig.eigenvalues()[1])) return std::nullopt;
  RowSolution s;
  s.H_inv = H.inverse();
  s.x = s.H_inv * g;
  return s;
}

/// Reduced χ² inflation: the formal covariance is kept unless the residuals
/// scatter more than it predicts.
double inflation(double chi2, int dof) { return dof > 0 ? std::max(1.0, chi2 / dof) : 1.0; }

}  // namespace

// ---------------------------------------------------------------- the line

LineGeometry line_geometry(const Vec6& x_f) {
  LineGeometry g;
  g.p1 = x_f.head<3>();
  g.p2 = x_f.tail<3>();
  const Vec2 d = (g.p2 - g.p1).head<2>();
  g.L = d.norm();
  g.t = d / g.L;
  g.n = normal_of(g.t);
  g.z = g.p1.z();
  return g;
}

Vec6 make_line(const Vec2& point, const Vec2& t, double z, double s1, double s2) {
  Vec6 x;
  x << point + s1 * t, z, point + s2 * t, z;
  return x;
}

Vec2 direction(double alpha) { return {std::cos(alpha), std::sin(alpha)}; }

double angle_of(const Vec2& t) { return std::atan2(t.y(), t.x()); }

Vec2 foot_on_line(const Vec6& x_f, const Vec2& point) {
  const LineGeometry g = line_geometry(x_f);
  const Vec2 p1 = g.p1.head<2>();
  return p1 + g.t.dot(point - p1) * g.t;
}

// ---------------------------------------------------------------- eqs. 17, 21

// Eq. 17 (row 1) and eq. 21 (rows 2, 3), with the rotation and the offset
// taken about the anchor a instead of the centre, as for the wall: row 2 is
// √2 times the normal move at a, i.e. the end points weighted by
// w1 = 1 − τ_a/L and w2 = τ_a/L, τ_a = t·(a − p1). With a at the centre,
// w1 = w2 = ½ and the rows are eq. 21 exactly. Keeping a fixed while
// unmeasured end points slide keeps the meaning of δx_p unchanged.
Eigen::MatrixXd hline_B(const Vec6& x_f, int dim, const Vec2& anchor) {
  if (dim != 1 && dim != 3) return Eigen::MatrixXd(0, 6);
  const LineGeometry g = line_geometry(x_f);
  const double w2 = g.t.dot(anchor - g.p1.head<2>()) / g.L, w1 = 1.0 - w2;
  Eigen::MatrixXd B = Eigen::MatrixXd::Zero(dim, 6);
  B.block<1, 2>(0, 0) = g.n.transpose() / (g.L * kSqrt2);
  B.block<1, 2>(0, 3) = -g.n.transpose() / (g.L * kSqrt2);
  if (dim == 3) {
    B.block<1, 2>(1, 0) = kSqrt2 * w1 * g.n.transpose();
    B.block<1, 2>(1, 3) = kSqrt2 * w2 * g.n.transpose();
    B(2, 2) = B(2, 5) = 1.0 / kSqrt2;
  }
  return B;
}

// The dual of eqs. 17/21: column 1 turns the line about the anchor,
// δp_k = −√2 (τ_k − τ_a) n δ1 (a turn of δα = √2 δ1); column 2 moves both
// end points along n by δ2/√2; column 3 raises both by δ3/√2 — the same
// number added to both heights, so z1 = z2 survives every perturbation
// (the horizontal constraint, T-RO §IV-C). B B̃ = I (eq. 12) since n ⟂ t.
Eigen::MatrixXd hline_B_dual(const Vec6& x_f, int dim, const Vec2& anchor) {
  if (dim != 1 && dim != 3) return Eigen::MatrixXd(6, 0);
  const LineGeometry g = line_geometry(x_f);
  const double tau_a = g.t.dot(anchor - g.p1.head<2>());
  Eigen::MatrixXd Bd = Eigen::MatrixXd::Zero(6, dim);
  Bd.block<2, 1>(0, 0) = kSqrt2 * tau_a * g.n;
  Bd.block<2, 1>(3, 0) = -kSqrt2 * (g.L - tau_a) * g.n;
  if (dim == 3) {
    Bd.block<2, 1>(0, 1) = g.n / kSqrt2;
    Bd.block<2, 1>(3, 1) = g.n / kSqrt2;
    Bd(2, 2) = Bd(5, 2) = 1.0 / kSqrt2;
  }
  return Bd;
}

// ---------------------------------------------------------------- eqs. 18–22

// Eq. 18 with the camera's optical axis along z: s = (v0, v1, v4),
// e = (v2, v3, v4); eq. 19: c = s×e/|s×e|. With u = s×e,
// ∂u/∂s_k = e_k × e and ∂u/∂e_k = s × e_k; v4 enters both.
std::optional<MeasuredLine> measured_line(const Eigen::VectorXd& v) {
  if (v.size() != kMeasurementSize || !v.allFinite() || !(v[4] > 0.0)) return std::nullopt;
  MeasuredLine m;
  m.s = Vec3(v[0], v[1], v[4]);
  m.e = Vec3(v[2], v[3], v[4]);
  const Vec3 u = m.s.cross(m.e);
  if (!(u.norm() > 1e-9 * m.s.norm() * m.e.norm())) return std::nullopt;
  m.c = u.normalized();
  const Vec3 ex = Vec3::UnitX(), ey = Vec3::UnitY(), ez = Vec3::UnitZ();
  Eigen::Matrix<double, 3, kMeasurementSize> du;
  du << ex.cross(m.e), ey.cross(m.e), m.s.cross(ex), m.s.cross(ey), ez.cross(m.e) + m.s.cross(ez);
  m.J_cv = normalisation_jacobian(u) * du;
  return m;
}

// Eq. 20: η = c·t̂, t̂ = d/|d|, d = ê − ŝ, so ∂η/∂ê = cᵀ(I − t̂t̂ᵀ)/|d| = −∂η/∂ŝ
// and ∂η/∂v = t̂ᵀ ∂c/∂v. Eq. 22: η2 = c·r̂, r̂ = m/|m|, m = ê + ŝ, the same
// with both end points entering with a plus sign.
void line_innovation(const Vec6& x_o, const MeasuredLine& m, int rows, Innovation& out) {
  const Vec3 s_hat = x_o.head<3>(), e_hat = x_o.tail<3>();
  out.eta.resize(rows);
  out.J_eta_o.resize(rows, 6);
  out.J_eta_v.resize(rows, kMeasurementSize);

  const Vec3 d = e_hat - s_hat;
  const Vec3 t_hat = d.normalized();
  const Eigen::RowVector3d dt = m.c.transpose() * normalisation_jacobian(d);
  out.eta[0] = m.c.dot(t_hat);
  out.J_eta_o.row(0) << -dt, dt;
  out.J_eta_v.row(0) = t_hat.transpose() * m.J_cv;
  if (rows < 2) return;

  const Vec3 mid = e_hat + s_hat;
  const Vec3 r_hat = mid.normalized();
  const Eigen::RowVector3d dr = m.c.transpose() * normalisation_jacobian(mid);
  out.eta[1] = m.c.dot(r_hat);
  out.J_eta_o.row(1) << dr, dr;
  out.J_eta_v.row(1) = r_hat.transpose() * m.J_cv;
}

// Closest points of o + μu and point + λ·dir: (w + μu − λ dir) ⟂ u and dir,
// w = o − point, gives μ(1 − b²) = b e − d and λ = e + μ b with b = u·dir,
// d = u·w, e = dir·w (unit u and dir).
std::optional<double> ray_to_line(const Vec3& o, const Vec3& u, const Vec3& point, const Vec3& dir) {
  const Vec3 unit = u.normalized();
  const Vec3 w = o - point;
  const double b = unit.dot(dir), d = unit.dot(w), e = dir.dot(w);
  const double denom = 1.0 - b * b;
  if (!(denom > 1e-9)) return std::nullopt;
  const double mu = (b * e - d) / denom;
  if (!(mu > 0.0)) return std::nullopt;
  return e + mu * b;
}

// ---------------------------------------------------------------- dense information

PlaneObservation plane_in_map(const MeasuredLine& m, const Eigen::MatrixXd& C_v, const Pose6& x_ms) {
  const Mat3 R = rotation(x_ms);
  const Eigen::Matrix<double, 3, kMeasurementSize> J = R * m.J_cv;
  PlaneObservation p;
  p.c = R * m.c;
  p.C_c = J * C_v * J.transpose();
  p.C_c = 0.5 * (p.C_c + p.C_c.transpose()).eval();
  p.o = x_ms.head<3>();
  return p;
}

// P = (o_xy + λ n, z) lies in the plane c̃·(P − o) = 0, c̃ = c − (c·t)t:
// λ c̃_xy·n + c̃_z (z − o_z) = 0; the whole line P + s t does, as c̃ ⟂ t.
std::optional<Vec2> point_in_plane(const PlaneObservation& p, const Vec2& t, double z) {
  const Vec3 T = horizontal(t);
  const Vec2 n = normal_of(t);
  const Vec3 ct = p.c - p.c.dot(T) * T;
  const double denom = ct.head<2>().dot(n);
  if (!(std::abs(denom) > 1e-9 * ct.norm())) return std::nullopt;
  const double lambda = -ct.z() * (z - p.o.z()) / denom;
  return Vec2(p.o.head<2>() + lambda * n);
}

// δ(ω × v) = −[v]× ω = −[v]× E δ(θ, φ, ψ).
Eigen::Matrix<double, 3, 6> turn_with_sensor(const Vec3& v, const Pose6& x_ms) {
  Eigen::Matrix<double, 3, 6> J = Eigen::Matrix<double, 3, 6>::Zero();
  J.rightCols<3>() = -skew(v) * rate_matrix(x_ms);
  return J;
}

// The plane with normal c holds the horizontal direction (−c_y, c_x), of
// angle α_i; dα_i = g·dc with g = (−c_y, c_x, 0)/(c_x² + c_y²), so
// σ²_αi = gᵀ C_c g and, for planes turning with the sensor, dα_i = gᵀ δ(ω × c).

std::vector<double> direction_weights(const std::vector<PlaneObservation>& planes) {
  std::vector<double> w;
  w.reserve(planes.size());
  for (const PlaneObservation& p : planes) {
    const Vec3 g = direction_gradient(p.c);
    w.push_back(g.isZero() ? 0.0 : 1.0 / std::max(g.dot(p.C_c * g), 1e-18));
  }
  return w;
}

DirectionFit fit_direction(const std::vector<PlaneObservation>& planes, const std::vector<double>& weights,
                           const Vec2& t_ref, const Pose6& x_ms) {
  const double alpha_ref = angle_of(t_ref);
  DirectionFit fit;
  std::vector<std::size_t> used;
  double sum_w = 0.0, sum_wd = 0.0;
  Eigen::Matrix<double, 1, 6> sum_wJ = Eigen::Matrix<double, 1, 6>::Zero();
  for (std::size_t i = 0; i < planes.size(); ++i) {
    const Vec3 g = direction_gradient(planes[i].c);
    if (!(weights[i] > 0.0) || g.isZero()) continue;
    used.push_back(i);
    sum_w += weights[i];
    sum_wd += weights[i] * line_angle_offset(planes[i].c, alpha_ref);
    sum_wJ += weights[i] * g.transpose() * turn_with_sensor(planes[i].c, x_ms);
  }
  if (used.empty()) {
    fit.alpha = alpha_ref;
    fit.variance = fit.spread = std::numeric_limits<double>::infinity();
    return fit;
  }
  const double mean = sum_wd / sum_w;
  double chi2 = 0.0;
  for (std::size_t i : used) {
    const double r = line_angle_offset(planes[i].c, alpha_ref) - mean;
    chi2 += weights[i] * r * r;
    fit.spread = std::max(fit.spread, std::abs(r));
  }
  fit.alpha = wrap_angle(alpha_ref + mean);
  fit.variance = inflation(chi2, static_cast<int>(used.size()) - 1) / sum_w;
  fit.J_pose = sum_wJ / sum_w;
  return fit;
}


// δr = δc·k with k = P_t Q (P − o), Q = ∂c̃/∂(P_t c): σ² = kᵀ C_c k.
std::vector<double> plane_weights(const std::vector<PlaneObservation>& planes, const Vec2& t, const Vec3& at) {
  const LineFrame f(t);
  std::vector<double> w;
  w.reserve(planes.size());
  for (const PlaneObservation& p : planes) {
    const Vec3 pc = f.Pt * p.c;
    if (!(pc.norm() > 1e-9)) {
      w.push_back(0.0);
      continue;
    }
    const Vec3 k = f.Pt * normalisation_jacobian(pc) * (at - p.o);
    w.push_back(1.0 / std::max(k.dot(p.C_c * k), 1e-18));
  }
  return w;
}

// Normal equations H x = g, H = Σ w AᵀA, g = Σ w Aᵀb. Differentiating with
// the weights fixed, H δx = Σ w [δAᵀ (b − A x) + Aᵀ (δb − δA x)].
std::optional<PositionFit> fit_position(const std::vector<PlaneObservation>& planes, const std::vector<double>& weights,
                                        const Vec2& t, const Vec2& pivot, const Pose6& x_ms) {
  const LineFrame f(t);
  std::vector<CrossSectionRow> rows;
  std::vector<RowDerivatives> derivatives;
  for (std::size_t i = 0; i < planes.size(); ++i) {
    if (!usable(planes[i], weights[i], f)) continue;
    rows.push_back(cross_section_row(planes[i], weights[i], f, horizontal(pivot)));
    derivatives.push_back(row_derivatives(planes[i], f, horizontal(pivot), x_ms));
  }
  const std::optional<RowSolution> ls = solve_rows(rows);
  if (!ls) return std::nullopt;

  PositionFit fit;
  fit.x = ls->x;
  Eigen::Matrix<double, 2, kParams> rhs = Eigen::Matrix<double, 2, kParams>::Zero();
  for (std::size_t k = 0; k < rows.size(); ++k) {
    const CrossSectionRow& r = rows[k];
    const RowDerivatives& d = derivatives[k];
    const double residual = r.b - r.A.dot(fit.x);
    fit.chi2 += r.w * residual * residual;
    const RowParams dAx = fit.x.transpose() * d.dA;
    rhs += r.w * (d.dA * residual + r.A.transpose() * (d.db - dAx));
  }
  fit.cov = inflation(fit.chi2, static_cast<int>(rows.size()) - 2) * ls->H_inv;
  const Eigen::Matrix<double, 2, kParams> J = ls->H_inv * rhs;
  fit.J_pose = J.leftCols<6>();
  fit.J_alpha = J.col(6);
  return fit;
}

// ---------------------------------------------------------------- consistency of the planes

/// The row of plane p in the inverse-height form (estimate_ray): ρ c̃·(P − o)
/// = A x − b with A = (c̃·n, c̃·(q − o)), b = −c̃_z; weight w/ρ², its noise
/// being ρ times that of c̃·(P − o).
CrossSectionRow ray_row(const PlaneObservation& p, double w, const LineFrame& f, const Vec3& q, double rho) {
  const Vec3 ct = (f.Pt * p.c).normalized();
  CrossSectionRow row;
  row.A << ct.dot(f.N), ct.dot(q - p.o);
  row.b = -ct.z();
  row.w = w / (rho * rho);
  return row;
}

// The deleted residual of row k: with the other rows alone x would be x_(k),
// and e_(k) = e/(1 − h), Var e_(k) = (1/w)/(1 − h), so its χ² is
// w e²/(1 − h) (leave-one-out, with no refit needed).
std::optional<RayEstimate> estimate_ray(const std::vector<PlaneObservation>& planes, const std::vector<double>& weights,
                                        const Vec2& t, const Vec3& q, double rho,
                                        const std::optional<InverseHeightPrior>& prior) {
  const LineFrame f(t);
  std::vector<CrossSectionRow> rows;
  std::vector<std::size_t> index;  // the plane of each row
  for (std::size_t i = 0; i < planes.size(); ++i) {
    if (!usable(planes[i], weights[i], f)) continue;
    rows.push_back(ray_row(planes[i], weights[i], f, q, rho));
    index.push_back(i);
  }
  if (prior) rows.push_back({Eigen::RowVector2d(0.0, 1.0), prior->rho, 1.0 / (prior->sigma * prior->sigma)});
  const std::optional<RowSolution> ls = solve_rows(rows);
  if (!ls) return std::nullopt;

  RayEstimate e;
  e.x = ls->x;
  e.cov = ls->H_inv;
  e.rows = static_cast<int>(rows.size());
  e.deleted_chi2.assign(planes.size(), 0.0);
  for (std::size_t k = 0; k < rows.size(); ++k) {
    const CrossSectionRow& r = rows[k];
    const double residual = r.b - r.A.dot(e.x);
    e.chi2 += r.w * residual * residual;
    if (k >= index.size()) continue;  // the prior
    const double leverage = r.w * r.A.dot(e.cov * r.A.transpose());
    e.deleted_chi2[index[k]] = leverage < 1.0 - 1e-9 ? r.w * residual * residual / (1.0 - leverage)
                                                     : std::numeric_limits<double>::infinity();
  }
  return e;
}

Vec3 ray_point(const RayEstimate& estimate, const Vec2& t, const Vec3& q) {
  const LineFrame f(t);
  return q + (estimate.x[0] * f.N + Vec3::UnitZ()) / estimate.x[1];
}

double plane_chi2(const PlaneObservation& plane, double w, const Vec2& t, const Vec3& q, double rho,
                  const RayEstimate& estimate) {
  const LineFrame f(t);
  if (!usable(plane, w, f)) return std::numeric_limits<double>::infinity();
  const CrossSectionRow r = ray_row(plane, w, f, q, rho);
  const double residual = r.b - r.A.dot(estimate.x);
  return residual * residual / (1.0 / r.w + r.A.dot(estimate.cov * r.A.transpose()));
}

// Prefix sums of the normal equations over the planes sorted by camera
// offset give both sides of every cut in one pass.
SplitTest split_test(const std::vector<PlaneObservation>& planes, const std::vector<double>& weights, const Vec2& t,
                     const Vec3& q, double rho, const InverseHeightPrior& prior) {
  const LineFrame f(t);
  std::vector<std::size_t> order;
  for (std::size_t i = 0; i < planes.size(); ++i)
    if (usable(planes[i], weights[i], f)) order.push_back(i);
  std::sort(order.begin(), order.end(),
            [&](std::size_t a, std::size_t b) { return f.N.dot(planes[a].o) < f.N.dot(planes[b].o); });

  const std::size_t m = order.size();
  std::vector<Mat2> H(m + 1, Mat2::Zero());  // H[k], g[k]: sums over the first k planes
  std::vector<Vec2> g(m + 1, Vec2::Zero());
  for (std::size_t k = 0; k < m; ++k) {
    const CrossSectionRow r = ray_row(planes[order[k]], weights[order[k]], f, q, rho);
    H[k + 1] = H[k] + r.w * r.A.transpose() * r.A;
    g[k + 1] = g[k] + r.w * r.A.transpose() * r.b;
  }
  const double w_prior = 1.0 / (prior.sigma * prior.sigma);
  const Mat2 H_prior = Eigen::Vector2d(0.0, w_prior).asDiagonal();
  const Vec2 g_prior(0.0, w_prior * prior.rho);

  SplitTest test;
  constexpr std::size_t kMinSide = 2;
  for (std::size_t k = kMinSide; m >= 2 * kMinSide && k + kMinSide <= m; ++k) {
    const Mat2 H1 = H[k] + H_prior, H2 = H[m] - H[k] + H_prior;
    if (!(H1.determinant() > 0.0 && H2.determinant() > 0.0)) continue;
    const Mat2 C1 = H1.inverse(), C2 = H2.inverse();
    const Vec2 dx = C1 * (g[k] + g_prior) - C2 * (g[m] - g[k] + g_prior);
    const double chi2 = dx.dot((C1 + C2).ldlt().solve(dx));
    if (!(chi2 > test.chi2)) continue;
    test.chi2 = chi2;
    const auto cut = order.begin() + static_cast<std::ptrdiff_t>(k);
    if (k <= m - k)
      test.smaller.assign(order.begin(), cut);
    else
      test.smaller.assign(cut, order.end());
  }
  return test;
}

RaySpread ray_spread(const std::vector<PlaneObservation>& planes, const Vec2& t, const Vec3& P) {
  RaySpread spread;
  if (planes.empty()) return spread;
  const Vec3 N = horizontal(normal_of(t));
  std::vector<double> angles;
  angles.reserve(planes.size());
  for (const PlaneObservation& p : planes) angles.push_back(std::atan2(N.dot(P - p.o), P.z() - p.o.z()));
  std::sort(angles.begin(), angles.end());
  spread.span = angles.back() - angles.front();
  for (std::size_t i = 1; i < angles.size(); ++i)
    spread.largest_gap = std::max(spread.largest_gap, angles[i] - angles[i - 1]);
  return spread;
}

}  // namespace mspace::hline
