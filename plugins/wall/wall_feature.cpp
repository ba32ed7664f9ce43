// wall_feature.cpp — see wall_feature.hpp.
#include "wall_feature.hpp"

#include <Eigen/Dense>
#include <algorithm>
#include <cmath>
#include <iterator>
#include <limits>
#include <numbers>
#include <random>
#include <stdexcept>

#include "mspace/feature_log.hpp"
#include "mspace/measurements/line_segment2d.hpp"
#include "mspace/pose.hpp"
#include "mspace/saved_state.hpp"
#include "mspace/transform.hpp"

namespace mspace::wall {
namespace {

namespace ls = line_segment;
const double kSqrt2 = std::numbers::sqrt2;
constexpr int kSaveVersion = 1;
/// v, C_v, flags, view, real start (seen, x, y), real end (seen, x, y), point count.
constexpr int kObservationRecord = 4 + 16 + 1 + saved::kViewSize + 6 + 1;

const CoordLayout& wall_layout() {
  static const CoordLayout layout{BlockKind::Point2D, BlockKind::Point2D};
  return layout;
}

/// End points, length L, direction t and normal γ = (t_y, −t_x) (eq. 13).
struct Geometry {
  Vec2 p1, p2, t, gamma;
  double L = 0.0;
};

Geometry geometry(const Eigen::Vector4d& x) {
  Geometry g;
  g.p1 = x.head<2>();
  g.p2 = x.tail<2>();
  g.L = (g.p2 - g.p1).norm();
  g.t = (g.p2 - g.p1) / g.L;
  g.gamma = Vec2(g.t.y(), -g.t.x());
  return g;
}

/// Turns a vector by +90°.
Vec2 perp(const Vec2& v) { return {-v.y(), v.x()}; }

bool is_line_measurement(const Measurement& m) {
  return m.kind == ls::kKind && m.v.size() == ls::kSize && m.C_v.rows() == ls::kSize && m.C_v.cols() == ls::kSize &&
         m.v.allFinite() && m.C_v.allFinite() && m.v[ls::kRho] > 0.0;
}

bool end_is_real(std::uint32_t flags, int end) { return (flags & (end == kStart ? ls::kRealA : ls::kRealB)) != 0; }

/// Planar sensor → map for points in the sensor's x–y plane (inverse of eq. 34).
Eigen::Matrix2Xd sensor_to_map(const Pose6& x_ms, const Eigen::Matrix2Xd& points) {
  const Eigen::Matrix2d R = rotation(x_ms).topLeftCorner<2, 2>();
  return (R * points).colwise() + x_ms.head<2>();
}

/// Measured end point (ρu + s t_m) of the segment, sensor frame.
Vec2 measured_end(const Eigen::VectorXd& v, int end) {
  const double a = v[ls::kAlpha];
  const Vec2 u(std::cos(a), std::sin(a)), t(std::sin(a), -std::cos(a));
  return v[ls::kRho] * u + v[end == kStart ? ls::kSa : ls::kSb] * t;
}

Vec2 map_point(const Pose6& x_ms, const Vec2& p) { return sensor_to_map(x_ms, p).col(0); }

Eigen::Matrix2d symmetric(const Eigen::Matrix2d& m) { return 0.5 * (m + m.transpose()); }

}  // namespace

// ---------------------------------------------------------------- geometry

PredictedLine predict_line(const Eigen::Vector4d& x_o) {
  const Vec2 p1 = x_o.head<2>(), p2 = x_o.tail<2>();
  const Vec2 d = p2 - p1;
  const double L = d.norm();
  const Vec2 t = d / L, u = perp(t);  // u: from the sensor towards the wall when ρ̂ > 0
  const double rho = u.dot(p1);
  const double s1 = t.dot(p1), s2 = t.dot(p2);
  PredictedLine out;
  out.h << rho, std::atan2(u.y(), u.x()), s1, s2;
  // dφ = u·(dp2 − dp1)/L; dρ̂ = u·dp1 − ŝ1 dφ; dŝ_k = t·dp_k + ρ̂ dφ.
  const Eigen::RowVector2d uL = u.transpose() / L;
  out.J.row(0) << u.transpose() + s1 * uL, -s1 * uL;
  out.J.row(1) << -uL, uL;
  out.J.row(2) << t.transpose() - rho * uL, rho * uL;
  out.J.row(3) << -rho * uL, t.transpose() + rho * uL;
  return out;
}

// Eq. 14 (first two rows) and Table II (a tangent row per end point), with
// the rotation taken about the anchor a rather than the centre: row 1 is the
// normal displacement at a (times √2), i.e. the end points weighted by
// w1 = (τ2 − τa)/L and w2 = (τa − τ1)/L. With a at the centre (w1 = w2 = ½)
// this is eq. 14 exactly. Keeping a fixed while unmeasured ends slide keeps
// the meaning of δx_p (and so of its covariance) unchanged — the same reason
// eq. 33 scales the angle column by L/L_s.
Eigen::MatrixXd wall_B(const Eigen::Vector4d& x_f, const std::vector<int>& ends, const Vec2& anchor) {
  const Geometry g = geometry(x_f);
  const double w2 = g.t.dot(anchor - g.p1) / g.L, w1 = 1.0 - w2;
  Eigen::MatrixXd B = Eigen::MatrixXd::Zero(2 + static_cast<Eigen::Index>(ends.size()), 4);
  B.row(0) << g.gamma.transpose() / (g.L * kSqrt2), -g.gamma.transpose() / (g.L * kSqrt2);
  B.row(1) << kSqrt2 * w1 * g.gamma.transpose(), kSqrt2 * w2 * g.gamma.transpose();
  for (std::size_t i = 0; i < ends.size(); ++i) B.block<1, 2>(2 + static_cast<Eigen::Index>(i), 2 * ends[i]) = g.t;
  return B;
}

// Eq. 15 with the rotation about the anchor, dp_k = −√2 (τ_k − τ_a) γ δ1,
// and the tangent columns; B B̃ = I (eq. 12) because γ ⊥ t.
Eigen::MatrixXd wall_B_dual(const Eigen::Vector4d& x_f, const std::vector<int>& ends, const Vec2& anchor) {
  const Geometry g = geometry(x_f);
  const double tau_a = g.t.dot(anchor - g.p1);
  Eigen::MatrixXd Bd = Eigen::MatrixXd::Zero(4, 2 + static_cast<Eigen::Index>(ends.size()));
  Bd.col(0) << kSqrt2 * tau_a * g.gamma, -kSqrt2 * (g.L - tau_a) * g.gamma;
  Bd.col(1) << g.gamma / kSqrt2, g.gamma / kSqrt2;
  for (std::size_t i = 0; i < ends.size(); ++i) Bd.block<2, 1>(2 * ends[i], 2 + static_cast<Eigen::Index>(i)) = g.t;
  return Bd;
}

Vec2 wall_centre(const Eigen::Vector4d& x_f) { return 0.5 * (x_f.head<2>() + x_f.tail<2>()); }

// Eq. 33 with one change: the corner's columns move the whole wall (both
// ends), not only the shared end, so the wall turns about the corner and the
// angle column (L/L_s) γ at the free end always means a turn of 1/L_s. With
// the paper's columns a move of the corner would pivot the wall about the free
// end, by an angle that changes whenever that end slides — the same reason
// the unshared wall's rotation is taken about a fixed anchor (see wall_B).
Eigen::MatrixXd shared_wall_B_dual(const Eigen::Vector4d& x_f, const std::vector<int>& ends,
                                   const std::array<bool, 2>& shared, double L_s) {
  const Geometry g = geometry(x_f);
  const bool one_shared = shared[kStart] != shared[kEnd];
  const int free = shared[kStart] ? kEnd : kStart;
  const bool tangent = one_shared && std::find(ends.begin(), ends.end(), free) != ends.end();
  Eigen::MatrixXd Bd = Eigen::MatrixXd::Zero(4, (one_shared ? 3 : 4) + (tangent ? 1 : 0));
  Eigen::Index col = 0;
  if (one_shared) {
    Bd.block<2, 1>(2 * free, col++) = (g.L / L_s) * g.gamma;  // the angle about the corner
    if (tangent) Bd.block<2, 1>(2 * free, col++) = g.t;
  }
  for (int e : {kStart, kEnd}) {
    if (!shared[e]) continue;
    Bd.block<2, 2>(2 * e, col).setIdentity();
    if (one_shared) Bd.block<2, 2>(2 * free, col).setIdentity();  // the wall moves with its corner
    col += 2;
  }
  return Bd;
}

// B B̃ = I: the angle row is the free end's normal move relative to the
// corner (times L_s/L), the tangent row its tangential move relative to the
// corner, the corner rows the shared end itself.
Eigen::MatrixXd shared_wall_B(const Eigen::Vector4d& x_f, const std::vector<int>& ends,
                              const std::array<bool, 2>& shared, double L_s) {
  const Geometry g = geometry(x_f);
  const bool one_shared = shared[kStart] != shared[kEnd];
  const int free = shared[kStart] ? kEnd : kStart, corner = 1 - free;
  const bool tangent = one_shared && std::find(ends.begin(), ends.end(), free) != ends.end();
  Eigen::MatrixXd B = Eigen::MatrixXd::Zero((one_shared ? 3 : 4) + (tangent ? 1 : 0), 4);
  Eigen::Index row = 0;
  if (one_shared) {
    B.block<1, 2>(row, 2 * free) = (L_s / g.L) * g.gamma.transpose();
    B.block<1, 2>(row++, 2 * corner) = -(L_s / g.L) * g.gamma.transpose();
    if (tangent) {
      B.block<1, 2>(row, 2 * free) = g.t.transpose();
      B.block<1, 2>(row++, 2 * corner) = -g.t.transpose();
    }
  }
  for (int e : {kStart, kEnd}) {
    if (!shared[e]) continue;
    B.block<2, 2>(row, 2 * e).setIdentity();
    row += 2;
  }
  return B;
}

// The corner c solves n_a·(c − p1) = 0 and n_b·(c − q1) = 0 with the
// (unnormalised) normals n = perp(p2 − p1). Differentiating,
//   n_a·dc = n_a·dp1 + (dp2 − dp1)·perp(c − p1),
// and the same for b; N = (n_a; n_b) is inverted once.
std::optional<LineIntersection> intersect_lines(const Eigen::Vector4d& a, const Eigen::Vector4d& b,
                                                double min_angle) {
  const Vec2 p1 = a.head<2>(), q1 = b.head<2>();
  const Vec2 da = a.tail<2>() - p1, db = b.tail<2>() - q1;
  const double cross = da.x() * db.y() - da.y() * db.x();
  if (!(std::abs(cross) >= std::sin(min_angle) * da.norm() * db.norm())) return std::nullopt;
  const Vec2 n_a = perp(da), n_b = perp(db);
  Eigen::Matrix2d N;
  N << n_a.transpose(), n_b.transpose();
  const Eigen::Matrix2d N_inv = N.inverse();
  LineIntersection out;
  out.point = N_inv * Vec2(n_a.dot(p1), n_b.dot(q1));
  const Vec2 m_a = perp(out.point - p1), m_b = perp(out.point - q1);
  Eigen::Matrix<double, 2, 4> rows_a = Eigen::Matrix<double, 2, 4>::Zero(), rows_b = rows_a;
  rows_a.row(0) << (n_a - m_a).transpose(), m_a.transpose();
  rows_b.row(1) << (n_b - m_b).transpose(), m_b.transpose();
  out.J_a = N_inv * rows_a;
  out.J_b = N_inv * rows_b;
  return out;
}

Eigen::MatrixXd wall_B(const Eigen::Vector4d& x_f, const std::vector<int>& ends) {
  return wall_B(x_f, ends, wall_centre(x_f));
}
Eigen::MatrixXd wall_B_dual(const Eigen::Vector4d& x_f, const std::vector<int>& ends) {
  return wall_B_dual(x_f, ends, wall_centre(x_f));
}

// The measured line in the map: u_m = (cos β, sin β), β = α + θ_s, offset
// c = u_m·s + ρ. An end point p_k's normal displacement (along γ = −u_m) is
//   δn_k = −δρ − u_m·δs − w_k (δα + δθ),   w_k = u_m'·(s − p_k), u_m' = du_m/dβ,
// and the M-space of eq. 14 is δ1 = (δn1 − δn2)/(L√2), δ2 = (δn1 + δn2)/√2.
void line_placement_jacobians(const Eigen::Vector4d& x_f, double alpha, const Pose6& x_ms, Eigen::Matrix2d& J_v,
                              Eigen::Matrix<double, 2, 6>& J_s) {
  const Geometry g = geometry(x_f);
  const double beta = alpha + x_ms[kTheta];
  const Vec2 u(std::cos(beta), std::sin(beta)), du(-std::sin(beta), std::cos(beta));
  const Vec2 s = x_ms.head<2>();
  const double w1 = du.dot(s - g.p1), w2 = du.dot(s - g.p2);
  const double rot = -(w1 - w2) / (g.L * kSqrt2);  // ∂δ1/∂(α + θ)
  const double off = -(w1 + w2) / kSqrt2;          // ∂δ2/∂(α + θ)
  J_v << 0.0, rot, -kSqrt2, off;
  J_s.setZero();
  J_s(0, kTheta) = rot;
  J_s.block<1, 2>(1, kX) = -kSqrt2 * u.transpose();
  J_s(1, kTheta) = off;
}

Eigen::Vector4d place_on_line(double rho, double alpha, const Pose6& x_ms, const Vec2& start_near,
                              const Vec2& end_near) {
  const double beta = alpha + x_ms[kTheta];
  const Vec2 u(std::cos(beta), std::sin(beta)), t(std::sin(beta), -std::cos(beta));
  const Vec2 foot = x_ms.head<2>() + rho * u;
  Eigen::Vector4d x;
  x << foot + t.dot(start_near - foot) * t, foot + t.dot(end_near - foot) * t;
  return x;
}

// ---------------------------------------------------------------- WallFeature

WallFeature::WallFeature(const WallConfig& config, const Eigen::Vector4d& x_f, int mspace_dim, std::vector<int> ends)
    : config_(config), ends_(std::move(ends)) {
  if (mspace_dim != 0 && mspace_dim != 2 + static_cast<int>(ends_.size()))
    throw std::invalid_argument("wall: M-space dimension must be 0 or 2 + the number of measured end points");
  if (!((x_f.tail<2>() - x_f.head<2>()).norm() > 0.0)) throw std::invalid_argument("wall: zero length");
  x_ = x_f;
  mdim_ = mspace_dim;
  anchor_ = wall_centre(x_f);
}

void WallFeature::set_anchor(const Vec2& anchor) { anchor_ = anchor; }

const CoordLayout& WallFeature::layout() const { return wall_layout(); }

Eigen::MatrixXd WallFeature::B() const {
  if (mdim_ == 0) return Eigen::MatrixXd(0, 4);
  return any_shared() ? shared_wall_B(x_, ends_, shared_, L_s_) : wall_B(x_, ends_, anchor_);
}

Eigen::MatrixXd WallFeature::B_dual() const {
  if (mdim_ == 0) return Eigen::MatrixXd(4, 0);
  return any_shared() ? shared_wall_B_dual(x_, ends_, shared_, L_s_) : wall_B_dual(x_, ends_, anchor_);
}

// Eq. 24, then the anchor follows the line: rotation about it leaves it in
// place, the normal move carries it along (its projection on the new line).
void WallFeature::apply_perturbation(const Eigen::VectorXd& dx_p) {
  Feature::apply_perturbation(dx_p);
  const Geometry g = geometry(x_);
  anchor_ = g.p1 + g.t.dot(anchor_ - g.p1) * g.t;
}

bool WallFeature::in_mspace(int end) const { return std::find(ends_.begin(), ends_.end(), end) != ends_.end(); }

// Eq. 16 with h = (ρ̂, α̂[, ŝ_k]) of the wall in the sensor frame: η = h − v.
bool WallFeature::innovation(const Eigen::VectorXd& x_o, const Measurement& m, Innovation& out) const {
  if (!is_line_measurement(m) || x_o.size() != 4) return false;
  if (!((x_o.tail<2>() - x_o.head<2>()).norm() > 1e-9)) return false;
  const PredictedLine p = predict_line(x_o);
  if (p.h[0] <= 1e-6) return false;  // seen from behind
  if (m.v[ls::kSb] < p.h[2] - config_.match_margin || m.v[ls::kSa] > p.h[3] + config_.match_margin) return false;

  std::vector<int> rows = {0, 1};  // index into h; the same index into v
  if (mdim_ != 0)
    for (int e : {kStart, kEnd})
      if (fixed_end(e) && end_is_real(m.flags, e)) rows.push_back(2 + e);
  const auto n = static_cast<Eigen::Index>(rows.size());
  out.eta.resize(n);
  out.J_eta_o.resize(n, 4);
  out.J_eta_v = Eigen::MatrixXd::Zero(n, ls::kSize);
  for (Eigen::Index i = 0; i < n; ++i) {
    const int r = rows[static_cast<std::size_t>(i)];
    out.eta[i] = p.h[r] - m.v[r];
    out.J_eta_o.row(i) = p.J.row(r);
    out.J_eta_v(i, r) = -1.0;
  }
  out.eta[1] = wrap_angle(out.eta[1]);
  return true;
}

Eigen::MatrixXd WallFeature::gating_covariance() const {
  if (mdim_ != 0) return {};
  return gating_cov_;
}

void WallFeature::add_dense_information(const Measurement& m, const SensorView& view) {
  if (!is_line_measurement(m))
    throw std::invalid_argument("wall: add_dense_information got a measurement of kind '" + m.kind +
                                "' (expected a valid '" + ls::kKind + "')");
  WallObservation obs;
  obs.points = m.dense.rows() == 2 ? sensor_to_map(view.x_ms, m.dense) : Eigen::Matrix2Xd(2, 0);
  obs.v = m.v;
  obs.C_v = m.C_v;
  obs.flags = m.flags;
  obs.view = view;
  for (int e : {kStart, kEnd})
    if (end_is_real(m.flags, e)) obs.real_end[e] = map_point(view.x_ms, measured_end(m.v, e));
  observations_.push_back(std::move(obs));
  prune(view.path_distance);
  if (mdim_ == 0)
    follow_latest();
  else
    slide_ends();
}

void WallFeature::prune(double path_distance) {
  while (observations_.size() > 1 &&
         (path_distance - observations_.front().view.path_distance > config_.max_path_distance ||
          static_cast<int>(observations_.size()) > config_.max_observations))
    observations_.pop_front();
}

void WallFeature::follow_latest() {
  const WallObservation& latest = observations_.back();
  // Ends: the extremes of everything observed, projected onto the new line.
  const Vec2 a = map_point(latest.view.x_ms, measured_end(latest.v, kStart));
  const Vec2 b = map_point(latest.view.x_ms, measured_end(latest.v, kEnd));
  const Vec2 t = (b - a).normalized();
  double lo = 0.0, hi = (b - a).norm();
  for (const WallObservation& o : observations_)
    for (Eigen::Index i = 0; i < o.points.cols(); ++i) {
      const double s = t.dot(o.points.col(i) - a);
      lo = std::min(lo, s);
      hi = std::max(hi, s);
    }
  x_ = place_on_line(latest.v[ls::kRho], latest.v[ls::kAlpha], latest.view.x_ms, a + lo * t, a + hi * t);
  // Gating covariance: δx_f = B̃ (J_v δv + J_s δx_ms) for the line dimensions.
  Eigen::Matrix2d J_v;
  Eigen::Matrix<double, 2, 6> J_s;
  line_placement_jacobians(x_, latest.v[ls::kAlpha], latest.view.x_ms, J_v, J_s);
  const Eigen::Matrix2d C_p = symmetric(J_v * latest.C_v.topLeftCorner<2, 2>() * J_v.transpose() +
                                        J_s * latest.view.C_ms * J_s.transpose());
  const Eigen::MatrixXd Bd = wall_B_dual(x_, {});
  gating_cov_ = Bd * C_p * Bd.transpose();
}

// Sliding (ICRA §IV "Add information"): ends outside the M-space move
// outwards along t to the observed extent; the line itself is not touched.
void WallFeature::slide_ends() {
  const Geometry g = geometry(x_);
  double lo = 0.0, hi = g.L;
  for (const WallObservation& o : observations_)
    for (Eigen::Index i = 0; i < o.points.cols(); ++i) {
      const double s = g.t.dot(o.points.col(i) - g.p1);
      lo = std::min(lo, s);
      hi = std::max(hi, s);
    }
  if (!fixed_end(kStart)) x_.head<2>() = g.p1 + lo * g.t;
  if (!fixed_end(kEnd)) x_.tail<2>() = g.p1 + hi * g.t;
}

Eigen::MatrixXd WallFeature::symmetry_directions() const {
  const Geometry g = geometry(x_);
  Eigen::MatrixXd dirs = Eigen::MatrixXd::Zero(4, 0);
  for (int e : {kStart, kEnd}) {
    if (mdim_ != 0 && fixed_end(e)) continue;
    dirs.conservativeResize(4, dirs.cols() + 1);
    dirs.col(dirs.cols() - 1).setZero();
    dirs.col(dirs.cols() - 1).segment<2>(2 * e) = g.t;
  }
  return dirs;
}

// extra = (measured ends…, start shared, end shared, L_s, anchor x, anchor y);
// the dense information as arrays (see the header).
SavedFeature WallFeature::save() const {
  const auto n = static_cast<Eigen::Index>(ends_.size());
  SavedFeature s{x_, mdim_, Eigen::VectorXd(n + 5), {}, kSaveVersion};
  for (Eigen::Index i = 0; i < n; ++i) s.extra[i] = ends_[static_cast<std::size_t>(i)];
  s.extra.tail<5>() << (shared_[kStart] ? 1.0 : 0.0), (shared_[kEnd] ? 1.0 : 0.0), L_s_, anchor_;
  if (!observations_.empty()) {
    Eigen::MatrixXd records(kObservationRecord, static_cast<Eigen::Index>(observations_.size()));
    Eigen::Index total = 0;
    for (const WallObservation& o : observations_) total += o.points.cols();
    Eigen::MatrixXd points(2, total);
    Eigen::Index at = 0;
    for (Eigen::Index i = 0; i < records.cols(); ++i) {
      const WallObservation& o = observations_[static_cast<std::size_t>(i)];
      auto col = records.col(i);
      col.head<4>() = o.v;
      saved::put_matrix(col, 4, o.C_v);
      col[20] = o.flags;
      saved::put_view(col, 21, o.view);
      for (int e : {kStart, kEnd}) {
        const int base = 21 + saved::kViewSize + 3 * e;
        col[base] = o.real_end[e] ? 1.0 : 0.0;
        col.segment<2>(base + 1) = o.real_end[e] ? *o.real_end[e] : Vec2::Zero();
      }
      col[kObservationRecord - 1] = static_cast<double>(o.points.cols());
      points.middleCols(at, o.points.cols()) = o.points;
      at += o.points.cols();
    }
    s.put("observations", records);
    s.put("points", points);
  }
  if (mdim_ == 0) s.put("gating_covariance", gating_cov_);
  return s;
}

void WallFeature::set_dense(std::deque<WallObservation> observations, const Eigen::Matrix4d& gating_cov) {
  observations_ = std::move(observations);
  gating_cov_ = gating_cov;
}

int WallFeature::own_dims() const {
  const int n_shared = (shared_[kStart] ? 1 : 0) + (shared_[kEnd] ? 1 : 0);
  const int line_dims = n_shared == 0 ? 2 : n_shared == 1 ? 1 : 0;  // rotation + offset, the angle, none
  return line_dims + static_cast<int>(ends_.size());
}

void WallFeature::set_shared(const std::array<bool, 2>& shared, double L_s) {
  shared_ = shared;
  L_s_ = L_s;
  std::erase_if(ends_, [&](int e) { return shared_[e]; });
  if (mdim_ != 0) mdim_ = own_dims() + 2 * ((shared_[kStart] ? 1 : 0) + (shared_[kEnd] ? 1 : 0));
}

bool WallFeature::can_share(int block) const { return mdim_ >= 2 && (block == kStart || block == kEnd) && !shared_[block]; }

// T-RO §VI: the corner is where the two lines cross (refused when they cross
// at less than min_corner_angle: nearly parallel lines have no stable corner).
std::optional<JoinProposal> WallFeature::propose_join(int block, const Feature& other, int other_block) const {
  if (!can_share(block) || !(other.layout() == wall_layout()) || other_block < 0 || other_block > 1) return std::nullopt;
  const std::optional<LineIntersection> c = intersect_lines(x_, other.coords(), config_.min_corner_angle);
  if (!c) return std::nullopt;
  return JoinProposal{c->point, c->J_a, c->J_b};
}

// The end moves onto the corner; the new own dimensions are the new B's own
// rows applied to the old B̃ (a linear function of the old perturbations).
Eigen::MatrixXd WallFeature::share_block(int block, const Eigen::VectorXd& value) {
  if (!can_share(block) || value.size() != 2) throw std::logic_error("wall: share_block on a block that cannot be shared");
  const Eigen::MatrixXd old_Bd = B_dual();
  x_.segment<2>(2 * block) = value;
  std::array<bool, 2> shared = shared_;
  shared[block] = true;
  set_shared(shared, any_shared() ? L_s_ : geometry(x_).L);
  return B().topRows(own_dims()) * old_Bd;
}

// A copy of this wall mapped a second time (e.g. beyond an end the first
// pass had not seen, or by a returning robot) and merged into it: its
// observations join this wall's dense information in the order they were
// made, so that the ends it saw are this wall's extent and its real-end
// sightings count towards this wall's end extensions (ICRA §IV, "Add
// information"). The line is not touched; the ends outside the M-space slide.
void WallFeature::absorb(const Feature& duplicate) {
  const auto* copy = dynamic_cast<const WallFeature*>(&duplicate);
  if (copy == nullptr || copy == this || copy->observations_.empty()) return;
  std::deque<WallObservation> merged;
  std::merge(observations_.begin(), observations_.end(), copy->observations_.begin(), copy->observations_.end(),
             std::back_inserter(merged), [](const WallObservation& a, const WallObservation& b) {
               return a.view.path_distance < b.view.path_distance;
             });
  observations_ = std::move(merged);
  prune(observations_.back().view.path_distance);
  if (mdim_ == 0)
    follow_latest();
  else
    slide_ends();
}

std::optional<Extension> WallFeature::extend(const SensorView& last_view) {
  if (observations_.empty() || mdim_ == 4) return std::nullopt;
  const WallObservation& latest = observations_.back();
  if (latest.view.t != last_view.t || latest.view.sensor != last_view.sensor) return std::nullopt;
  return mdim_ == 0 ? extend_line() : extend_ends();
}

// 0 → 2: the point cloud must be a long, thin line; then the standard EKF
// initialisation from the newest measurement (the wall already lies on it).
std::optional<Extension> WallFeature::extend_line() {
  if (num_observations() < config_.min_observations) return std::nullopt;
  Eigen::Index total = 0;
  for (const WallObservation& o : observations_) total += o.points.cols();
  if (total < config_.min_points) return std::nullopt;
  Eigen::Matrix2Xd all(2, total);
  Eigen::Index at = 0;
  for (const WallObservation& o : observations_) {
    all.middleCols(at, o.points.cols()) = o.points;
    at += o.points.cols();
  }
  const Eigen::Matrix2Xd centred = all.colwise() - all.rowwise().mean();
  const Eigen::SelfAdjointEigenSolver<Eigen::Matrix2d> eig(centred * centred.transpose() / static_cast<double>(total));
  if (std::sqrt(std::max(0.0, eig.eigenvalues()[0])) > config_.max_normal_std) return std::nullopt;
  if (geometry(x_).L < config_.min_length) return std::nullopt;

  const WallObservation& latest = observations_.back();
  Eigen::Matrix2d J_v;
  Eigen::Matrix<double, 2, 6> J_s;
  line_placement_jacobians(x_, latest.v[ls::kAlpha], latest.view.x_ms, J_v, J_s);
  Extension ext;
  ext.new_dims = 2;
  ext.sensor = latest.view.sensor;
  ext.J_sensor = J_s;
  ext.J_own = Eigen::MatrixXd(2, 0);
  ext.C_new = symmetric(J_v * latest.C_v.topLeftCorner<2, 2>() * J_v.transpose());
  feature_log(*this).debug("enters the map as a line: ", observations_.size(), " observations, ", total,
                           " points, ", std::sqrt(std::max(0.0, eig.eigenvalues()[0])), " m across it, ",
                           geometry(x_).L, " m long");
  mdim_ = 2;
  anchor_ = wall_centre(x_);  // eq. 14 about the centre at this moment
  gating_cov_.setZero();
  return ext;
}

// 2 → 3 → 4: an end seen as real often enough, in one place, and now. Its
// tangential coordinate τ = t·(R e + s − p1) of the measured end e = ρu + s_k t_m
// gives δτ = δs_k − ρ δα + t·δs + t·(R e)^⊥ δθ.
std::optional<Extension> WallFeature::extend_ends() {
  const WallObservation& latest = observations_.back();
  const Geometry g = geometry(x_);
  std::vector<int> add;
  for (int e : {kStart, kEnd}) {
    if (fixed_end(e) || !latest.real_end[e]) continue;
    std::vector<double> tau;
    for (const WallObservation& o : observations_)
      if (o.real_end[e]) tau.push_back(g.t.dot(*o.real_end[e] - g.p1));
    if (static_cast<int>(tau.size()) < config_.min_end_observations) continue;
    const auto [lo, hi] = std::minmax_element(tau.begin(), tau.end());
    if (*hi - *lo > 2.0 * config_.max_end_spread) continue;
    feature_log(*this).debug(e == kStart ? "start" : "end", " point fixed: seen as real ", tau.size(),
                             " times within ", *hi - *lo, " m along the wall");
    add.push_back(e);
  }
  if (add.empty()) return std::nullopt;

  const auto n = static_cast<Eigen::Index>(add.size());
  Extension ext;
  ext.new_dims = static_cast<int>(n);
  ext.sensor = latest.view.sensor;
  ext.J_sensor = Eigen::MatrixXd::Zero(n, 6);
  ext.J_own = Eigen::MatrixXd(n, 0);
  Eigen::MatrixXd J_v = Eigen::MatrixXd::Zero(n, ls::kSize);
  const Vec2 s = latest.view.x_ms.head<2>();
  Eigen::Vector4d moved = x_;
  for (Eigen::Index i = 0; i < n; ++i) {
    const int e = add[static_cast<std::size_t>(i)];
    const Vec2 end = *latest.real_end[e];
    ext.J_sensor.block<1, 2>(i, kX) = g.t.transpose();
    ext.J_sensor(i, kTheta) = g.t.dot(perp(end - s));
    J_v(i, ls::kAlpha) = -latest.v[ls::kRho];
    J_v(i, e == kStart ? ls::kSa : ls::kSb) = 1.0;
    moved.segment<2>(2 * e) = g.p1 + g.t.dot(end - g.p1) * g.t;  // slide onto the measured end
    ends_.push_back(e);
  }
  const Eigen::MatrixXd C = J_v * latest.C_v * J_v.transpose();
  ext.C_new = 0.5 * (C + C.transpose());
  x_ = moved;
  mdim_ += static_cast<int>(n);
  return ext;
}

// ---------------------------------------------------------------- WallType

std::vector<ParamSpec> WallType::param_specs() {
  const WallConfig d;
  return {
      param_int("min_observations", d.min_observations, "observations before the line enters the M-space", 1.0),
      param_int("min_points", d.min_points, "scan points (all stored observations) before the line enters", 2.0),
      param_double("min_length", d.min_length, "observed length before the line enters (m)", 0.0),
      param_double("max_normal_std", d.max_normal_std,
                   "largest std of the stored points across the line for it to enter (m)", 0.0),
      param_int("min_end_observations", d.min_end_observations,
                "observations of an end as a real end before it enters the M-space", 1.0),
      param_double("max_end_spread", d.max_end_spread,
                   "half the largest spread of those observed end positions along the wall (m)", 0.0),
      param_double("max_path_distance", d.max_path_distance,
                   "dense information older than this much path distance is pruned (m)", 0.0),
      param_int("max_observations", d.max_observations, "most observations kept as dense information", 1.0),
      param_double("match_margin", d.match_margin,
                   "a segment must overlap the wall, give or take this much, to match it (m)", 0.0),
      param_double("min_corner_angle_deg", d.min_corner_angle * 180.0 / std::numbers::pi,
                   "two walls share a corner only when they cross at this angle or more (deg)", 0.0, 90.0),
  };
}

WallType::WallType(const PluginArgs& args) {
  const Params& p = args.params;
  config_.min_observations = static_cast<int>(p.get_int("min_observations"));
  config_.min_points = static_cast<int>(p.get_int("min_points"));
  config_.min_length = p.get_double("min_length");
  config_.max_normal_std = p.get_double("max_normal_std");
  config_.min_end_observations = static_cast<int>(p.get_int("min_end_observations"));
  config_.max_end_spread = p.get_double("max_end_spread");
  config_.max_path_distance = p.get_double("max_path_distance");
  config_.max_observations = static_cast<int>(p.get_int("max_observations"));
  config_.match_margin = p.get_double("match_margin");
  config_.min_corner_angle = p.get_double("min_corner_angle_deg") * std::numbers::pi / 180.0;
  if (config_.max_observations < std::max(config_.min_observations, config_.min_end_observations))
    throw std::invalid_argument("wall: max_observations must be at least min_observations and min_end_observations");
}

const CoordLayout& WallType::layout() const { return wall_layout(); }

std::vector<std::string> WallType::measurement_kinds() const { return {ls::kKind}; }

std::unique_ptr<Feature> WallType::create(const Measurement& m, const SensorView& view) {
  if (!is_line_measurement(m) || !(m.v[ls::kSb] > m.v[ls::kSa])) return nullptr;
  const Vec2 a = map_point(view.x_ms, measured_end(m.v, kStart));
  const Vec2 b = map_point(view.x_ms, measured_end(m.v, kEnd));
  return std::make_unique<WallFeature>(config_, place_on_line(m.v[ls::kRho], m.v[ls::kAlpha], view.x_ms, a, b), 0,
                                       std::vector<int>{});
}

std::optional<FeatureSample> WallType::sample(int dim, std::uint64_t seed) const {
  if (dim != 0 && dim != 2 && dim != 3 && dim != 4) return std::nullopt;
  std::mt19937_64 rng(seed);
  auto uniform = [&](double lo, double hi) { return std::uniform_real_distribution<double>(lo, hi)(rng); };
  const Vec2 centre(uniform(-5.0, 5.0), uniform(-5.0, 5.0));
  const double heading = uniform(-std::numbers::pi, std::numbers::pi), L = uniform(2.0, 6.0);
  const Vec2 t(std::cos(heading), std::sin(heading)), gamma(t.y(), -t.x());
  Eigen::Vector4d x_f;
  x_f << centre - 0.5 * L * t, centre + 0.5 * L * t;
  std::vector<int> ends;
  if (dim >= 3) ends.push_back(uniform(0.0, 1.0) < 0.5 ? kStart : kEnd);
  if (dim == 4) ends.push_back(1 - ends.front());

  const Vec2 sensor = centre + uniform(2.0, 5.0) * gamma + uniform(-L / 3.0, L / 3.0) * t;
  const double yaw = std::atan2(-gamma.y(), -gamma.x()) + uniform(-0.5, 0.5);
  FeatureSample out;
  out.x_ms = make_pose2d(sensor.x(), sensor.y(), yaw);
  out.feature = std::make_unique<WallFeature>(config_, x_f, dim, ends);

  const Eigen::VectorXd x_o = to_sensor_frame(wall_layout(), x_f, out.x_ms);
  const PredictedLine p = predict_line(x_o);
  Measurement& m = out.measurement;
  m.kind = ls::kKind;
  m.v = p.h;
  m.C_v = Eigen::Vector4d(1e-4, 1e-4, 2.5e-3, 2.5e-3).asDiagonal();
  const auto real = [&](int e) { return std::find(ends.begin(), ends.end(), e) != ends.end(); };
  m.flags = ls::make_flags(real(kStart) ? ls::EndReason::Depth : ls::EndReason::Occluded,
                           real(kEnd) ? ls::EndReason::Depth : ls::EndReason::Occluded);
  constexpr int kPoints = 10;
  m.dense.resize(2, kPoints);
  for (int i = 0; i < kPoints; ++i) {
    const double f = static_cast<double>(i) / (kPoints - 1);
    m.dense.col(i) = (1.0 - f) * x_o.head<2>() + f * x_o.tail<2>();
  }
  return out;
}

std::optional<SampleObservation> WallType::sample_observation(int dim, std::uint64_t seed, int /*k*/) const {
  std::optional<FeatureSample> s = sample(dim, seed);
  if (!s) return std::nullopt;
  SampleObservation o{s->x_ms, 0.0, s->measurement};
  o.measurement.flags = ls::make_flags(ls::EndReason::Depth, ls::EndReason::Depth);
  return o;
}

namespace {

/// The dense information of a saved wall (see WallFeature::save).
std::deque<WallObservation> restore_observations(const SavedFeature& saved) {
  const Eigen::MatrixXd records = saved::records(saved, "observations", kObservationRecord, "wall");
  const Eigen::MatrixXd points = saved::records(saved, "points", 2, "wall");
  std::deque<WallObservation> out;
  Eigen::Index at = 0;
  for (Eigen::Index i = 0; i < records.cols(); ++i) {
    const Eigen::VectorXd col = records.col(i);
    WallObservation o;
    o.v = col.head<4>();
    o.C_v = saved::get_matrix(col, 4, 4, 4);
    const double flags = col[20], count = col[kObservationRecord - 1];
    if (!(flags >= 0.0 && flags <= 4294967295.0 && std::floor(flags) == flags) ||
        !(count >= 0.0 && std::floor(count) == count && at + static_cast<Eigen::Index>(count) <= points.cols()))
      throw std::invalid_argument("wall: saved observation " + std::to_string(i) +
                                  " has malformed flags or more points than the saved 'points'");
    o.flags = static_cast<std::uint32_t>(flags);
    o.view = saved::get_view(col, 21);
    for (int e : {kStart, kEnd}) {
      const int base = 21 + saved::kViewSize + 3 * e;
      if (col[base] != 0.0) o.real_end[e] = Vec2(col.segment<2>(base + 1));
    }
    o.points = points.middleCols(at, static_cast<Eigen::Index>(count));
    at += static_cast<Eigen::Index>(count);
    out.push_back(std::move(o));
  }
  if (at != points.cols()) throw std::invalid_argument("wall: saved 'points' holds points of no observation");
  return out;
}

}  // namespace

std::unique_ptr<Feature> WallType::restore(const SavedFeature& saved) const {
  saved::expect_layout(saved, kSaveVersion, {"observations", "points", "gating_covariance"}, "wall");
  if (saved.coords.size() != 4 || !saved.coords.allFinite() || !saved.extra.allFinite())
    throw std::invalid_argument("wall: saved coordinates must be 4 finite numbers");
  const Eigen::Index n_ends = saved.extra.size() - 5;
  if (n_ends < 0)
    throw std::invalid_argument(
        "wall: saved extra must hold the measured ends, the two shared flags, L_s and the anchor (x, y)");
  std::vector<int> ends;
  for (Eigen::Index i = 0; i < n_ends; ++i) {
    const double e = saved.extra[i];
    if (e != 0.0 && e != 1.0) throw std::invalid_argument("wall: saved end points must be 0 (start) or 1 (end)");
    ends.push_back(static_cast<int>(e));
  }
  const std::array<bool, 2> shared = {saved.extra[n_ends] != 0.0, saved.extra[n_ends + 1] != 0.0};
  const int unshared_dim = saved.mspace_dim == 0 ? 0 : 2 + static_cast<int>(ends.size());
  auto wall = std::make_unique<WallFeature>(config_, Eigen::Vector4d(saved.coords), unshared_dim, ends);
  wall->set_anchor(saved.extra.tail<2>());
  if (shared[kStart] || shared[kEnd]) wall->set_shared(shared, saved.extra[n_ends + 2]);
  if (wall->mspace_dim() != saved.mspace_dim)
    throw std::invalid_argument("wall: saved M-space dimension does not match its ends and shared corners");
  wall->set_dense(restore_observations(saved),
                  saved::fixed(saved, "gating_covariance", 4, 4, Eigen::Matrix4d::Zero(), "wall"));
  return wall;
}

std::unique_ptr<Feature> WallType::from_true_shape(const TrueShape& shape, const Pose6& x_ms) const {
  if (shape.kind != TrueShape::Kind::Segment) return nullptr;
  // The normal γ = (t_y, −t_x) must point towards the sensor (eq. 13): order
  // the ends so that it does.
  Vec2 start = shape.a.head<2>(), end = shape.b.head<2>();
  const Vec2 t = (end - start).normalized();
  if (Vec2(t.y(), -t.x()).dot(x_ms.head<2>() - start) < 0.0) std::swap(start, end);
  Eigen::Vector4d x_f;
  x_f << start, end;
  return std::make_unique<WallFeature>(config_, x_f, 4, std::vector<int>{kStart, kEnd});
}

}  // namespace mspace::wall
