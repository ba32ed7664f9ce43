// pole_feature.cpp — see pole_feature.hpp.
#include "pole_feature.hpp"

#include <cmath>
#include <numbers>
#include <random>
#include <stdexcept>

#include "mspace/pose.hpp"
#include "mspace/placement.hpp"
#include "mspace/saved_state.hpp"

namespace mspace::pole {
namespace {

constexpr int kDim = 3;  ///< full M-space dimension = size of x_f
constexpr int kGatingCovEntries = kDim * kDim;
constexpr int kSaveVersion = 1;
constexpr int kDetectionRecord = 3 + 9 + saved::kViewSize;  ///< v, C_v, view

const CoordLayout& pole_layout() {
  static const CoordLayout layout{BlockKind::Scalar, BlockKind::Point2D};
  return layout;
}

bool is_pole_measurement(const Measurement& m) {
  return m.kind == kRangeBearingDiameter && m.v.size() == kDim && m.C_v.rows() == kDim &&
         m.C_v.cols() == kDim && m.v.allFinite() && m.C_v.allFinite();
}

/// A detection that can be placed: a defined bearing and a positive diameter.
bool is_placeable(const Eigen::Vector3d& v) { return v[0] >= kMinRange && v[2] > 0.0; }

placement::Placement back_project(const Eigen::Vector3d& v, const Pose6& x_ms) {
  Eigen::Matrix3d J_ov;
  const Eigen::Vector3d x_o = sensor_coords(v, &J_ov);
  return placement::place(pole_layout(), x_o, J_ov, x_ms);
}

}  // namespace

Eigen::Vector3d observe(const Eigen::Vector3d& x_o, Eigen::Matrix3d* J) {
  const double x = x_o[1], y = x_o[2];
  const double r2 = x * x + y * y;
  const double r = std::sqrt(r2);
  if (J != nullptr) {
    // Rows: ∂r = (0, x/r, y/r); ∂b = (0, −y/r², x/r²); ∂d = (2, 0, 0).
    *J << 0.0, x / r, y / r,  //
        0.0, -y / r2, x / r2,  //
        2.0, 0.0, 0.0;
  }
  return {r, std::atan2(y, x), 2.0 * x_o[0]};
}

Eigen::Vector3d sensor_coords(const Eigen::Vector3d& v, Eigen::Matrix3d* J) {
  const double r = v[0], c = std::cos(v[1]), s = std::sin(v[1]);
  if (J != nullptr) {
    // Columns: ∂/∂r, ∂/∂b, ∂/∂d.
    *J << 0.0, 0.0, 0.5,  //
        c, -r * s, 0.0,   //
        s, r * c, 0.0;
  }
  return {0.5 * v[2], r * c, r * s};
}

// ---------------------------------------------------------------- PoleFeature

PoleFeature::PoleFeature(const PoleConfig& config, const Eigen::Vector3d& v,
                         const Eigen::Matrix3d& C_v, const SensorView& view)
    : config_(config) {
  mdim_ = 0;
  place_at({v, C_v, view});
}

PoleFeature::PoleFeature(const PoleConfig& config, const Eigen::Vector3d& x_f, int mspace_dim,
                         int detections, const Eigen::Matrix3d& gating_cov)
    : config_(config), detections_(detections), gating_cov_(gating_cov) {
  x_ = x_f;
  mdim_ = mspace_dim;
}

const CoordLayout& PoleFeature::layout() const { return pole_layout(); }

// §IV-H: the M-space of a pole is radius and centre, B = I. A tentative pole
// has none: B is 0×3 and B̃ 3×0, so B B̃ = I₀ (eq. 12).
Eigen::MatrixXd PoleFeature::B() const { return Eigen::MatrixXd::Identity(mdim_, kDim); }

Eigen::MatrixXd PoleFeature::B_dual() const { return Eigen::MatrixXd::Identity(kDim, mdim_); }

void PoleFeature::apply_perturbation(const Eigen::VectorXd& dx_p) {
  if (dx_p.size() != mdim_)
    throw std::invalid_argument("pole: apply_perturbation got " + std::to_string(dx_p.size()) +
                                " values for M-space dimension " + std::to_string(mdim_));
  x_.head(mdim_) += dx_p;
}

// eq. 16: η(x_o, v) = h(x_o) − v, so J_ηo = ∂h/∂x_o and J_ηv = −I.
bool PoleFeature::innovation(const Eigen::VectorXd& x_o, const Measurement& m,
                             Innovation& out) const {
  if (!is_pole_measurement(m) || x_o.size() != kDim) return false;
  // hypot (correctly rounded, and a third of this function's instructions)
  // only near the threshold: with x² + y² ≥ (2 kMinRange)², rounded or not,
  // the range is far above kMinRange; NaN or an underflow goes to hypot as before.
  const double r2 = x_o[1] * x_o[1] + x_o[2] * x_o[2];
  if (!(r2 >= 4.0 * kMinRange * kMinRange) && std::hypot(x_o[1], x_o[2]) < kMinRange) return false;
  Eigen::Matrix3d J_ho;
  Eigen::Vector3d eta = observe(x_o, &J_ho) - m.v;
  eta[1] = wrap_angle(eta[1]);
  out.eta = eta;
  out.J_eta_o = J_ho;
  out.J_eta_v = -Eigen::MatrixXd::Identity(kDim, kDim);
  return true;
}

Eigen::MatrixXd PoleFeature::gating_covariance() const {
  if (mdim_ != 0) return {};
  return gating_cov_;
}

void PoleFeature::place_at(const PoleDetection& detection) {
  const placement::Placement p = back_project(detection.v, detection.view.x_ms);
  x_ = p.x_f;
  gating_cov_ = placement::covariance(p, detection.C_v, detection.view.C_ms);
  latest_ = detection;
}

void PoleFeature::add_dense_information(const Measurement& m, const SensorView& view) {
  if (!is_pole_measurement(m)) {
    throw std::invalid_argument("pole: add_dense_information got a measurement of kind '" + m.kind +
                                "' (expected '" + kRangeBearingDiameter +
                                "' with a 3-vector and a 3×3 covariance)");
  }
  if (mdim_ != 0) return;  // initialised: the estimator holds all there is to know
  ++detections_;
  if (is_placeable(m.v)) place_at({m.v, m.C_v, view});
}

SavedFeature PoleFeature::save() const {
  SavedFeature saved{x_, mdim_, {}, {}, kSaveVersion};
  if (mdim_ == 0) {
    saved.extra.resize(1 + kGatingCovEntries);
    saved.extra[0] = detections_;
    for (int i = 0; i < kGatingCovEntries; ++i) saved.extra[1 + i] = gating_cov_(i / kDim, i % kDim);
  }
  if (latest_) {
    Eigen::VectorXd record(kDetectionRecord);
    record.head<3>() = latest_->v;
    saved::put_matrix(record, 3, latest_->C_v);
    saved::put_view(record, 12, latest_->view);
    saved.put("latest", record);
  }
  return saved;
}

std::optional<Extension> PoleFeature::extend(const SensorView& last_view) {
  if (mdim_ != 0 || detections_ < config_.min_detections || !latest_) return std::nullopt;
  const PoleDetection& d = *latest_;
  const bool observed_now = d.view.t == last_view.t && d.view.sensor == last_view.sensor;
  if (!observed_now || !is_placeable(d.v) || d.v[0] < config_.min_range_for_init) return std::nullopt;
  // Standard EKF landmark initialisation with B = I: δx_p = J_s δx_ms + J_v δv.
  const placement::Placement p = back_project(d.v, d.view.x_ms);
  Extension ext = placement::full_extension(p, d.C_v, d.view.sensor);
  x_ = p.x_f;
  mdim_ = kDim;
  latest_.reset();
  return ext;
}

// ---------------------------------------------------------------- PoleType

std::vector<ParamSpec> PoleType::param_specs() {
  return {
      param_int("min_detections", 3,
                "consistent detections of a tentative pole before it is initialised from the newest",
                1.0),
      param_double("min_range_for_init", 0.0,
                   "the initialising detection must be at least this far (m); 0 = no limit", 0.0),
  };
}

PoleType::PoleType(const PluginArgs& args) {
  config_.min_detections = static_cast<int>(args.params.get_int("min_detections"));
  config_.min_range_for_init = args.params.get_double("min_range_for_init");
}

const CoordLayout& PoleType::layout() const { return pole_layout(); }

std::vector<std::string> PoleType::measurement_kinds() const { return {kRangeBearingDiameter}; }

std::unique_ptr<Feature> PoleType::create(const Measurement& m, const SensorView& view) {
  if (!is_pole_measurement(m)) return nullptr;
  const Eigen::Vector3d v = m.v;
  if (!is_placeable(v)) return nullptr;
  return std::make_unique<PoleFeature>(config_, v, m.C_v, view);
}

std::optional<FeatureSample> PoleType::sample(int dim, std::uint64_t seed) const {
  if (dim != 0 && dim != kDim) return std::nullopt;
  std::mt19937_64 rng(seed);
  auto uniform = [&rng](double lo, double hi) { return std::uniform_real_distribution<double>(lo, hi)(rng); };
  constexpr double kPi = std::numbers::pi;
  constexpr double kTilt = 0.2;  // rad: a sensor on a car on uneven ground

  FeatureSample s;
  s.x_ms = make_pose(uniform(-50, 50), uniform(-50, 50), uniform(-1, 1), uniform(-kPi, kPi),
                     uniform(-kTilt, kTilt), uniform(-kTilt, kTilt));
  s.measurement.kind = kRangeBearingDiameter;
  s.measurement.v = Eigen::Vector3d(uniform(2, 30), uniform(-kPi / 2, kPi / 2), uniform(0.1, 1.2));
  s.measurement.C_v = Eigen::Vector3d(0.1 * 0.1, 0.01 * 0.01, 0.05 * 0.05).asDiagonal();

  SensorView view;
  view.x_ms = s.x_ms;
  view.C_ms = Mat6::Identity() * 1e-4;
  if (dim == 0) {
    const Eigen::Vector3d v = s.measurement.v;
    const Eigen::Matrix3d C_v = s.measurement.C_v;
    s.feature = std::make_unique<PoleFeature>(config_, v, C_v, view);
    s.feature->add_dense_information(s.measurement, view);
  } else {
    const Eigen::Vector3d v = s.measurement.v;
    s.feature = restore(SavedFeature{back_project(v, s.x_ms).x_f, kDim, {}});
  }
  return s;
}

std::unique_ptr<Feature> PoleType::restore(const SavedFeature& saved) const {
  saved::expect_layout(saved, kSaveVersion, {"latest"}, "pole");
  if (saved.coords.size() != kDim || !saved.coords.allFinite())
    throw std::invalid_argument("pole: saved coordinates must be 3 finite numbers (radius, x, y)");
  if (saved.mspace_dim == kDim) {
    if (saved.extra.size() != 0 || !saved.arrays.empty())
      throw std::invalid_argument("pole: an initialised pole has no extra state");
    return std::make_unique<PoleFeature>(config_, saved.coords, kDim, 0, Eigen::Matrix3d::Zero());
  }
  if (saved.mspace_dim != 0 || saved.extra.size() != 1 + kGatingCovEntries || !saved.extra.allFinite())
    throw std::invalid_argument(
        "pole: saved state must be dimension 3, or dimension 0 with 10 extra numbers "
        "(detections, gating covariance)");
  Eigen::Matrix3d gating_cov;
  for (int i = 0; i < kGatingCovEntries; ++i) gating_cov(i / kDim, i % kDim) = saved.extra[1 + i];
  const double detections = saved.extra[0];
  if (!(detections >= 0.0 && detections <= 1e9 && std::floor(detections) == detections))
    throw std::invalid_argument("pole: the saved number of detections is not a non-negative integer");
  auto pole = std::make_unique<PoleFeature>(config_, saved.coords, 0, static_cast<int>(detections), gating_cov);
  const Eigen::MatrixXd latest = saved::records(saved, "latest", kDetectionRecord, "pole");
  if (latest.cols() > 1) throw std::invalid_argument("pole: at most one saved 'latest' detection");
  if (latest.cols() == 1) {
    const Eigen::VectorXd record = latest.col(0);
    pole->set_latest({record.head<3>(), saved::get_matrix(record, 3, 3, 3), saved::get_view(record, 12)});
  }
  return pole;
}

std::unique_ptr<Feature> PoleType::from_true_shape(const TrueShape& shape, const Pose6& /*x_ms*/) const {
  if (shape.kind != TrueShape::Kind::VerticalCylinder) return nullptr;
  return restore(SavedFeature{Eigen::Vector3d(shape.radius, shape.a.x(), shape.a.y()), kDim, {}});
}

}  // namespace mspace::pole
