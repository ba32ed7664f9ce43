// point_feature.cpp — see point_feature.hpp.
#include "point_feature.hpp"

#include <Eigen/Dense>
#include <cmath>
#include <random>
#include <stdexcept>

#include "mspace/pose.hpp"
#include "mspace/transform.hpp"

namespace mspace::point {
namespace {

constexpr int kDim = 3;  ///< full M-space dimension = size of x_f

const CoordLayout& point_layout() {
  static const CoordLayout layout{BlockKind::Point3D};
  return layout;
}

/// Distance of a sensor-frame point from the sensor's z axis, √(x² + y²).
double axis_distance(const Eigen::Vector3d& p) { return std::hypot(p.x(), p.y()); }

/// A well-formed measurement of the kind a point understands.
bool is_point_measurement(const Measurement& m) {
  return m.kind == kRangeBearingElevation && m.v.size() == kDim && m.C_v.rows() == kDim &&
         m.C_v.cols() == kDim && m.v.allFinite() && m.C_v.allFinite();
}

/// Can v be back-projected to a point with a defined bearing (a positive
/// range, away from the sensor's z axis)?
bool is_placeable(const Eigen::Vector3d& v) {
  return v[0] > 0.0 && axis_distance(spherical_to_cartesian(v)) >= kMinAxisDistance;
}

}  // namespace

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

// ---------------------------------------------------------------- PointFeature

PointFeature::PointFeature(const PointConfig& config, const Eigen::Vector3d& v,
                           const Eigen::Matrix3d& C_v, const SensorView& view)
    : config_(config) {
  mdim_ = 0;
  place_at(v, C_v, view);
}

PointFeature::PointFeature(const PointConfig& config, const Eigen::Vector3d& x_f, int mspace_dim)
    : config_(config) {
  x_ = x_f;
  mdim_ = mspace_dim;
}

const CoordLayout& PointFeature::layout() const { return point_layout(); }

// Table II: the M-space of a point is the point itself, B = I. A tentative
// point has no M-space: B is 0×3 and B̃ 3×0, so B B̃ = I₀ (eq. 12) holds too.
Eigen::MatrixXd PointFeature::B() const { return Eigen::MatrixXd::Identity(mdim_, kDim); }

Eigen::MatrixXd PointFeature::B_dual() const { return Eigen::MatrixXd::Identity(kDim, mdim_); }

// eq. 16: η(x_o, v) = h(x_o) − v, so J_ηo = ∂h/∂x_o and J_ηv = −I.
bool PointFeature::innovation(const Eigen::VectorXd& x_o, const Measurement& m,
                              Innovation& out) const {
  if (!is_point_measurement(m) || x_o.size() != kDim) return false;
  const Eigen::Vector3d p = x_o;
  if (axis_distance(p) < kMinAxisDistance) return false;
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
  if (mdim_ != 0) return {};
  return gating_cov_;
}

void PointFeature::place_at(const Eigen::Vector3d& v, const Eigen::Matrix3d& C_v,
                            const SensorView& view) {
  const placement::Placement bp = back_project(v, view.x_ms);
  x_ = bp.x_f;
  // First-order covariance of x_f = g(v, x_ms) with v and x_ms independent.
  gating_cov_ = placement::covariance(bp, C_v, view.C_ms);
}

void PointFeature::add_dense_information(const Measurement& m, const SensorView& view) {
  if (!is_point_measurement(m)) {
    throw std::invalid_argument("point: add_dense_information got a measurement of kind '" +
                                m.kind + "' (expected '" + kRangeBearingElevation +
                                "' with a 3-vector and a 3×3 covariance)");
  }
  if (mdim_ != 0) return;  // initialised: the estimator holds all there is to know
  observations_.push_back({m.v, m.C_v, view});
  while (static_cast<int>(observations_.size()) > config_.max_dense) observations_.pop_front();
  place_at(m.v, m.C_v, view);
}

std::optional<Extension> PointFeature::extend(const SensorView& last_view) {
  if (mdim_ != 0 || num_observations() < config_.min_observations) return std::nullopt;
  const PointObservation& latest = observations_.back();
  const bool observed_now = latest.view.t == last_view.t && latest.view.sensor == last_view.sensor;
  if (!observed_now || latest.v[0] < config_.min_range_for_init || !is_placeable(latest.v)) {
    return std::nullopt;
  }
  // Standard EKF landmark initialisation: δx_f = J_s δx_ms + J_v δv, and with
  // B = I the new M-space perturbations are δx_f itself.
  const placement::Placement bp = back_project(latest.v, latest.view.x_ms);
  Extension ext = placement::full_extension(bp, latest.C_v, latest.view.sensor);
  x_ = bp.x_f;
  mdim_ = kDim;
  observations_.clear();
  return ext;
}

// ---------------------------------------------------------------- PointType

std::vector<ParamSpec> PointType::param_specs() {
  return {
      param_int("min_observations", 3,
                "observations of a tentative point before it is initialised (the first ones "
                "only confirm it)",
                1.0),
      param_int("max_dense", 10,
                "most recent observations kept while tentative (≥ min_observations)", 1.0),
      param_double("min_range_for_init", 0.0,
                   "the initialising observation must be at least this far (m); 0 = no limit", 0.0),
  };
}

PointType::PointType(const PluginArgs& args) {
  config_.min_observations = static_cast<int>(args.params.get_int("min_observations"));
  config_.max_dense = static_cast<int>(args.params.get_int("max_dense"));
  config_.min_range_for_init = args.params.get_double("min_range_for_init");
  if (config_.max_dense < config_.min_observations) {
    throw std::invalid_argument("point: max_dense (" + std::to_string(config_.max_dense) +
                                ") must be at least min_observations (" +
                                std::to_string(config_.min_observations) +
                                "), or no point is ever initialised");
  }
}

const CoordLayout& PointType::layout() const { return point_layout(); }

std::vector<std::string> PointType::measurement_kinds() const { return {kRangeBearingElevation}; }

std::unique_ptr<Feature> PointType::create(const Measurement& m, const SensorView& view) {
  if (!is_point_measurement(m)) return nullptr;
  const Eigen::Vector3d v = m.v;
  if (!is_placeable(v)) return nullptr;
  return std::make_unique<PointFeature>(config_, v, m.C_v, view);
}

// ---------------------------------------------------------------- conformance

std::optional<FeatureSample> PointType::sample(int dim, std::uint64_t seed) const {
  if (dim != 0 && dim != kDim) return std::nullopt;
  std::mt19937_64 rng(seed);
  auto uniform = [&rng](double lo, double hi) { return std::uniform_real_distribution<double>(lo, hi)(rng); };
  FeatureSample s;
  s.x_ms = make_pose(uniform(-10, 10), uniform(-10, 10), uniform(0, 1), uniform(-3, 3), uniform(-0.2, 0.2),
                     uniform(-0.2, 0.2));
  const Eigen::Vector3d v(uniform(2, 8), uniform(-1.5, 1.5), uniform(-0.4, 0.4));
  s.measurement.kind = kRangeBearingElevation;
  s.measurement.v = v;
  s.measurement.C_v = Eigen::Vector3d(0.05 * 0.05, 0.01 * 0.01, 0.02 * 0.02).asDiagonal();
  if (dim == 0) {
    SensorView view;
    view.x_ms = s.x_ms;
    view.C_ms = Mat6::Identity() * 1e-4;
    s.feature = std::make_unique<PointFeature>(config_, v, s.measurement.C_v, view);
  } else {
    s.feature = std::make_unique<PointFeature>(config_, back_project(v, s.x_ms).x_f, kDim);
  }
  return s;
}

std::unique_ptr<Feature> PointType::restore(const SavedFeature& saved) const {
  if (saved.coords.size() != kDim || !saved.coords.allFinite() || (saved.mspace_dim != 0 && saved.mspace_dim != kDim) ||
      saved.extra.size() != 0) {
    throw std::invalid_argument("point: restore needs 3 finite coordinates, dimension 0 or 3 and no extra state (got " +
                                std::to_string(saved.coords.size()) + " coordinates, dimension " +
                                std::to_string(saved.mspace_dim) + ")");
  }
  return std::make_unique<PointFeature>(config_, Eigen::Vector3d(saved.coords), saved.mspace_dim);
}

}  // namespace mspace::point
