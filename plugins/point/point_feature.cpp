// point_feature.cpp — see point_feature.hpp.
#include "point_feature.hpp"

#include <Eigen/Dense>
#include <algorithm>
#include <cmath>
#include <limits>
#include <numbers>
#include <random>
#include <stdexcept>

#include "mspace/feature_log.hpp"
#include "mspace/pose.hpp"
#include "mspace/saved_state.hpp"
#include "mspace/transform.hpp"

namespace mspace::point {
namespace {

constexpr int kDim = kFullDim;  ///< full M-space dimension = size of x_f

/// Shorter vectors (a predicted point, a measured bearing) have no direction.
constexpr double kMinNorm = 1e-9;
/// Depths below this (m) are clamped when weighting a ray in the least squares.
constexpr double kMinRayDepth = 0.05;
/// Reweighting passes of the triangulation (the depths settle in two or three).
constexpr int kTriangulationPasses = 4;
/// A least-squares information matrix whose smallest eigenvalue is below this
/// fraction of its largest is treated as singular.
constexpr double kMinInformationRatio = 1e-12;

const CoordLayout& point_layout() {
  static const CoordLayout layout{BlockKind::Point3D};
  return layout;
}

double degrees_to_radians(double deg) { return deg * std::numbers::pi / 180.0; }

/// Distance of a sensor-frame point from the sensor's z axis, √(x² + y²).
double axis_distance(const Eigen::Vector3d& p) { return std::hypot(p.x(), p.y()); }

/// A well-formed measurement of `kind`: a `size`-vector with a size × size covariance.
bool is_measurement_of(const Measurement& m, const char* kind, int size = kDim) {
  return m.kind == kind && m.v.size() == size && m.C_v.rows() == size && m.C_v.cols() == size &&
         m.v.allFinite() && m.C_v.allFinite();
}

/// A well-formed range/bearing/elevation measurement.
bool is_point_measurement(const Measurement& m) { return is_measurement_of(m, kRangeBearingElevation); }

/// A well-formed planar range/bearing measurement.
bool is_planar_measurement(const Measurement& m) { return is_measurement_of(m, kRangeBearing, 2); }

/// Either of the two: a measurement with a range.
bool is_ranged_measurement(const Measurement& m) { return is_point_measurement(m) || is_planar_measurement(m); }

/// The observation of a ranged measurement, a planar one padded with zeros.
PointObservation observation_of(const Measurement& m, const SensorView& view) {
  PointObservation o;
  o.size = static_cast<int>(m.v.size());
  o.v.setZero();
  o.C_v.setZero();
  o.v.head(o.size) = m.v;
  o.C_v.topLeftCorner(o.size, o.size) = m.C_v;
  o.view = view;
  return o;
}

/// C_v of an observation without its padding.
Eigen::MatrixXd covariance_of(const PointObservation& o) { return o.C_v.topLeftCorner(o.size, o.size); }

/// The back-projection of a ranged observation from its own view.
placement::Placement place_observation(const PointObservation& o) {
  return o.planar() ? back_project_planar(o.v.head<2>(), o.view.x_ms) : back_project(o.v, o.view.x_ms);
}

/// A well-formed bearing: also a direction (v not ~0).
bool is_bearing_measurement(const Measurement& m) {
  return is_measurement_of(m, kBearing3d) && m.v.norm() >= kMinNorm;
}

/// A bearing that can become a ray (its covariance has rank 2 across it).
bool is_usable_bearing(const Measurement& m) {
  return is_bearing_measurement(m) && tangent_covariance(m.v, m.C_v).has_value();
}

/// Can v be back-projected to a point with a defined bearing (a positive
/// range, away from the sensor's z axis)?
bool is_placeable(const Eigen::Vector3d& v) {
  return v[0] > 0.0 && axis_distance(spherical_to_cartesian(v)) >= kMinAxisDistance;
}

/// The same for an observation (a planar one lies in the scan plane: its
/// distance from the axis is its range).
bool is_placeable(const PointObservation& o) { return o.planar() ? o.v[0] >= kMinAxisDistance : is_placeable(o.v); }

/// Was `taken` the view of the current step and sensor?
bool taken_at(const SensorView& taken, const SensorView& now) {
  return taken.t == now.t && taken.sensor == now.sensor;
}

/// The map-frame point p expressed through the camera pose x_ms:
/// p = x_ms ⊕ p_s with p_s = T(p | x_ms) its camera-frame coordinates (eq. 7)
/// held fixed. J_v = ∂p/∂p_s = R_ms, J_s = ∂p/∂x_ms (placement.hpp).
placement::Placement attach_to_camera(const Eigen::Vector3d& p, const Pose6& x_ms) {
  const Eigen::VectorXd p_s = to_sensor_frame(point_layout(), p, x_ms);
  return placement::place(point_layout(), p_s, Eigen::Matrix3d::Identity(), x_ms);
}

/// A map-frame covariance C of a point attached to the camera as in
/// attach_to_camera, in the camera frame: J_vᵀ C J_v (J_v = R_ms is a rotation).
Eigen::Matrix3d to_camera_frame(const placement::Placement& attached, const Eigen::Matrix3d& C) {
  return attached.J_v.transpose() * C * attached.J_v;
}

/// The rays of the stored bearing observations, oldest first.
std::vector<Ray> rays_of(const std::deque<PointObservation>& observations) {
  std::vector<Ray> rays;
  rays.reserve(observations.size());
  for (const PointObservation& o : observations) rays.push_back(make_ray(o.v, o.C_v, o.view.x_ms));
  return rays;
}

/// One least-squares pass of triangulate() with the given ray depths.
std::optional<Triangulation> solve_rays(const std::vector<Ray>& rays, const std::vector<double>& depth,
                                        const std::optional<DepthPrior>& prior) {
  // Normal equations A p = b, written relative to the last camera centre o
  // (p = o + q) so that far-away map coordinates do not cost precision.
  const Ray& last = rays.back();
  const Eigen::Vector3d& o = last.centre;
  Eigen::Matrix3d A = Eigen::Matrix3d::Zero();
  Eigen::Vector3d b = Eigen::Vector3d::Zero();
  for (std::size_t i = 0; i < rays.size(); ++i) {
    const Eigen::Matrix3d W = rays[i].information / (depth[i] * depth[i]);
    A += W;
    b += W * (rays[i].centre - o);
  }
  if (prior) {
    const double w = 1.0 / (prior->sigma * prior->sigma);
    A += w * last.direction * last.direction.transpose();
    b += w * last.direction * prior->depth;
  }
  const Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> eig(0.5 * (A + A.transpose()));
  const Eigen::Vector3d lambda = eig.eigenvalues();  // ascending
  if (eig.info() != Eigen::Success || !(lambda[2] > 0.0) || lambda[0] < kMinInformationRatio * lambda[2]) {
    return std::nullopt;
  }
  Triangulation t;
  t.covariance = eig.eigenvectors() * lambda.cwiseInverse().asDiagonal() * eig.eigenvectors().transpose();
  t.point = o + t.covariance * b;
  t.min_depth = std::numeric_limits<double>::infinity();
  for (const Ray& r : rays) t.min_depth = std::min(t.min_depth, r.direction.dot(t.point - r.centre));
  return t;
}

// ---- conformance samples

/// A uniform draw in [lo, hi) from a seeded engine.
double draw(std::mt19937_64& rng, double lo, double hi) {
  return std::uniform_real_distribution<double>(lo, hi)(rng);
}

/// A sensor pose with a small tilt: the sensor looks along x (range sensor)
/// or, for an upward camera, along the map's z.
Pose6 sample_pose(std::mt19937_64& rng) {
  const double x = draw(rng, -10, 10), y = draw(rng, -10, 10), z = draw(rng, 0, 1);
  const double theta = draw(rng, -3, 3), phi = draw(rng, -0.2, 0.2), psi = draw(rng, -0.2, 0.2);
  return make_pose(x, y, z, theta, phi, psi);
}

/// The view a conformance sample is taken from.
SensorView sample_view(const Pose6& x_ms) {
  SensorView view;
  view.x_ms = x_ms;
  view.C_ms = Mat6::Identity() * 1e-4;
  return view;
}

}  // namespace

// ---------------------------------------------------------------- spherical maps

Eigen::Vector3d cartesian_to_spherical(const Eigen::Vector3d& p, Eigen::Matrix3d* J) {
  const double rho2 = p.x() * p.x() + p.y() * p.y();
  const double rho = std::sqrt(rho2);
  const double r2 = rho2 + p.z() * p.z();
  const double r = std::sqrt(r2);
  if (J != nullptr) {
    // ∂r/∂p = pᵀ/r; ∂b/∂p = (−y, x, 0)/ρ²; ∂e/∂p = (−xz/ρ, −yz/ρ, ρ)/r².
    *J << p.x() / r, p.y() / r, p.z() / r,  //
        -p.y() / rho2, p.x() / rho2, 0.0,   //
        -p.x() * p.z() / (rho * r2), -p.y() * p.z() / (rho * r2), rho / r2;
  }
  return {r, std::atan2(p.y(), p.x()), std::atan2(p.z(), rho)};
}

Eigen::Vector3d spherical_to_cartesian(const Eigen::Vector3d& v, Eigen::Matrix3d* J) {
  const double r = v[0];
  const double cb = std::cos(v[1]), sb = std::sin(v[1]);
  const double ce = std::cos(v[2]), se = std::sin(v[2]);
  if (J != nullptr) {
    // Columns: ∂p/∂r, ∂p/∂b, ∂p/∂e.
    *J << ce * cb, -r * ce * sb, -r * se * cb,  //
        ce * sb, r * ce * cb, -r * se * sb,     //
        se, 0.0, r * ce;
  }
  return {r * ce * cb, r * ce * sb, r * se};
}

placement::Placement back_project(const Eigen::Vector3d& v, const Pose6& x_ms) {
  // Spherical → Cartesian in the sensor frame, then the inverse of eq. 7
  // (the generic SDK placement: x_mf = R_ms p + t_ms with its Jacobians).
  Eigen::Matrix3d J_pv;
  const Eigen::Vector3d p = spherical_to_cartesian(v, &J_pv);
  return placement::place(point_layout(), p, J_pv, x_ms);
}

placement::Placement back_project_planar(const Eigen::Vector2d& v, const Pose6& x_ms) {
  const double r = v[0], cb = std::cos(v[1]), sb = std::sin(v[1]);
  Eigen::Matrix<double, 3, 2> J_pv;  // columns ∂p/∂r, ∂p/∂b
  J_pv << cb, -r * sb,  //
      sb, r * cb,       //
      0.0, 0.0;
  return placement::place(point_layout(), Eigen::Vector3d(r * cb, r * sb, 0.0), J_pv, x_ms);
}

Eigen::Vector2d planar_range_bearing(const Eigen::Vector3d& p, Eigen::Matrix<double, 2, 3>* J) {
  const double rho2 = p.x() * p.x() + p.y() * p.y();
  const double rho = std::sqrt(rho2);
  if (J != nullptr) {
    *J << p.x() / rho, p.y() / rho, 0.0,  //
        -p.y() / rho2, p.x() / rho2, 0.0;
  }
  return {rho, std::atan2(p.y(), p.x())};
}

std::optional<RayHeight> ray_height(const Eigen::Vector2d& xy, const Eigen::Vector3d& v, const Pose6& x_ms) {
  // The unit direction s(b, e) in the sensor frame and ∂s/∂(r, b, e) (the
  // range column is zero: the ray does not depend on it).
  Eigen::Matrix3d J_sv;
  const Eigen::Vector3d s = spherical_to_cartesian(Eigen::Vector3d(1.0, v[1], v[2]), &J_sv);
  J_sv.col(0).setZero();
  // u = R_ms s through the SDK placement of s as a point: x = R_ms s + t,
  // so ∂u/∂x_ms = J_s − [I 0] and ∂u/∂v = J_v.
  const placement::Placement ray = placement::place(point_layout(), s, J_sv, x_ms);
  const Eigen::Vector3d t = x_ms.head<3>();
  const Eigen::Vector3d u = ray.x_f - t;
  Eigen::Matrix<double, 3, 6> J_us = ray.J_s;
  J_us.leftCols<3>() -= Eigen::Matrix3d::Identity();
  const Eigen::Vector2d u_h = u.head<2>(), g = xy - t.head<2>();
  const double q = u_h.squaredNorm(), k = u_h.dot(g);
  constexpr double kMinHorizontal = 1e-3;  // |u_h| = sin of the ray's angle from the vertical
  if (q < kMinHorizontal * kMinHorizontal || !(k > 0.0)) return std::nullopt;
  const double lambda = k / q;
  RayHeight h;
  h.z = t.z() + u.z() * lambda;
  // z = t_z + u_z (u_hᵀ g)/(u_hᵀ u_h), g = (x, y) − t_h.
  Eigen::RowVector3d dz_du;
  dz_du.head<2>() = u.z() * (g.transpose() / q - 2.0 * k * u_h.transpose() / (q * q));
  dz_du[2] = lambda;
  h.J_xy = u.z() * u_h.transpose() / q;
  h.J_s = dz_du * J_us;
  h.J_s.head<2>() -= h.J_xy;  // through g = (x, y) − t_h
  h.J_s[2] += 1.0;            // t_z
  h.J_v = dz_du * ray.J_v;
  return h;
}

// ---------------------------------------------------------------- bearing geometry

TangentBasis tangent_basis(const Eigen::Vector3d& n) {
  const double s = n.z() >= 0.0 ? 1.0 : -1.0;
  const double k = 1.0 / (1.0 + s * n.z());
  const double x = n.x(), y = n.y();
  TangentBasis t;
  t.E.col(0) << 1.0 - k * x * x, -k * x * y, -s * x;
  t.E.col(1) << -s * k * x * y, s * (1.0 - k * y * y), -y;
  // ∂k/∂n_z = −s k²; everything else by the product rule.
  t.dE1 << -2.0 * k * x, 0.0, s * k * k * x * x,  //
      -k * y, -k * x, s * k * k * x * y,          //
      -s, 0.0, 0.0;
  t.dE2 << -s * k * y, -s * k * x, k * k * x * y,  //
      0.0, -2.0 * s * k * y, k * k * y * y,        //
      0.0, -1.0, 0.0;
  return t;
}

// eq. 16 for a bearing: η = Eᵀ p̂, the predicted direction seen in the
// measured direction's tangent plane (see the header for the Jacobians).
bool bearing_innovation(const Eigen::Vector3d& p, const Eigen::Vector3d& v, Innovation& out) {
  const double range = p.norm(), length = v.norm();
  if (range < kMinNorm || length < kMinNorm) return false;
  const Eigen::Vector3d p_hat = p / range, n = v / length;
  if (p_hat.dot(n) <= 0.0) return false;
  const TangentBasis t = tangent_basis(n);
  const Eigen::Matrix3d I = Eigen::Matrix3d::Identity();
  out.eta = t.E.transpose() * p_hat;
  out.J_eta_o = t.E.transpose() * (I - p_hat * p_hat.transpose()) / range;
  Eigen::Matrix<double, 2, 3> J_eta_n;  // ∂η/∂n at fixed p
  J_eta_n.row(0) = p_hat.transpose() * t.dE1;
  J_eta_n.row(1) = p_hat.transpose() * t.dE2;
  out.J_eta_v = J_eta_n * (I - n * n.transpose()) / length;  // n = v/|v|
  return true;
}

std::optional<Eigen::Matrix2d> tangent_covariance(const Eigen::Vector3d& v, const Eigen::Matrix3d& C_v) {
  const double length = v.norm();
  if (!(length >= kMinNorm)) return std::nullopt;
  // n = v/|v| moves by (I − nnᵀ)δv/|v|; its tangent-plane coordinates are Eᵀδn = Eᵀδv/|v|.
  const Eigen::Matrix<double, 3, 2> E = tangent_basis(v / length).E;
  const Eigen::Matrix2d C = E.transpose() * C_v * E / (length * length);
  const Eigen::Matrix2d C_sym = 0.5 * (C + C.transpose());
  const Eigen::Vector2d lambda = Eigen::SelfAdjointEigenSolver<Eigen::Matrix2d>(C_sym).eigenvalues();
  if (!(lambda[1] > 0.0) || lambda[0] < kMinInformationRatio * lambda[1]) return std::nullopt;
  return C_sym;
}

Ray make_ray(const Eigen::Vector3d& v, const Eigen::Matrix3d& C_v, const Pose6& x_ms) {
  const std::optional<Eigen::Matrix2d> C_t = tangent_covariance(v, C_v);
  if (!C_t) {
    throw std::invalid_argument("point: a bearing needs a non-zero direction and a covariance of rank 2 across it");
  }
  const Eigen::Vector3d n = v.normalized();
  const Eigen::Matrix<double, 3, 2> E = tangent_basis(n).E;
  const Eigen::Matrix3d R = rotation(x_ms);
  Ray r;
  r.centre = x_ms.head<3>();
  r.direction = R * n;
  r.information = R * E * C_t->inverse() * E.transpose() * R.transpose();
  return r;
}

double max_parallax(const std::vector<Ray>& rays) {
  double largest = 0.0;
  for (std::size_t i = 0; i < rays.size(); ++i) {
    for (std::size_t j = i + 1; j < rays.size(); ++j) {
      const Eigen::Vector3d& a = rays[i].direction;
      const Eigen::Vector3d& b = rays[j].direction;
      largest = std::max(largest, std::atan2(a.cross(b).norm(), a.dot(b)));
    }
  }
  return largest;
}

std::optional<Triangulation> triangulate(const std::vector<Ray>& rays, const std::optional<DepthPrior>& prior) {
  if (rays.empty()) return std::nullopt;
  std::vector<double> depth(rays.size(), prior ? prior->depth : 1.0);
  std::optional<Triangulation> t;
  for (int pass = 0; pass < kTriangulationPasses; ++pass) {
    t = solve_rays(rays, depth, prior);
    if (!t) return std::nullopt;
    for (std::size_t i = 0; i < rays.size(); ++i) {
      depth[i] = std::max(rays[i].direction.dot(t->point - rays[i].centre), kMinRayDepth);
    }
  }
  return t;
}

// ---------------------------------------------------------------- PointFeature

PointFeature::PointFeature(const PointConfig& config, const PointObservation& first) : config_(config) {
  mdim_ = kTentativeDim;
  place_at(first);
}

PointFeature::PointFeature(const PointConfig& config, const Measurement& bearing, const SensorView& view)
    : config_(config) {
  mdim_ = 0;
  place_on_rays({make_ray(bearing.v, bearing.C_v, view.x_ms)}, view);
}

PointFeature::PointFeature(const PointConfig& config, const Eigen::Vector3d& x_f, int mspace_dim)
    : config_(config) {
  x_ = x_f;
  mdim_ = mspace_dim;
}

namespace {

/// Version 2 added the size of v to each record (planar observations).
constexpr int kSaveVersion = 2;
constexpr int kVersion1Record = 3 + 9 + saved::kViewSize;
constexpr int kObservationRecord = 1 + kVersion1Record;

Eigen::MatrixXd save_observations(const std::deque<PointObservation>& list) {
  Eigen::MatrixXd out(kObservationRecord, static_cast<Eigen::Index>(list.size()));
  for (Eigen::Index i = 0; i < out.cols(); ++i) {
    const PointObservation& o = list[static_cast<std::size_t>(i)];
    auto col = out.col(i);
    col[0] = o.size;
    col.segment<3>(1) = o.v;
    saved::put_matrix(col, 4, o.C_v);
    saved::put_view(col, 13, o.view);
  }
  return out;
}

std::deque<PointObservation> restore_observations(const SavedFeature& s, const char* name) {
  const bool v1 = s.version == 1;
  const Eigen::MatrixXd a = saved::records(s, name, v1 ? kVersion1Record : kObservationRecord, "point");
  const int at = v1 ? 0 : 1;  // version 1: no size row, every observation 3 rows
  std::deque<PointObservation> out;
  for (Eigen::Index i = 0; i < a.cols(); ++i) {
    const Eigen::VectorXd col = a.col(i);
    PointObservation o;
    o.size = v1 ? 3 : static_cast<int>(col[0]);
    if (!v1 && col[0] != 2.0 && col[0] != 3.0)
      throw std::invalid_argument(std::string("point: saved array '") + name + "' has a record of size " +
                                  std::to_string(col[0]) + " (2 or 3 expected)");
    o.v = col.segment<3>(at);
    o.C_v = saved::get_matrix(col, at + 3, 3, 3);
    o.view = saved::get_view(col, at + 12);
    if (o.planar() && (o.v[2] != 0.0 || o.C_v.row(2).any() || o.C_v.col(2).any()))
      throw std::invalid_argument(std::string("point: saved array '") + name +
                                  "' has a planar record with a third row");
    out.push_back(o);
  }
  return out;
}

}  // namespace

PointFeature::PointFeature(const PointConfig& config, const SavedFeature& s) : config_(config) {
  // Version 1 (before planar points) is read too: the same arrays without the size row.
  saved::expect_layout(s, s.version == 1 ? 1 : kSaveVersion, {"observations", "rays", "gating_covariance"}, "point");
  const bool known_dim = s.mspace_dim == kTentativeDim || s.mspace_dim == kPlanarDim || s.mspace_dim == kFullDim;
  if (s.coords.size() != kDim || !s.coords.allFinite() || !known_dim || s.extra.size() != 0) {
    throw std::invalid_argument(
        "point: restore needs 3 finite coordinates, dimension 0, 2 or 3 and no extra state (got " +
        std::to_string(s.coords.size()) + " coordinates, dimension " + std::to_string(s.mspace_dim) + ")");
  }
  x_ = s.coords;
  mdim_ = s.mspace_dim;
  observations_ = restore_observations(s, "observations");
  rays_ = restore_observations(s, "rays");
  gating_cov_ = saved::fixed(s, "gating_covariance", kDim, kDim, Eigen::Matrix3d::Zero(), "point");
  for (const PointObservation& r : rays_)
    if (r.planar()) throw std::invalid_argument("point: a saved ray has 2 rows");
  if (mdim_ != kTentativeDim && !rays_.empty())
    throw std::invalid_argument("point: an initialised point keeps no rays");
  if (mdim_ == kFullDim && !observations_.empty())
    throw std::invalid_argument("point: a point at dimension 3 keeps no observations");
  for (const PointObservation& o : observations_)
    if (mdim_ == kPlanarDim && o.planar())
      throw std::invalid_argument("point: a point at dimension 2 keeps only observations with an elevation");
}

SavedFeature PointFeature::save() const {
  SavedFeature s{x_, mdim_, {}, {}, kSaveVersion};
  if (!observations_.empty()) s.put("observations", save_observations(observations_));
  if (!rays_.empty()) s.put("rays", save_observations(rays_));
  if (mdim_ == kTentativeDim) s.put("gating_covariance", gating_cov_);
  return s;
}

const CoordLayout& PointFeature::layout() const { return point_layout(); }

// Table II: the M-space of a point is the point itself, B = I. A planar point
// has the first two rows of it, B = [I₂ 0] and B̃ = Bᵀ (z outside the M-space).
// A tentative point has no M-space: B is 0×3 and B̃ 3×0, so B B̃ = I₀ (eq. 12)
// holds at every dimension.
Eigen::MatrixXd PointFeature::B() const { return Eigen::MatrixXd::Identity(mdim_, kDim); }

Eigen::MatrixXd PointFeature::B_dual() const { return Eigen::MatrixXd::Identity(kDim, mdim_); }

// eq. 16. Range/bearing/elevation: η(x_o, v) = h(x_o) − v, so J_ηo = ∂h/∂x_o
// and J_ηv = −I. Planar range/bearing (and the planar part of a
// range/bearing/elevation at dim 2): the same with the 2-row h of
// planar_range_bearing. Bearing: see bearing_innovation().
bool PointFeature::innovation(const Eigen::VectorXd& x_o, const Measurement& m,
                              Innovation& out) const {
  if (x_o.size() != kDim) return false;
  const Eigen::Vector3d p = x_o;
  if (is_bearing_measurement(m)) return mdim_ != kPlanarDim && bearing_innovation(p, m.v, out);
  const bool planar = is_planar_measurement(m);
  if (!planar && !is_point_measurement(m)) return false;
  if (axis_distance(p) < kMinAxisDistance) return false;
  if (planar || mdim_ == kPlanarDim) {
    Eigen::Matrix<double, 2, 3> J_ho;
    const Eigen::Vector2d h = planar_range_bearing(p, &J_ho);
    if (planar) {
      out.eta = h - m.v;
      out.J_eta_v = -Eigen::MatrixXd::Identity(2, 2);
    } else {
      // The planar part of (r, b, e): horizontal range r cos e and bearing b.
      const double r = m.v[0], b = m.v[1], ce = std::cos(m.v[2]), se = std::sin(m.v[2]);
      out.eta = h - Eigen::Vector2d(r * ce, b);
      out.J_eta_v.resize(2, 3);
      out.J_eta_v << -ce, 0.0, r * se,  //
          0.0, -1.0, 0.0;
    }
    out.eta[1] = wrap_angle(out.eta[1]);
    out.J_eta_o = J_ho;
    return true;
  }
  Eigen::Matrix3d J_ho;
  const Eigen::Vector3d h = cartesian_to_spherical(p, &J_ho);
  Eigen::Vector3d eta = h - m.v;
  eta[1] = wrap_angle(eta[1]);
  eta[2] = wrap_angle(eta[2]);
  out.eta = eta;
  out.J_eta_o = J_ho;
  out.J_eta_v = -Eigen::MatrixXd::Identity(kDim, kDim);
  return true;
}

Eigen::MatrixXd PointFeature::gating_covariance() const {
  if (mdim_ != kTentativeDim) return {};
  return gating_cov_;
}

std::vector<Ray> PointFeature::rays() const { return rays_of(rays_); }

void PointFeature::place_at(const PointObservation& o) {
  const placement::Placement bp = place_observation(o);
  x_ = bp.x_f;
  // First-order covariance of x_f = g(v, x_ms) with v and x_ms independent
  // (for a planar observation z varies only with the sensor pose).
  gating_cov_ = placement::covariance(bp, covariance_of(o), o.view.C_ms);
}

void PointFeature::place_on_rays(const std::vector<Ray>& rays, const SensorView& newest) {
  const std::optional<Triangulation> t =
      triangulate(rays, DepthPrior{config_.initial_depth, config_.initial_depth_sigma});
  // With the prior the information is positive definite whenever the newest
  // ray has a rank-2 covariance, which make_ray has checked.
  if (!t) throw std::logic_error("point: the least squares of the rays with a depth prior is singular");
  // The least-squares covariance is relative to the cameras; the newest
  // camera's own pose uncertainty is added as for a range/bearing/elevation
  // back-projection, with the point held fixed in that camera's frame.
  const placement::Placement attached = attach_to_camera(t->point, newest.x_ms);
  x_ = attached.x_f;
  gating_cov_ = placement::covariance(attached, to_camera_frame(attached, t->covariance), newest.C_ms);
}

void PointFeature::store_ray(const PointObservation& observation) {
  // The newest ray is always kept. The one before it stays only if it is at
  // least ray_spacing (path distance) beyond its own predecessor: a camera
  // that stands still or creeps keeps replacing the newest ray.
  const auto n = rays_.size();
  const bool replace_newest =
      n >= 2 && rays_[n - 1].view.path_distance - rays_[n - 2].view.path_distance < config_.ray_spacing;
  if (replace_newest) rays_.pop_back();
  rays_.push_back(observation);
  // Over the limit: drop the second oldest, keeping the first ray (the
  // widest baseline) and the newest ones.
  if (static_cast<int>(rays_.size()) > config_.max_rays) rays_.erase(rays_.begin() + 1);
}

void PointFeature::add_dense_information(const Measurement& m, const SensorView& view) {
  if (is_ranged_measurement(m)) {
    if (mdim_ == kFullDim) return;  // the estimator holds all there is to know
    const PointObservation o = observation_of(m, view);
    if (mdim_ == kPlanarDim) {
      // The evidence for 2 → 3 is the newest elevation; a planar
      // measurement adds nothing the estimator does not hold.
      if (!o.planar()) observations_.assign(1, o);
      return;
    }
    observations_.push_back(o);
    while (static_cast<int>(observations_.size()) > config_.max_dense) observations_.pop_front();
    place_at(o);
    return;
  }
  if (!is_usable_bearing(m)) {
    throw std::invalid_argument("point: add_dense_information got a measurement of kind '" + m.kind +
                                "' (expected '" + kRangeBearingElevation + "' or '" + kBearing3d +
                                "' with a 3-vector and a 3×3 covariance, of rank 2 across a bearing, or '" +
                                kRangeBearing + "' with a 2-vector and a 2×2 covariance)");
  }
  if (mdim_ != kTentativeDim) return;
  store_ray({m.v, m.C_v, view});
  place_on_rays(rays_of(rays_), view);
}

std::optional<Extension> PointFeature::extend(const SensorView& last_view) {
  if (mdim_ == kFullDim) return std::nullopt;
  std::optional<Extension> ext;
  if (mdim_ == kPlanarDim) {
    ext = extend_elevation(last_view);
  } else {
    ext = extend_from_range_bearing(last_view);
    if (!ext) ext = extend_from_rays(last_view);
  }
  if (ext) {
    mdim_ += ext->new_dims;
    observations_.clear();
    rays_.clear();
  }
  return ext;
}

std::optional<Extension> PointFeature::extend_from_range_bearing(const SensorView& last_view) {
  if (num_observations() < config_.min_observations) return std::nullopt;
  const PointObservation& latest = observations_.back();
  if (!taken_at(latest.view, last_view) || latest.v[0] < config_.min_range_for_init || !is_placeable(latest)) {
    return std::nullopt;
  }
  // Standard EKF landmark initialisation: δx_f = J_s δx_ms + J_v δv, and the
  // new M-space perturbations are B δx_f: all of it with an elevation
  // (B = I), its x and y without (B = [I₂ 0], z stays in the scan plane).
  const placement::Placement bp = place_observation(latest);
  x_ = bp.x_f;
  feature_log(*this).debug("placed from the newest of ", num_observations(), " observations, ", latest.v[0],
                           " m away", latest.planar() ? " (planar: x, y only)" : "");
  Extension ext = placement::full_extension(bp, covariance_of(latest), latest.view.sensor);
  if (latest.planar()) {
    ext.new_dims = kPlanarDim;
    ext.J_sensor = ext.J_sensor.topRows(kPlanarDim).eval();
    ext.J_own = Eigen::MatrixXd(kPlanarDim, 0);
    ext.C_new = ext.C_new.topLeftCorner(kPlanarDim, kPlanarDim).eval();
  }
  return ext;
}

// 2 → 3: z from the newest elevation (ray_height and the file comment).
std::optional<Extension> PointFeature::extend_elevation(const SensorView& last_view) {
  if (observations_.empty()) return std::nullopt;
  const PointObservation& o = observations_.back();
  if (o.planar() || !taken_at(o.view, last_view)) return std::nullopt;
  const std::optional<RayHeight> h = ray_height(x_.head<2>(), o.v, o.view.x_ms);
  if (!h) return std::nullopt;
  Extension ext;
  ext.new_dims = 1;
  ext.sensor = o.view.sensor;
  ext.J_sensor = h->J_s;
  ext.J_own = h->J_xy;  // δx_p,old = (δx, δy): B̃ = [I₂ 0]ᵀ
  const Eigen::RowVector3d J_v_C = h->J_v * o.C_v;
  const double variance = J_v_C.dot(h->J_v);  // J_v C_v J_vᵀ
  if (!(variance > 0.0)) return std::nullopt;
  ext.C_new = Eigen::MatrixXd::Constant(1, 1, variance);
  x_[2] = h->z;
  feature_log(*this).debug("height ", h->z, " m (sigma ", std::sqrt(variance), ") from an elevation");
  return ext;
}

std::optional<Extension> PointFeature::extend_from_rays(const SensorView& last_view) {
  if (num_rays() < config_.min_rays || !taken_at(rays_.back().view, last_view)) return std::nullopt;
  const std::vector<Ray> rays = rays_of(rays_);
  if (max_parallax(rays) < degrees_to_radians(config_.min_parallax_deg)) return std::nullopt;
  const std::optional<Triangulation> t = triangulate(rays);
  if (!t || t->min_depth <= kMinRayDepth) return std::nullopt;
  // p = x_ms ⊕ p_s: δp = J_s δx_ms + R_ms δp_s, and R_ms δp_s has the
  // triangulation's covariance, so C_new = C_tri (B = I: δx_p = δp).
  const placement::Placement attached = attach_to_camera(t->point, last_view.x_ms);
  x_ = attached.x_f;
  feature_log(*this).debug("triangulated from ", rays.size(), " rays, parallax ",
                           max_parallax(rays) * 180.0 / std::numbers::pi, " deg, nearest depth ", t->min_depth, " m");
  return placement::full_extension(attached, to_camera_frame(attached, t->covariance), last_view.sensor);
}

// ---------------------------------------------------------------- PointType

std::vector<ParamSpec> PointType::param_specs() {
  const PointConfig d;
  return {
      param_int("min_observations", d.min_observations,
                "range/bearing/elevation: observations of a tentative point before it is initialised "
                "(the first ones only confirm it)",
                1.0),
      param_int("max_dense", d.max_dense,
                "range/bearing/elevation: most recent observations kept while tentative (≥ min_observations)",
                1.0),
      param_double("min_range_for_init", d.min_range_for_init,
                   "range/bearing/elevation: the initialising observation must be at least this far (m); "
                   "0 = no limit",
                   0.0),
      param_int("min_rays", d.min_rays, "bearings: rays of a tentative point before it can be triangulated", 2.0),
      param_int("max_rays", d.max_rays,
                "bearings: rays kept while tentative (≥ min_rays; the first ray is always kept)", 2.0),
      param_double("min_parallax_deg", d.min_parallax_deg,
                   "bearings: largest angle between two rays needed to triangulate (deg)", 0.1, 90.0),
      param_double("initial_depth", d.initial_depth,
                   "bearings: depth along the newest ray of a point not yet triangulated (m)", 0.01),
      param_double("initial_depth_sigma", d.initial_depth_sigma,
                   "bearings: std of that depth, which sets how far along the ray a tentative point "
                   "is matched (m)",
                   0.01),
      param_double("ray_spacing", d.ray_spacing,
                   "bearings: path distance between stored rays (m); closer rays replace the newest", 0.0),
  };
}

PointType::PointType(const PluginArgs& args) {
  const Params& p = args.params;
  config_.min_observations = static_cast<int>(p.get_int("min_observations"));
  config_.max_dense = static_cast<int>(p.get_int("max_dense"));
  config_.min_range_for_init = p.get_double("min_range_for_init");
  config_.min_rays = static_cast<int>(p.get_int("min_rays"));
  config_.max_rays = static_cast<int>(p.get_int("max_rays"));
  config_.min_parallax_deg = p.get_double("min_parallax_deg");
  config_.initial_depth = p.get_double("initial_depth");
  config_.initial_depth_sigma = p.get_double("initial_depth_sigma");
  config_.ray_spacing = p.get_double("ray_spacing");
  if (config_.max_dense < config_.min_observations) {
    throw std::invalid_argument("point: max_dense (" + std::to_string(config_.max_dense) +
                                ") must be at least min_observations (" +
                                std::to_string(config_.min_observations) +
                                "), or no point is ever initialised");
  }
  if (config_.max_rays < config_.min_rays) {
    throw std::invalid_argument("point: max_rays (" + std::to_string(config_.max_rays) +
                                ") must be at least min_rays (" + std::to_string(config_.min_rays) +
                                "), or no point is ever triangulated");
  }
}

const CoordLayout& PointType::layout() const { return point_layout(); }

std::vector<std::string> PointType::measurement_kinds() const {
  return {kRangeBearingElevation, kRangeBearing, kBearing3d};
}

std::unique_ptr<Feature> PointType::create(const Measurement& m, const SensorView& view) {
  if (is_usable_bearing(m)) return std::make_unique<PointFeature>(config_, m, view);
  if (!is_ranged_measurement(m)) return nullptr;
  const PointObservation o = observation_of(m, view);
  if (!is_placeable(o)) return nullptr;
  return std::make_unique<PointFeature>(config_, o);
}

// ---------------------------------------------------------------- conformance

std::optional<FeatureSample> PointType::sample(int dim, std::uint64_t seed) const {
  switch (dim) {
    case kTentativeDim:
    case kFullDim:
      // 0: extends to 3, never (one repeated bearing has no parallax), to 2.
      return seed % 3 == 0 ? range_bearing_sample(dim, seed, false)
             : seed % 3 == 1 ? bearing_sample(dim, seed)
                             : range_bearing_sample(dim, seed, true);
    case kPlanarDim:
      // Planar measurements, or an elevation that extends the point to 3.
      return range_bearing_sample(dim, seed, seed % 2 == 0);
    default:
      return std::nullopt;
  }
}

std::optional<FeatureSample> PointType::range_bearing_sample(int dim, std::uint64_t seed, bool planar) const {
  std::mt19937_64 rng(seed);
  FeatureSample s;
  s.x_ms = sample_pose(rng);
  const double r = draw(rng, 2, 8), b = draw(rng, -1.5, 1.5), e = draw(rng, -0.4, 0.4);
  // A planar sensor sees the point in its scan plane (a point elsewhere is
  // held at its own height, which a tilted sensor's planar innovation sees).
  const Eigen::Vector3d v(r, b, planar ? 0.0 : e);
  const Eigen::Vector3d sigma(0.05, 0.01, 0.02);  // the default range_bearing extractor's
  s.measurement.kind = planar ? kRangeBearing : kRangeBearingElevation;
  s.measurement.v = v.head(planar ? 2 : 3);
  s.measurement.C_v = sigma.head(planar ? 2 : 3).array().square().matrix().asDiagonal();
  if (dim == kTentativeDim) {
    s.feature = std::make_unique<PointFeature>(config_, observation_of(s.measurement, sample_view(s.x_ms)));
  } else {
    s.feature = std::make_unique<PointFeature>(config_, back_project(v, s.x_ms).x_f, dim);
  }
  return s;
}

std::optional<FeatureSample> PointType::bearing_sample(int dim, std::uint64_t seed) const {
  constexpr double kSigma = 0.002;  // rad: 0.5 px at a focal length of 250 px
  std::mt19937_64 rng(seed);
  FeatureSample s;
  s.x_ms = sample_pose(rng);
  const double off_axis = draw(rng, 0.0, 0.9), azimuth = draw(rng, -3.1, 3.1), depth = draw(rng, 1.5, 4.0);
  const Eigen::Vector3d b(std::sin(off_axis) * std::cos(azimuth), std::sin(off_axis) * std::sin(azimuth),
                          std::cos(off_axis));
  s.measurement.kind = kBearing3d;
  s.measurement.v = b;
  s.measurement.C_v = kSigma * kSigma * (Eigen::Matrix3d::Identity() - b * b.transpose());
  if (dim == 0) {
    s.feature = std::make_unique<PointFeature>(config_, s.measurement, sample_view(s.x_ms));
  } else {
    const Eigen::VectorXd p_s = depth * b;
    s.feature = std::make_unique<PointFeature>(config_, to_map_frame(point_layout(), p_s, s.x_ms), kDim);
  }
  return s;
}

std::unique_ptr<Feature> PointType::restore(const SavedFeature& saved) const {
  return std::make_unique<PointFeature>(config_, saved);
}

std::unique_ptr<Feature> PointType::from_true_shape(const TrueShape& shape, const Pose6& /*x_ms*/) const {
  if (shape.kind != TrueShape::Kind::Point) return nullptr;
  return std::make_unique<PointFeature>(config_, Eigen::Vector3d(shape.a), kDim);
}

}  // namespace mspace::point
