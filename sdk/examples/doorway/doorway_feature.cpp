// doorway_feature.cpp — see doorway_feature.hpp.
#include "doorway_feature.hpp"

#include <Eigen/Dense>
#include <cmath>
#include <random>
#include <stdexcept>
#include <string>

#include "mspace/feature_log.hpp"
#include "mspace/numeric.hpp"
#include "mspace/pose.hpp"
#include "mspace/saved_state.hpp"
#include "mspace/transform.hpp"

namespace doorway {
namespace {

using mspace::BlockKind;
using mspace::CoordLayout;
using mspace::Extension;
using mspace::Measurement;
using mspace::SensorView;

constexpr int kSize = 4;  ///< x_f = (p1, p2)
constexpr int kSaveVersion = 1;
constexpr int kObservationRecord = 4 + 16 + mspace::saved::kViewSize;  ///< v, C_v, view

const CoordLayout& doorway_layout() {
  static const CoordLayout layout{BlockKind::Point2D, BlockKind::Point2D};
  return layout;
}

/// The doorway's derived quantities: centre, orientation, width, u and u⊥.
struct Geometry {
  Eigen::Vector2d c, u, n;
  double alpha = 0.0, w = 0.0;
};

Geometry geometry(const Eigen::VectorXd& x) {
  Geometry g;
  const Eigen::Vector2d p1 = x.head<2>(), p2 = x.tail<2>();
  g.c = 0.5 * (p1 + p2);
  g.w = (p2 - p1).norm();
  g.u = (p2 - p1) / g.w;
  g.n = Eigen::Vector2d(-g.u.y(), g.u.x());
  g.alpha = std::atan2(g.u.y(), g.u.x());
  return g;
}

/// x_f from centre, orientation and width.
Eigen::VectorXd compose(const Eigen::Vector2d& c, double alpha, double w) {
  const Eigen::Vector2d u(std::cos(alpha), std::sin(alpha));
  Eigen::VectorXd x(kSize);
  x << c - 0.5 * w * u, c + 0.5 * w * u;
  return x;
}

/// B of eq. 10 at x for M-space dimension dim (0, 3 or 4).
Eigen::MatrixXd B_at(const Eigen::VectorXd& x, int dim) {
  Eigen::MatrixXd B = Eigen::MatrixXd::Zero(dim, kSize);
  if (dim == 0) return B;
  const Geometry g = geometry(x);
  B.block<2, 2>(0, 0) = 0.5 * Eigen::Matrix2d::Identity();
  B.block<2, 2>(0, 2) = 0.5 * Eigen::Matrix2d::Identity();
  B.block<1, 2>(2, 0) = -g.n.transpose() / g.w;
  B.block<1, 2>(2, 2) = g.n.transpose() / g.w;
  if (dim == 4) {
    B.block<1, 2>(3, 0) = -g.u.transpose();
    B.block<1, 2>(3, 2) = g.u.transpose();
  }
  return B;
}

/// (r, b) of a sensor-frame point; J = ∂(r, b)/∂q.
Eigen::Vector2d polar(const Eigen::Vector2d& q, Eigen::Matrix2d* J) {
  const double r2 = q.squaredNorm(), r = std::sqrt(r2);
  if (J != nullptr) *J << q.x() / r, q.y() / r, -q.y() / r2, q.x() / r2;
  return {r, std::atan2(q.y(), q.x())};
}

bool is_jamb_measurement(const Measurement& m) {
  return m.kind == kJambsKind && m.v.size() == kSize && m.C_v.rows() == kSize && m.C_v.cols() == kSize &&
         m.v.allFinite() && m.C_v.allFinite() && m.v[0] > 0 && m.v[2] > 0;
}

void require_jamb_measurement(const Measurement& m) {
  if (!is_jamb_measurement(m))
    throw std::invalid_argument("doorway: expected a '" + std::string(kJambsKind) +
                                "' measurement with a 4-vector (r1, b1, r2, b2), positive ranges and a 4×4 covariance");
}

// ---- The functions a numeric feature needs: values only, no derivatives.

/// η = h(x_o) − v (eq. 16): the polar coordinates of both jambs minus the
/// measurement, bearings wrapped. false when a jamb is at the sensor.
bool jamb_residual(const Eigen::VectorXd& x_o, const Eigen::VectorXd& v, Eigen::VectorXd& eta) {
  if (x_o.size() != kSize || v.size() != kSize) return false;
  eta.resize(kSize);
  for (int i = 0; i < 2; ++i) {
    const Eigen::Vector2d q = x_o.segment<2>(2 * i);
    if (q.norm() < 1e-6) return false;
    const Eigen::Vector2d h = polar(q, nullptr);
    eta[2 * i] = h[0] - v[2 * i];
    eta[2 * i + 1] = mspace::wrap_angle(h[1] - v[2 * i + 1]);
  }
  return true;
}

/// The map-frame jambs of v seen from x_ms (the back-projection, no Jacobians).
Eigen::VectorXd jambs_in_map(const Eigen::VectorXd& v, const Eigen::VectorXd& x_ms) {
  return mspace::to_map_frame(doorway_layout(), jambs_in_sensor_frame(Eigen::Vector4d(v)), mspace::Pose6(x_ms));
}

/// The width |q2 − q1| of one observation.
double width_of(const Eigen::Vector4d& v) {
  const Eigen::Vector4d q = jambs_in_sensor_frame(v);
  return (q.tail<2>() - q.head<2>()).norm();
}

/// Bearings (rows 1 and 3 of η) are differenced wrapped.
const mspace::NumericOptions& jamb_options() {
  static const mspace::NumericOptions options = [] {
    mspace::NumericOptions o;
    o.angle_rows = {1, 3};
    return o;
  }();
  return options;
}

/// The width of one observation and its variance J_w C_v J_wᵀ, J_w by central differences.
std::pair<double, double> measured_width_numeric(const Eigen::Vector4d& v, const Eigen::Matrix4d& C_v) {
  const Eigen::MatrixXd J_wv = mspace::numeric_jacobian(
      mspace::NumericJacobian::measurement,
      [](const Eigen::VectorXd& x, Eigen::VectorXd& w) {
        w = Eigen::VectorXd::Constant(1, width_of(x));
        return true;
      },
      v);
  return {width_of(v), (J_wv * C_v * J_wv.transpose())(0, 0)};
}

// ---- The analytic versions.

/// The width |q2 − q1| of one observation and its variance J_w C_v J_wᵀ.
std::pair<double, double> measured_width(const Eigen::Vector4d& v, const Eigen::Matrix4d& C_v) {
  Eigen::Matrix4d J_q;
  const Eigen::Vector4d q = jambs_in_sensor_frame(v, &J_q);
  const Eigen::Vector2d d = q.tail<2>() - q.head<2>();
  const double w = d.norm();
  Eigen::RowVector4d J_wq;
  J_wq << -d.transpose() / w, d.transpose() / w;
  const Eigen::RowVector4d J_wv = J_wq * J_q;
  return {w, J_wv * C_v * J_wv.transpose()};
}

/// The map-frame jambs of v seen from x_ms, with J_fv = ∂x_f/∂v and J_fs = ∂x_f/∂x_ms.
Eigen::VectorXd back_project(const Eigen::Vector4d& v, const mspace::Pose6& x_ms, Eigen::MatrixXd& J_fv,
                             Eigen::MatrixXd& J_fs) {
  Eigen::Matrix4d J_qv;
  const Eigen::VectorXd q = jambs_in_sensor_frame(v, &J_qv);
  Eigen::MatrixXd J_fq;
  const Eigen::VectorXd x = mspace::to_map_frame(doorway_layout(), q, x_ms, &J_fq, &J_fs);
  J_fv = J_fq * J_qv;
  return x;
}

}  // namespace

Eigen::Vector4d jambs_in_sensor_frame(const Eigen::Vector4d& v, Eigen::Matrix4d* J) {
  Eigen::Vector4d q;
  if (J != nullptr) J->setZero();
  for (int i = 0; i < 2; ++i) {
    const double r = v[2 * i], b = v[2 * i + 1];
    q.segment<2>(2 * i) << r * std::cos(b), r * std::sin(b);
    if (J != nullptr) J->block<2, 2>(2 * i, 2 * i) << std::cos(b), -r * std::sin(b), std::sin(b), r * std::cos(b);
  }
  return q;
}

// ---------------------------------------------------------------- DoorwayFeature

DoorwayFeature::DoorwayFeature(const DoorwayConfig& config, const Eigen::Vector4d& v, const Eigen::Matrix4d& C_v,
                               const SensorView& view)
    : config_(config) {
  place_at(v, C_v, view);
}

DoorwayFeature::DoorwayFeature(const DoorwayConfig& config, const mspace::SavedFeature& saved) : config_(config) {
  mspace::saved::expect_layout(saved, kSaveVersion, {"observations", "gating_covariance"}, "doorway");
  x_ = saved.coords;
  mdim_ = saved.mspace_dim;
  if (saved.extra.size() == 3) width_evidence_ = saved.extra;
  const Eigen::MatrixXd records = mspace::saved::records(saved, "observations", kObservationRecord, "doorway");
  for (Eigen::Index i = 0; i < records.cols(); ++i) {
    const Eigen::VectorXd col = records.col(i);
    observations_.push_back({col.head<4>(), mspace::saved::get_matrix(col, 4, 4, 4), mspace::saved::get_view(col, 20)});
  }
  gating_cov_ = mspace::saved::fixed(saved, "gating_covariance", 4, 4, Eigen::Matrix4d::Zero(), "doorway");
}

const CoordLayout& DoorwayFeature::layout() const { return doorway_layout(); }

Eigen::MatrixXd DoorwayFeature::B() const { return B_at(x_, mdim_); }

// eq. 11, the columns dual to the rows of B (see the header).
Eigen::MatrixXd DoorwayFeature::B_dual() const {
  Eigen::MatrixXd Bd = Eigen::MatrixXd::Zero(kSize, mdim_);
  if (mdim_ == 0) return Bd;
  const Geometry g = geometry(x_);
  Bd.block<2, 2>(0, 0) = Eigen::Matrix2d::Identity();
  Bd.block<2, 2>(2, 0) = Eigen::Matrix2d::Identity();
  Bd.block<2, 1>(0, 2) = -0.5 * g.w * g.n;
  Bd.block<2, 1>(2, 2) = 0.5 * g.w * g.n;
  if (mdim_ == 4) {
    Bd.block<2, 1>(0, 3) = -0.5 * g.u;
    Bd.block<2, 1>(2, 3) = 0.5 * g.u;
  }
  return Bd;
}

// eq. 16: η = h(x_o) − v with h the polar coordinates of both jambs; J_ηv = −I.
bool DoorwayFeature::innovation(const Eigen::VectorXd& x_o, const Measurement& m, mspace::Innovation& out) const {
  if (!is_jamb_measurement(m) || x_o.size() != kSize) return false;
  if (config_.numeric) return mspace::numeric_innovation(jamb_residual, x_o, m.v, out, mspace::kNumericBoth, jamb_options());
  out.eta.resize(kSize);
  out.J_eta_o = Eigen::MatrixXd::Zero(kSize, kSize);
  for (int i = 0; i < 2; ++i) {
    const Eigen::Vector2d q = x_o.segment<2>(2 * i);
    if (q.norm() < 1e-6) return false;
    Eigen::Matrix2d J;
    const Eigen::Vector2d h = polar(q, &J);
    out.eta[2 * i] = h[0] - m.v[2 * i];
    out.eta[2 * i + 1] = mspace::wrap_angle(h[1] - m.v[2 * i + 1]);
    out.J_eta_o.block<2, 2>(2 * i, 2 * i) = J;
  }
  out.J_eta_v = -Eigen::MatrixXd::Identity(kSize, kSize);
  return true;
}

Eigen::MatrixXd DoorwayFeature::gating_covariance() const {
  if (mdim_ != 0) return {};
  return gating_cov_;
}

void DoorwayFeature::apply_perturbation(const Eigen::VectorXd& dx_p) {
  if (dx_p.size() != mdim_) throw std::invalid_argument("doorway: perturbation of the wrong size");
  if (mdim_ == 0) return;
  const Geometry g = geometry(x_);
  x_ = compose(g.c + dx_p.head<2>(), g.alpha + dx_p[2], g.w + (mdim_ == 4 ? dx_p[3] : 0.0));
}

void DoorwayFeature::place_at(const Eigen::Vector4d& v, const Eigen::Matrix4d& C_v, const SensorView& view) {
  Eigen::MatrixXd J_fv, J_fs;
  x_ = back_project(v, view.x_ms, J_fv, J_fs);
  const Eigen::MatrixXd C = J_fv * C_v * J_fv.transpose() + J_fs * view.C_ms * J_fs.transpose();
  gating_cov_ = 0.5 * (C + C.transpose());
}

void DoorwayFeature::add_width_evidence(const Eigen::Vector4d& v, const Eigen::Matrix4d& C_v) {
  const auto [w, var] = config_.numeric ? measured_width_numeric(v, C_v) : measured_width(v, C_v);
  width_evidence_ += Eigen::Vector3d(w / var, 1.0 / var, 1.0);
}

void DoorwayFeature::add_dense_information(const Measurement& m, const SensorView& view) {
  require_jamb_measurement(m);
  if (mdim_ == 0) {
    observations_.push_back({m.v, m.C_v, view});
    while (static_cast<int>(observations_.size()) > config_.max_dense) observations_.pop_front();
    place_at(m.v, m.C_v, view);
  } else if (mdim_ == 3) {
    add_width_evidence(m.v, m.C_v);
  }
}

// 0 → 3: the centre and orientation of the latest back-projection enter the
// estimator (δx_p = B δx_f with δx_f = J_fs δx_ms + J_fv δv); the width is
// fixed at the weighted mean of the stored observations.
std::optional<Extension> DoorwayFeature::enter_map() {
  const JambObservation& latest = observations_.back();
  Eigen::MatrixXd J_fv, J_fs;
  const Eigen::VectorXd x_bp = back_project(latest.v, latest.view.x_ms, J_fv, J_fs);
  const Eigen::MatrixXd B3 = B_at(x_bp, 3);
  for (const JambObservation& o : observations_) add_width_evidence(o.v, o.C_v);
  const Geometry g = geometry(x_bp);
  x_ = compose(g.c, g.alpha, width_evidence_[0] / width_evidence_[1]);
  mdim_ = 3;
  Extension ext;
  ext.new_dims = 3;
  ext.sensor = latest.view.sensor;
  ext.J_own = Eigen::MatrixXd(3, 0);
  Eigen::MatrixXd C;
  if (config_.numeric) {
    // The new coordinates δx_p = B3 δx_f as functions of the sensor pose and of v.
    const Eigen::Vector4d v = latest.v;
    const Eigen::VectorXd x_ms = latest.view.x_ms;
    ext.J_sensor = mspace::numeric_jacobian(
        mspace::NumericJacobian::sensor,
        [&](const Eigen::VectorXd& x, Eigen::VectorXd& p) {
          p = B3 * jambs_in_map(v, x);
          return true;
        },
        x_ms);
    const Eigen::MatrixXd J_v = mspace::numeric_jacobian(
        mspace::NumericJacobian::measurement,
        [&](const Eigen::VectorXd& vv, Eigen::VectorXd& p) {
          p = B3 * jambs_in_map(vv, x_ms);
          return true;
        },
        v);
    C = J_v * latest.C_v * J_v.transpose();
  } else {
    ext.J_sensor = B3 * J_fs;
    C = B3 * J_fv * latest.C_v * J_fv.transpose() * B3.transpose();
  }
  ext.C_new = 0.5 * (C + C.transpose());
  observations_.clear();
  return ext;
}

// 3 → 4: the width, from the evidence alone (frame independent: J_sensor = 0).
std::optional<Extension> DoorwayFeature::add_width() {
  const Geometry g = geometry(x_);
  x_ = compose(g.c, g.alpha, width_evidence_[0] / width_evidence_[1]);
  mdim_ = 4;
  mspace::feature_log(*this).debug("width ", width_evidence_[0] / width_evidence_[1], " m from ",
                                   width_evidence_[2], " observations (sigma ", std::sqrt(1.0 / width_evidence_[1]),
                                   " m)");
  Extension ext;
  ext.new_dims = 1;
  ext.C_new = Eigen::MatrixXd::Constant(1, 1, 1.0 / width_evidence_[1]);
  width_evidence_.setZero();
  return ext;
}

std::optional<Extension> DoorwayFeature::extend(const SensorView& last_view) {
  if (mdim_ == 0 && static_cast<int>(observations_.size()) >= config_.min_observations) {
    const SensorView& latest = observations_.back().view;
    if (latest.t == last_view.t && latest.sensor == last_view.sensor) return enter_map();
  }
  if (mdim_ == 3 && width_evidence_[2] >= config_.width_observations) return add_width();
  return std::nullopt;
}

std::optional<mspace::FeatureDrawing> DoorwayFeature::drawing() const {
  constexpr double kHalf = 0.05;  // m: half the side of a jamb's square
  mspace::FeatureDrawing out;
  for (int jamb = 0; jamb < 2; ++jamb) {
    const Eigen::Vector2d p = x_.segment<2>(2 * jamb);
    mspace::DrawingItem post{mspace::DrawingItem::Kind::Polygon, Eigen::Matrix2Xd(2, 4), ""};
    post.points << p.x() - kHalf, p.x() + kHalf, p.x() + kHalf, p.x() - kHalf,  //
        p.y() - kHalf, p.y() - kHalf, p.y() + kHalf, p.y() + kHalf;
    out.items.push_back(std::move(post));
  }
  mspace::DrawingItem opening{mspace::DrawingItem::Kind::Segments, Eigen::Matrix2Xd(2, 2), "door"};
  opening.points << x_.segment<2>(0), x_.segment<2>(2);
  out.items.push_back(std::move(opening));
  return out;
}

mspace::SavedFeature DoorwayFeature::save() const {
  mspace::SavedFeature s{x_, mdim_, width_evidence_, {}, kSaveVersion};
  if (!observations_.empty()) {
    Eigen::MatrixXd records(kObservationRecord, static_cast<Eigen::Index>(observations_.size()));
    for (Eigen::Index i = 0; i < records.cols(); ++i) {
      const JambObservation& o = observations_[static_cast<std::size_t>(i)];
      auto col = records.col(i);
      col.head<4>() = o.v;
      mspace::saved::put_matrix(col, 4, o.C_v);
      mspace::saved::put_view(col, 20, o.view);
    }
    s.put("observations", records);
  }
  if (mdim_ == 0) s.put("gating_covariance", gating_cov_);
  return s;
}

// ---------------------------------------------------------------- DoorwayType

std::vector<mspace::ParamSpec> DoorwayType::param_specs() {
  return {
      mspace::param_string("jacobians", "analytic",
                           "how the Jacobians are computed: by hand, or by the SDK's central differences",
                           {"analytic", "numeric"}),
      mspace::param_int("min_observations", 3, "observations before a tentative doorway enters the map", 1),
      mspace::param_int("width_observations", 10, "width observations before the width is estimated", 1),
      mspace::param_int("max_dense", 10, "observations kept while tentative (≥ min_observations)", 1),
  };
}

DoorwayType::DoorwayType(const mspace::PluginArgs& args) {
  config_.numeric = args.params.get_string("jacobians") == "numeric";
  config_.min_observations = static_cast<int>(args.params.get_int("min_observations"));
  config_.width_observations = static_cast<int>(args.params.get_int("width_observations"));
  config_.max_dense = static_cast<int>(args.params.get_int("max_dense"));
  if (config_.max_dense < config_.min_observations)
    throw std::invalid_argument("doorway: max_dense must be at least min_observations");
}

const CoordLayout& DoorwayType::layout() const { return doorway_layout(); }

std::unique_ptr<mspace::Feature> DoorwayType::create(const Measurement& m, const SensorView& view) {
  if (!is_jamb_measurement(m)) return nullptr;
  return std::make_unique<DoorwayFeature>(config_, Eigen::Vector4d(m.v), Eigen::Matrix4d(m.C_v), view);
}

std::optional<mspace::FeatureSample> DoorwayType::sample(int dim, std::uint64_t seed) const {
  if (dim != 0 && dim != 3 && dim != 4) return std::nullopt;
  std::mt19937_64 rng(seed);
  auto uniform = [&rng](double lo, double hi) { return std::uniform_real_distribution<double>(lo, hi)(rng); };
  mspace::FeatureSample s;
  s.x_ms = mspace::make_pose(uniform(-10, 10), uniform(-10, 10), uniform(0, 0.5), uniform(-3, 3), uniform(-0.1, 0.1),
                             uniform(-0.1, 0.1));
  const double range = uniform(2, 6), bearing = uniform(-1, 1), alpha = uniform(-3, 3), w = uniform(0.7, 1.2);
  const Eigen::Vector2d c(range * std::cos(bearing), range * std::sin(bearing));
  const Eigen::VectorXd q = compose(c, alpha, w);  // the jambs in the sensor frame
  Eigen::Vector4d v;
  v << polar(q.head<2>(), nullptr), polar(q.tail<2>(), nullptr);
  s.measurement.kind = kJambsKind;
  s.measurement.v = v;
  s.measurement.C_v = Eigen::Vector4d(9e-4, 1e-4, 9e-4, 1e-4).asDiagonal();
  if (dim == 0) {
    SensorView view;
    view.x_ms = s.x_ms;
    view.C_ms = mspace::Mat6::Identity() * 1e-4;
    s.feature = std::make_unique<DoorwayFeature>(config_, v, Eigen::Matrix4d(s.measurement.C_v), view);
  } else {
    s.feature = restore({mspace::to_map_frame(doorway_layout(), q, s.x_ms), dim, {}, {}, 0});
  }
  return s;
}

std::unique_ptr<mspace::Feature> DoorwayType::restore(const mspace::SavedFeature& saved) const {
  const bool ok = saved.coords.size() == kSize && saved.coords.allFinite() &&
                  (saved.coords.tail<2>() - saved.coords.head<2>()).norm() > 1e-6 &&
                  (saved.mspace_dim == 0 || saved.mspace_dim == 3 || saved.mspace_dim == 4) &&
                  (saved.extra.size() == 0 || saved.extra.size() == 3);
  if (!ok)
    throw std::invalid_argument("doorway: restore needs two distinct finite jambs (4 numbers), dimension 0, 3 or 4 "
                                "and 0 or 3 extra numbers");
  return std::make_unique<DoorwayFeature>(config_, saved);
}

}  // namespace doorway
