// hline_feature.cpp — see hline_feature.hpp.
#include "hline_feature.hpp"

#include <Eigen/Dense>
#include <algorithm>
#include <cmath>
#include <limits>
#include <numbers>
#include <random>
#include <stdexcept>

#include <boost/math/distributions/chi_squared.hpp>

#include "mspace/pose.hpp"
#include "mspace/saved_state.hpp"
#include "mspace/transform.hpp"

namespace mspace::hline {
namespace {

const double kSqrt2 = std::numbers::sqrt2;
constexpr double kDegree = std::numbers::pi / 180.0;
/// Smallest height above the camera (m) at which plane weights are taken.
constexpr double kMinHeight = 0.1;
constexpr int kSaveVersion = 1;
/// The plane's c, C_c, o; the rays to the end points; the view.
constexpr int kObservationRecord = 3 + 9 + 3 + 3 + 3 + saved::kViewSize;

const CoordLayout& hline_layout() {
  static const CoordLayout layout{BlockKind::Point3D, BlockKind::Point3D};
  return layout;
}

bool is_line_measurement(const Measurement& m) {
  return m.kind == kCeilingLine && m.v.size() == kMeasurementSize && m.C_v.rows() == kMeasurementSize &&
         m.C_v.cols() == kMeasurementSize && m.v.allFinite() && m.C_v.allFinite();
}

Vec2 centre_of(const Vec6& x_f) { return 0.5 * (x_f.head<2>() + x_f.segment<2>(3)); }

/// The horizontal direction held by a plane, (−c_y, c_x), with the sense of
/// `like`; `like` itself when the plane is (nearly) horizontal.
Vec2 direction_in_plane(const Vec3& c, const Vec2& like) {
  const Vec2 t(-c.y(), c.x());
  if (!(t.norm() > 1e-9)) return like;
  return t.dot(like) < 0.0 ? Vec2(-t.normalized()) : Vec2(t.normalized());
}

/// The extent [lo, hi] along the line (point, z, t) of the closest points
/// of the observed end-point rays; empty when no ray gives one.
struct Extent {
  double lo = std::numeric_limits<double>::infinity();
  double hi = -std::numeric_limits<double>::infinity();
  void add(double s) {
    lo = std::min(lo, s);
    hi = std::max(hi, s);
  }
  bool valid() const { return hi - lo > 1e-6; }
};

Extent ray_extent(const std::deque<HLineObservation>& observations, const Vec3& point, const Vec3& dir) {
  Extent e;
  for (const HLineObservation& o : observations)
    for (const Vec3& ray : {o.ray_s, o.ray_e})
      if (const std::optional<double> s = ray_to_line(o.plane.o, ray, point, dir)) e.add(*s);
  return e;
}

/// C_v of the extractor (ceiling_lines.hpp): σ_perp normal to the segment
/// and σ_along along it at each end point, σ_f for the focal length.
Eigen::MatrixXd endpoint_covariance(const Eigen::VectorXd& v, double sigma_perp, double sigma_along, double sigma_f) {
  const Vec2 t = (v.segment<2>(2) - v.head<2>()).normalized(), n(-t.y(), t.x());
  const Mat2 C = sigma_perp * sigma_perp * n * n.transpose() + sigma_along * sigma_along * t * t.transpose();
  Eigen::MatrixXd C_v = Eigen::MatrixXd::Zero(kMeasurementSize, kMeasurementSize);
  C_v.block<2, 2>(0, 0) = C;
  C_v.block<2, 2>(2, 2) = C;
  C_v(4, 4) = sigma_f * sigma_f;
  return C_v;
}

/// The x with P(X ≤ x) = p for X ~ χ²(dof).
double chi2_quantile(double p, int dof) {
  return boost::math::quantile(boost::math::chi_squared(static_cast<double>(dof)), p);
}

}  // namespace

// ---------------------------------------------------------------- HLineFeature

HLineFeature::HLineFeature(const HLineConfig& config, const Vec6& x_f, int mspace_dim, const Vec2& anchor)
    : config_(config) {
  if (mspace_dim != 0 && mspace_dim != 1 && mspace_dim != 3)
    throw std::invalid_argument("hline: M-space dimension must be 0, 1 or 3 (got " + std::to_string(mspace_dim) + ")");
  if (!x_f.allFinite() || !anchor.allFinite()) throw std::invalid_argument("hline: non-finite coordinates or anchor");
  if (!(std::abs(x_f[2] - x_f[5]) <= 1e-9 * (1.0 + std::abs(x_f[2]))))
    throw std::invalid_argument("hline: the end points must be at the same height (the line is horizontal)");
  if (!((x_f.segment<2>(3) - x_f.head<2>()).norm() > 0.0)) throw std::invalid_argument("hline: zero length");
  x_ = x_f;
  x_[5] = x_[2];
  mdim_ = mspace_dim;
  anchor_ = foot_on_line(x_, anchor);
}

const CoordLayout& HLineFeature::layout() const { return hline_layout(); }

Eigen::MatrixXd HLineFeature::B() const { return hline_B(x_, mdim_, anchor_); }

Eigen::MatrixXd HLineFeature::B_dual() const { return hline_B_dual(x_, mdim_, anchor_); }

// Eqs. 19–22 after the checks that say the measurement cannot be this line.
bool HLineFeature::innovation(const Eigen::VectorXd& x_o, const Measurement& m, Innovation& out) const {
  if (!is_line_measurement(m) || x_o.size() != 6 || !x_o.allFinite()) return false;
  const std::optional<MeasuredLine> line = measured_line(m.v);
  if (!line) return false;
  const Vec3 p1 = x_o.head<3>(), p2 = x_o.tail<3>();
  if (!(p1.z() > 1e-6 && p2.z() > 1e-6)) return false;  // the camera looks up at its lines
  const double L = (p2 - p1).norm();
  if (!(L > 1e-9)) return false;
  const Vec3 dir = (p2 - p1) / L;
  const std::optional<double> s = ray_to_line(Vec3::Zero(), line->s, p1, dir);
  const std::optional<double> e = ray_to_line(Vec3::Zero(), line->e, p1, dir);
  if (!s || !e) return false;
  if (std::max(*s, *e) < -config_.match_margin || std::min(*s, *e) > L + config_.match_margin) return false;
  if (mdim_ < 3 && std::abs(line->c.dot((p1 + p2).normalized())) > std::sin(config_.match_angle))
    return false;  // the position is a guess: the plane must still pass near it
  line_innovation(x_o, *line, mdim_ == 3 ? 2 : 1, out);
  return true;
}

Eigen::MatrixXd HLineFeature::gating_covariance() const {
  if (mdim_ != 0) return {};
  return gating_cov_;
}

// Eq. 24. B̃ adds the same number to both heights; making them one number
// only removes rounding, so the line stays exactly horizontal.
void HLineFeature::apply_perturbation(const Eigen::VectorXd& dx_p) {
  Feature::apply_perturbation(dx_p);
  x_[2] = x_[5] = 0.5 * (x_[2] + x_[5]);
  anchor_ = foot_on_line(x_, anchor_);
}

void HLineFeature::add_dense_information(const Measurement& m, const SensorView& view) {
  if (!is_line_measurement(m))
    throw std::invalid_argument("hline: add_dense_information got a measurement of kind '" + m.kind +
                                "' (expected a finite '" + kCeilingLine + "' with 5 numbers and a 5×5 covariance)");
  const std::optional<MeasuredLine> line = measured_line(m.v);
  if (!line) throw std::invalid_argument("hline: degenerate ceiling_line measurement (v4 ≤ 0 or s ∥ e)");
  const Mat3 R = rotation(view.x_ms);
  HLineObservation obs;
  obs.plane = plane_in_map(*line, m.C_v, view.x_ms);
  obs.ray_s = R * line->s.normalized();
  obs.ray_e = R * line->e.normalized();
  obs.view = view;
  if (mdim_ < 3 && !consistent_with_stored(obs.plane)) return;  // a parallel neighbour's plane, most likely
  observations_.push_back(obs);
  prune(view.path_distance);

  const LineGeometry g = line_geometry(x_);
  if (mdim_ == 0)
    follow_latest(direction_in_plane(obs.plane.c, g.t));
  else if (mdim_ == 1)
    follow_latest(g.t);
  else
    x_ = line_at(g.p1.head<2>(), g.t, g.z, true);  // slide the ends only
}

void HLineFeature::prune(double path_distance) {
  while (observations_.size() > 1 &&
         (path_distance - observations_.front().view.path_distance > config_.max_path_distance ||
          static_cast<int>(observations_.size()) > config_.max_observations))
    observations_.pop_front();
}

double HLineFeature::baseline(const Vec2& n) const {
  double lo = std::numeric_limits<double>::infinity(), hi = -lo;
  for (const HLineObservation& o : observations_) {
    lo = std::min(lo, n.dot(o.plane.o.head<2>()));
    hi = std::max(hi, n.dot(o.plane.o.head<2>()));
  }
  return hi - lo;
}

InverseHeightPrior HLineFeature::height_prior() const {
  return {1.0 / config_.initial_height, config_.inverse_height_sigma};
}

std::optional<RayEstimate> HLineFeature::estimate_from(const LineGeometry& g, const Vec3& q, const Vec3& at) const {
  const std::vector<PlaneObservation> stored = planes();
  const double rho = 1.0 / std::max(at.z() - q.z(), kMinHeight);
  return estimate_ray(stored, plane_weights(stored, g.t, at), g.t, q, rho, height_prior());
}

std::optional<RayEstimate> HLineFeature::estimate_from_newest(const LineGeometry& g, Vec3& at) const {
  const Vec3 q = observations_.back().plane.o;
  const std::optional<RayEstimate> first = estimate_from(g, q, Vec3(anchor_.x(), anchor_.y(), g.z));
  if (!first || !(first->x[1] > 0.0)) return std::nullopt;  // the line must be above the camera
  at = ray_point(*first, g.t, q);
  const std::optional<RayEstimate> e = estimate_from(g, q, at);
  if (!e || !(e->x[1] > 0.0)) return std::nullopt;
  at = ray_point(*e, g.t, q);
  return e;
}

// Seen from the new plane's camera centre q, the stored planes and the prior
// give the slope and inverse height of the ray to the line; the new plane,
// through q, must hold that ray: a test of its angle, whatever the height.
bool HLineFeature::consistent_with_stored(const PlaneObservation& plane) const {
  if (observations_.empty()) return true;
  const LineGeometry g = line_geometry(x_);
  const Vec3 at(anchor_.x(), anchor_.y(), g.z);
  const std::optional<RayEstimate> e = estimate_from(g, plane.o, at);
  if (!e) return true;  // nothing to test against (e.g. horizontal planes)
  const double rho = 1.0 / std::max(g.z - plane.o.z(), kMinHeight);
  const double w = plane_weights({plane}, g.t, at)[0];
  return plane_chi2(plane, w, g.t, plane.o, rho, *e) <= chi2_quantile(config_.consistency_probability, 1);
}

bool HLineFeature::residuals_agree(const LineGeometry& g) {
  Vec3 at;
  const std::optional<RayEstimate> e = estimate_from_newest(g, at);
  if (!e) return false;
  if (e->rows <= 2 || e->chi2 <= chi2_quantile(config_.consistency_probability, e->rows - 2)) return true;
  const auto worst = std::max_element(e->deleted_chi2.begin(), e->deleted_chi2.end());
  observations_.erase(observations_.begin() + (worst - e->deleted_chi2.begin()));
  return false;
}

bool HLineFeature::views_agree(const LineGeometry& g) {
  Vec3 at;
  const std::optional<RayEstimate> e = estimate_from_newest(g, at);
  if (!e) return false;
  const std::vector<PlaneObservation> stored = planes();
  const SplitTest split = split_test(stored, plane_weights(stored, g.t, at), g.t, observations_.back().plane.o,
                                     e->x[1], height_prior());
  if (split.chi2 <= chi2_quantile(config_.consistency_probability, 2)) return true;
  std::vector<bool> drop(observations_.size(), false);
  for (std::size_t i : split.smaller) drop[i] = true;
  std::deque<HLineObservation> kept;
  for (std::size_t i = 0; i < observations_.size(); ++i)
    if (!drop[i]) kept.push_back(observations_[i]);
  observations_ = std::move(kept);
  return false;
}

// (c) σ_z ≤ max_height_sigma (z − z_camera); (d) the largest gap between the
// viewing rays' angles ≤ max_ray_gap times their span.
bool HLineFeature::well_conditioned(const LineGeometry& g, const Vec2& point, double z, const Mat2& cov) const {
  const double height = z - observations_.back().plane.o.z();
  if (!(std::sqrt(cov(1, 1)) <= config_.max_height_sigma * height)) return false;
  const RaySpread rays = ray_spread(planes(), g.t, Vec3(point.x(), point.y(), z));
  return rays.largest_gap <= config_.max_ray_gap * rays.span;
}

std::vector<PlaneObservation> HLineFeature::planes() const {
  std::vector<PlaneObservation> out;
  out.reserve(observations_.size());
  for (const HLineObservation& o : observations_) out.push_back(o.plane);
  return out;
}

Vec6 HLineFeature::line_at(const Vec2& point, const Vec2& t, double z, bool grow) const {
  const Extent rays = ray_extent(observations_, Vec3(point.x(), point.y(), z), horizontal(t));
  Extent e;
  if (grow || !rays.valid()) {  // the current ends, projected onto this line
    e.add(t.dot(x_.head<2>() - point));
    e.add(t.dot(x_.segment<2>(3) - point));
  }
  if (rays.valid()) {
    e.add(rays.lo);
    e.add(rays.hi);
  }
  return make_line(point, t, z, e.lo, e.hi);
}

// Dims 0, 1: the position is not in the M-space, so the line moves onto the
// newest plane at the guessed height (a translation and sliding ends: B is
// unchanged). At dim 0 the direction follows too and the gating covariance
// is the direction's variance from that observation and the sensor pose.
void HLineFeature::follow_latest(const Vec2& t) {
  const HLineObservation& latest = observations_.back();
  const double z = latest.plane.o.z() + config_.initial_height;
  const std::optional<Vec2> point = point_in_plane(latest.plane, t, z);
  if (!point) return;
  x_ = line_at(*point, t, z, false);
  if (mdim_ != 0) {
    anchor_ = foot_on_line(x_, anchor_);
    return;
  }
  anchor_ = centre_of(x_);
  const std::vector<PlaneObservation> plane = {latest.plane};
  const DirectionFit fit = fit_direction(plane, direction_weights(plane), t, latest.view.x_ms);
  const double var_alpha = fit.variance + (fit.J_pose * latest.view.C_ms * fit.J_pose.transpose())(0, 0);
  const Eigen::MatrixXd Bd = hline_B_dual(x_, 1, anchor_);  // δα = √2 δ1
  gating_cov_ = Bd * (0.5 * var_alpha) * Bd.transpose();
}

Eigen::MatrixXd HLineFeature::symmetry_directions() const {
  const LineGeometry g = line_geometry(x_);
  Eigen::MatrixXd dirs = Eigen::MatrixXd::Zero(6, mdim_ == 3 ? 2 : 4);
  dirs.block<2, 1>(0, 0) = g.t;
  dirs.block<2, 1>(3, 1) = g.t;
  if (mdim_ != 3) {
    dirs.block<2, 1>(0, 2) = dirs.block<2, 1>(3, 2) = g.n;
    dirs(2, 3) = dirs(5, 3) = 1.0;
  }
  return dirs;
}

std::optional<double> HLineFeature::footprint_radius() const { return 0.5 * line_geometry(x_).L; }

std::optional<FeatureDrawing> HLineFeature::drawing() const {
  if (mdim_ != 1) return std::nullopt;
  const Vec2 t = (x_.segment<2>(3) - x_.head<2>()).normalized();
  // Without a stored observation (not reached by a line that extended to
  // dim 1, which keeps the planes it extended from) the anchor stands in.
  const Vec2 seen_from = observations_.empty() ? anchor_ : Vec2(observations_.back().plane.o.head<2>());
  return FeatureDrawing{{direction_item(seen_from, std::atan2(t.y(), t.x()))}};
}

SavedFeature HLineFeature::save() const {
  SavedFeature s{x_, mdim_, anchor_, {}, kSaveVersion};
  if (!observations_.empty()) {
    Eigen::MatrixXd records(kObservationRecord, static_cast<Eigen::Index>(observations_.size()));
    for (Eigen::Index i = 0; i < records.cols(); ++i) {
      const HLineObservation& o = observations_[static_cast<std::size_t>(i)];
      auto col = records.col(i);
      col.segment<3>(0) = o.plane.c;
      saved::put_matrix(col, 3, o.plane.C_c);
      col.segment<3>(12) = o.plane.o;
      col.segment<3>(15) = o.ray_s;
      col.segment<3>(18) = o.ray_e;
      saved::put_view(col, 21, o.view);
    }
    s.put("observations", records);
  }
  if (mdim_ == 0) s.put("gating_covariance", gating_cov_);
  return s;
}

void HLineFeature::set_saved_state(const Vec2& anchor, std::deque<HLineObservation> observations,
                                   const Eigen::Matrix<double, 6, 6>& gating_cov) {
  anchor_ = anchor;
  observations_ = std::move(observations);
  gating_cov_ = gating_cov;
}

std::optional<Extension> HLineFeature::extend(const SensorView& last_view) {
  if (observations_.empty() || mdim_ == 3) return std::nullopt;
  const SensorView& latest = observations_.back().view;
  if (latest.t != last_view.t || latest.sensor != last_view.sensor) return std::nullopt;
  return mdim_ == 0 ? extend_direction() : extend_position();
}

// 0 → 1: the weighted mean direction of the stored planes (eq. 17's M-space).
// δx_p = δα/√2, so J_sensor = J_α,pose/√2 and C_new = Var(α)/2.
std::optional<Extension> HLineFeature::extend_direction() {
  if (num_observations() < config_.min_observations) return std::nullopt;
  const HLineObservation& latest = observations_.back();
  const std::vector<PlaneObservation> obs = planes();
  const DirectionFit fit = fit_direction(obs, direction_weights(obs), line_geometry(x_).t, latest.view.x_ms);
  if (!(fit.spread <= config_.max_direction_spread) || !std::isfinite(fit.variance)) return std::nullopt;

  mdim_ = 1;
  gating_cov_.setZero();
  follow_latest(direction(fit.alpha));
  anchor_ = centre_of(x_);  // eq. 17 about the centre at this moment
  Extension ext;
  ext.new_dims = 1;
  ext.sensor = latest.view.sensor;
  ext.J_sensor = fit.J_pose / kSqrt2;
  ext.J_own = Eigen::MatrixXd(1, 0);
  ext.C_new = Eigen::MatrixXd::Constant(1, 1, 0.5 * fit.variance);
  return ext;
}

// 1 → 3: triangulation (eq. 21's offset and height), once the planes are
// one line (tests (a), (b): residuals_agree, views_agree) seen well enough
// (tests (c), (d): well_conditioned; see hline_feature.hpp). The least
// squares is solved about the anchor, the ends placed on the result, and
// solved again about their centre with weights at the solution; that second
// fit gives the new M-space coordinates √2 (o, z) at the new anchor:
// C_new = 2 cov, J_sensor = √2 ∂(o, z)/∂x_ms and, with δα = √2 δ1,
// J_own = 2 ∂(o, z)/∂α.
std::optional<Extension> HLineFeature::extend_position() {
  const LineGeometry g = line_geometry(x_);
  if (!(baseline(g.n) >= config_.min_baseline)) return std::nullopt;
  if (!residuals_agree(g) || !views_agree(g) || !(baseline(g.n) >= config_.min_baseline)) return std::nullopt;

  const HLineObservation& latest = observations_.back();
  const Pose6& x_ms = latest.view.x_ms;
  const std::vector<PlaneObservation> obs = planes();
  const std::optional<PositionFit> first =
      fit_position(obs, plane_weights(obs, g.t, Vec3(anchor_.x(), anchor_.y(), g.z)), g.t, anchor_, x_ms);
  if (!first || !(first->x[1] > latest.plane.o.z())) return std::nullopt;  // the line is above the camera
  const Vec2 centre = centre_of(line_at(anchor_ + first->x[0] * g.n, g.t, first->x[1], false));
  const std::vector<double> weights = plane_weights(obs, g.t, Vec3(centre.x(), centre.y(), first->x[1]));
  const std::optional<PositionFit> fit = fit_position(obs, weights, g.t, centre, x_ms);
  if (!fit || !(fit->x[1] > latest.plane.o.z())) return std::nullopt;
  const Vec2 point = centre + fit->x[0] * g.n;
  if (!well_conditioned(g, point, fit->x[1], fit->cov)) return std::nullopt;

  x_ = line_at(point, g.t, fit->x[1], false);
  anchor_ = foot_on_line(x_, point);
  mdim_ = 3;
  Extension ext;
  ext.new_dims = 2;
  ext.sensor = latest.view.sensor;
  ext.J_sensor = kSqrt2 * fit->J_pose;
  ext.J_own = 2.0 * fit->J_alpha;
  ext.C_new = 2.0 * 0.5 * (fit->cov + fit->cov.transpose());
  return ext;
}

// ---------------------------------------------------------------- HLineType

std::vector<ParamSpec> HLineType::param_specs() {
  const HLineConfig d;
  return {
      param_int("min_observations", d.min_observations,
                "observations whose directions agree before the direction enters the M-space", 1.0),
      param_double("max_direction_spread_deg", d.max_direction_spread / kDegree,
                   "largest deviation of an observation's direction from their mean for it to enter (deg)", 0.0,
                   90.0),
      param_double("initial_height", d.initial_height,
                   "guessed height above the camera of a line whose position is not yet triangulated (m)", 0.01),
      param_double("min_baseline", d.min_baseline,
                   "spread of the camera centres normal to the line before its position is triangulated (m)", 0.0),
      param_double("max_path_distance", d.max_path_distance,
                   "dense information older than this much path distance is pruned (m)", 0.0),
      param_int("max_observations", d.max_observations, "most observations kept as dense information", 1.0),
      param_double("match_angle_deg", d.match_angle / kDegree,
                   "while the position is a guess, largest angle between a measured plane and the line's centre (deg)",
                   0.0, 90.0),
      param_double("match_margin", d.match_margin,
                   "a segment must overlap the line, give or take this much, to match it (m)", 0.0),
      param_double("consistency_probability", d.consistency_probability,
                   "probability of the χ² tests that the planes are one line (a new plane at dims 0, 1 against the "
                   "stored ones; all of them, and the cameras either side of each cut, before triangulation)",
                   0.5, 1.0 - 1e-12),
      param_double("inverse_height_sigma", d.inverse_height_sigma,
                   "σ of the prior 1/initial_height on a line's inverse height above the camera in the tests of the "
                   "planes (1/m)",
                   0.001),
      param_double("max_height_sigma", d.max_height_sigma,
                   "largest σ of the triangulated height, as a fraction of the height above the camera", 0.0),
      param_double("max_ray_gap", d.max_ray_gap,
                   "largest gap between the viewing rays' angles (normal to the line), as a fraction of their span, "
                   "for the triangulation to enter",
                   0.0, 1.0),
  };
}

HLineType::HLineType(const PluginArgs& args) {
  const Params& p = args.params;
  config_.min_observations = static_cast<int>(p.get_int("min_observations"));
  config_.max_direction_spread = p.get_double("max_direction_spread_deg") * kDegree;
  config_.initial_height = p.get_double("initial_height");
  config_.min_baseline = p.get_double("min_baseline");
  config_.max_path_distance = p.get_double("max_path_distance");
  config_.max_observations = static_cast<int>(p.get_int("max_observations"));
  config_.match_angle = p.get_double("match_angle_deg") * kDegree;
  config_.match_margin = p.get_double("match_margin");
  config_.consistency_probability = p.get_double("consistency_probability");
  config_.inverse_height_sigma = p.get_double("inverse_height_sigma");
  config_.max_height_sigma = p.get_double("max_height_sigma");
  config_.max_ray_gap = p.get_double("max_ray_gap");
  if (config_.max_observations < config_.min_observations)
    throw std::invalid_argument("hline: max_observations (" + std::to_string(config_.max_observations) +
                                ") must be at least min_observations (" + std::to_string(config_.min_observations) +
                                "), or no direction is ever initialised");
}

const CoordLayout& HLineType::layout() const { return hline_layout(); }

std::vector<std::string> HLineType::measurement_kinds() const { return {kCeilingLine}; }

std::unique_ptr<Feature> HLineType::create(const Measurement& m, const SensorView& view) {
  if (!is_line_measurement(m)) return nullptr;
  const std::optional<MeasuredLine> line = measured_line(m.v);
  if (!line) return nullptr;
  const PlaneObservation plane = plane_in_map(*line, m.C_v, view.x_ms);
  const Vec2 t = direction_in_plane(plane.c, Vec2::UnitX());
  const double z = plane.o.z() + config_.initial_height;
  const std::optional<Vec2> point = point_in_plane(plane, t, z);
  if (!point) return nullptr;
  const Mat3 R = rotation(view.x_ms);
  const Vec3 P(point->x(), point->y(), z), T = horizontal(t);
  const std::optional<double> s = ray_to_line(plane.o, R * line->s, P, T);
  const std::optional<double> e = ray_to_line(plane.o, R * line->e, P, T);
  if (!s || !e || !(std::abs(*e - *s) > 1e-6)) return nullptr;
  const Vec6 x_f = make_line(*point, t, z, std::min(*s, *e), std::max(*s, *e));
  return std::make_unique<HLineFeature>(config_, x_f, 0, centre_of(x_f));
}

Eigen::VectorXd project_line(const Vec6& x_f, const Pose6& x_ms, double f) {
  const Eigen::VectorXd x_o = to_sensor_frame(hline_layout(), x_f, x_ms);
  Eigen::VectorXd v(kMeasurementSize);
  v << f * x_o[0] / x_o[2], f * x_o[1] / x_o[2], f * x_o[3] / x_o[5], f * x_o[4] / x_o[5], f;
  if (v[2] < v[0] || (v[2] == v[0] && v[3] < v[1])) {  // start = the smaller v0 (ceiling_lines.hpp)
    std::swap(v[0], v[2]);
    std::swap(v[1], v[3]);
  }
  return v;
}

std::optional<FeatureSample> HLineType::sample(int dim, std::uint64_t seed) const {
  if (dim != 0 && dim != 1 && dim != 3) return std::nullopt;
  std::mt19937_64 rng(seed);
  auto uniform = [&](double lo, double hi) { return std::uniform_real_distribution<double>(lo, hi)(rng); };
  const Vec2 centre(uniform(-5.0, 5.0), uniform(-5.0, 5.0));
  const Vec2 t = direction(uniform(-std::numbers::pi, std::numbers::pi));
  const double L = uniform(1.0, 3.0), camera_z = uniform(0.0, 1.0), z = camera_z + uniform(1.5, 2.5);
  const Vec6 x_f = make_line(centre, t, z, -0.5 * L, 0.5 * L);
  const Vec2 camera = centre + uniform(-0.8, 0.8) * normal_of(t) + uniform(-0.25 * L, 0.25 * L) * t;

  FeatureSample out;
  out.x_ms = make_pose(camera.x(), camera.y(), camera_z, uniform(-std::numbers::pi, std::numbers::pi),
                       uniform(-0.15, 0.15), uniform(-0.15, 0.15));
  out.feature = std::make_unique<HLineFeature>(config_, x_f, dim, centre);
  Measurement& m = out.measurement;
  m.kind = kCeilingLine;
  m.v = project_line(x_f, out.x_ms, 500.0);
  m.C_v = endpoint_covariance(m.v, 1.0, 5.0, 1.0);
  return out;
}

std::optional<SampleObservation> HLineType::sample_observation(int dim, std::uint64_t seed, int k) const {
  std::optional<FeatureSample> s = sample(dim, seed);
  if (!s) return std::nullopt;
  const Vec6 x_f = s->feature->coords();
  const Vec2 t = (x_f.segment<2>(3) - x_f.head<2>()).normalized();
  const double step = 0.13 * (k - 1);  // never exactly at min_baseline
  SampleObservation o;
  o.x_ms = s->x_ms;
  o.x_ms.head<2>() += step * normal_of(t);
  o.path_distance = step;
  o.measurement = s->measurement;
  o.measurement.v = project_line(x_f, o.x_ms, 500.0);
  o.measurement.C_v = endpoint_covariance(o.measurement.v, 1.0, 5.0, 1.0);
  return o;
}

std::unique_ptr<Feature> HLineType::from_true_shape(const TrueShape& shape, const Pose6& /*x_ms*/) const {
  if (shape.kind != TrueShape::Kind::Segment) return nullptr;
  // Horizontal within the constructor's tolerance; a sloped segment is no hline.
  if (!(std::abs(shape.a.z() - shape.b.z()) <= 1e-9 * (1.0 + std::abs(shape.a.z())))) return nullptr;
  if (!((shape.b - shape.a).head<2>().norm() > 0.0)) return nullptr;
  Vec6 x_f;
  x_f << shape.a, shape.b;
  return std::make_unique<HLineFeature>(config_, x_f, 3, Vec2(0.5 * (shape.a + shape.b).head<2>()));
}

std::unique_ptr<Feature> HLineType::restore(const SavedFeature& saved) const {
  if (saved.coords.size() != 6 || saved.extra.size() != 2)
    throw std::invalid_argument("hline: saved state must hold 6 coordinates and the anchor (x, y) (got " +
                                std::to_string(saved.coords.size()) + " and " + std::to_string(saved.extra.size()) +
                                ")");
  saved::expect_layout(saved, kSaveVersion, {"observations", "gating_covariance"}, "hline");
  auto line = std::make_unique<HLineFeature>(config_, Vec6(saved.coords), saved.mspace_dim, Vec2(saved.extra));
  if (saved.version == 0) return line;  // no dense information; the anchor is projected onto the line
  // Version 1: the anchor as saved (it is on the line already: projecting it
  // again could move it by a rounding error), the observations and the
  // gating covariance.
  const Eigen::MatrixXd records = saved::records(saved, "observations", kObservationRecord, "hline");
  std::deque<HLineObservation> observations;
  for (Eigen::Index i = 0; i < records.cols(); ++i) {
    const Eigen::VectorXd col = records.col(i);
    HLineObservation o;
    o.plane.c = col.segment<3>(0);
    o.plane.C_c = saved::get_matrix(col, 3, 3, 3);
    o.plane.o = col.segment<3>(12);
    o.ray_s = col.segment<3>(15);
    o.ray_e = col.segment<3>(18);
    o.view = saved::get_view(col, 21);
    observations.push_back(o);
  }
  const Eigen::Matrix<double, 6, 6> gating =
      saved::fixed(saved, "gating_covariance", 6, 6, Eigen::MatrixXd::Zero(6, 6), "hline");
  line->set_saved_state(Vec2(saved.extra), std::move(observations), gating);
  return line;
}

}  // namespace mspace::hline
