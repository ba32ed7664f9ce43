// laser_poles.cpp — see laser_poles.hpp.
#include "laser_poles.hpp"

#include "pole_scene.hpp"

#include <Eigen/Dense>
#include <algorithm>
#include <cmath>
#include <numbers>
#include <stdexcept>
#include <string>

namespace mspace::laser_poles {
namespace {

constexpr int kMaxIterations = 30;
constexpr double kConverged = 1e-10;  ///< squared step length (m²)
constexpr double kDegree = std::numbers::pi / 180.0;

/// Algebraic (Kåsa) fit: x² + y² + D x + E y + F = 0 in least squares.
std::optional<Eigen::Vector3d> kasa_fit(const Eigen::Matrix2Xd& p) {
  Eigen::MatrixX3d A(p.cols(), 3);
  Eigen::VectorXd b(p.cols());
  for (Eigen::Index i = 0; i < p.cols(); ++i) {
    A.row(i) << p(0, i), p(1, i), 1.0;
    b[i] = -p.col(i).squaredNorm();
  }
  const Eigen::Vector3d def = A.colPivHouseholderQr().solve(b);
  const Eigen::Vector2d c(-def[0] / 2, -def[1] / 2);
  const double r2 = c.squaredNorm() - def[2];
  if (!def.allFinite() || r2 <= 0.0) return std::nullopt;
  return Eigen::Vector3d(c.x(), c.y(), std::sqrt(r2));
}

/// Geometric residuals e_i = |p_i − c| − ρ and J = ∂e/∂(c_x, c_y, ρ).
Eigen::VectorXd residuals(const Eigen::Matrix2Xd& p, const Eigen::Vector3d& x, Eigen::MatrixX3d& J) {
  Eigen::VectorXd e(p.cols());
  J.resize(p.cols(), 3);
  for (Eigen::Index i = 0; i < p.cols(); ++i) {
    const Eigen::Vector2d d = p.col(i) - x.head<2>();
    const double n = d.norm();
    e[i] = n - x[2];
    J.row(i) << -d.x() / n, -d.y() / n, -1.0;
  }
  return e;
}

bool is_valid(double range, const LaserPolesConfig& c) { return range >= c.min_range && range <= c.max_range; }

}  // namespace

std::optional<Circle> fit_circle(const Eigen::Matrix2Xd& points, double sigma) {
  if (points.cols() < 3) return std::nullopt;
  std::optional<Eigen::Vector3d> start = kasa_fit(points);
  if (!start) return std::nullopt;
  Eigen::Vector3d x = *start;
  Eigen::MatrixX3d J;
  for (int it = 0; it < kMaxIterations; ++it) {  // Gauss–Newton
    const Eigen::VectorXd e = residuals(points, x, J);
    const Eigen::Vector3d step = (J.transpose() * J).ldlt().solve(-J.transpose() * e);
    if (!step.allFinite()) return std::nullopt;
    x += step;
    if (step.squaredNorm() < kConverged) break;
  }
  const Eigen::VectorXd e = residuals(points, x, J);
  const Eigen::Matrix3d JtJ = J.transpose() * J;
  Eigen::FullPivLU<Eigen::Matrix3d> lu(JtJ);
  if (!x.allFinite() || x[2] <= 0.0 || !lu.isInvertible()) return std::nullopt;
  Circle circle;
  circle.centre = x.head<2>();
  circle.radius = x[2];
  // Range noise moves point i along its beam u_i, which changes e_i by
  // cos γ_i = u_i · ∂|p_i − c|/∂p_i. The covariance of the (unweighted)
  // least-squares estimate is the sandwich (JᵀJ)⁻¹ Jᵀ Σ_e J (JᵀJ)⁻¹.
  Eigen::VectorXd var_e(points.cols());
  for (Eigen::Index i = 0; i < points.cols(); ++i) {
    const double cos_gamma = -points.col(i).normalized().dot(J.row(i).head<2>().transpose());
    var_e[i] = sigma * sigma * cos_gamma * cos_gamma;
  }
  const Eigen::Matrix3d inv = lu.inverse();
  circle.covariance = inv * J.transpose() * var_e.asDiagonal() * J * inv;
  circle.rms = std::sqrt(e.squaredNorm() / static_cast<double>(e.size()));
  return circle;
}

Eigen::MatrixX2d beams_of(const SensorReading& reading, const LaserPolesConfig& config) {
  const Eigen::MatrixXd& v = reading.values;
  Eigen::MatrixX2d beams;
  if (v.cols() == 2) {
    beams = v;
  } else if (v.rows() == 1) {
    beams.resize(v.cols(), 2);
    for (Eigen::Index k = 0; k < v.cols(); ++k)
      beams.row(k) << config.start_angle + static_cast<double>(k) * config.angle_step, v(0, k);
  } else {
    throw std::runtime_error("laser_poles: reading on channel '" + reading.channel + "' at t = " +
                             std::to_string(reading.t) + " must be N×2 (angle, range) or 1×N ranges, got " +
                             std::to_string(v.rows()) + "×" + std::to_string(v.cols()));
  }
  if (!beams.col(0).allFinite()) {
    throw std::runtime_error("laser_poles: reading on channel '" + reading.channel + "' at t = " +
                             std::to_string(reading.t) + " has a non-finite beam angle");
  }
  std::vector<Eigen::Index> order(static_cast<std::size_t>(beams.rows()));
  for (std::size_t i = 0; i < order.size(); ++i) order[i] = static_cast<Eigen::Index>(i);
  std::stable_sort(order.begin(), order.end(), [&](auto a, auto b) { return beams(a, 0) < beams(b, 0); });
  Eigen::MatrixX2d sorted(beams.rows(), 2);
  for (std::size_t i = 0; i < order.size(); ++i) sorted.row(static_cast<Eigen::Index>(i)) = beams.row(order[i]);
  return sorted;
}

std::vector<std::pair<int, int>> clusters(const Eigen::MatrixX2d& beams, const LaserPolesConfig& config) {
  std::vector<std::pair<int, int>> out;
  const int n = static_cast<int>(beams.rows());
  int first = -1;
  for (int k = 0; k <= n; ++k) {
    const bool valid = k < n && std::isfinite(beams(k, 1)) && is_valid(beams(k, 1), config);
    const bool continues = valid && first >= 0 && std::abs(beams(k, 1) - beams(k - 1, 1)) <= config.max_jump;
    if (first >= 0 && !continues) {
      out.emplace_back(first, k - 1);
      first = -1;
    }
    if (valid && first < 0) first = k;
  }
  return out;
}

// ---------------------------------------------------------------- LaserPolesExtractor

std::vector<ParamSpec> LaserPolesExtractor::param_specs() {
  return {
      param_double("range_sigma", 0.03, "range noise of one beam (m)", 1e-6),
      param_double("min_range", 0.3, "shorter returns are ignored (m)", 0.0),
      param_double("max_range", 75.0, "longer returns are 'no return' (m)", 0.0),
      param_double("start_angle_deg", -90.0, "angle of the first beam of a 1×N scan (deg)"),
      param_double("angle_step_deg", 0.5, "angle between beams of a 1×N scan (deg)", 1e-6),
      param_double("max_jump", 0.3, "largest range step between neighbouring beams of one object (m)", 0.0),
      param_int("min_points", 3, "fewest beams a pole must reflect (≥ 3 to fit a circle)", 3.0),
      param_double("min_radius", 0.03, "smallest pole radius reported (m)", 0.0),
      param_double("max_radius", 1.0, "largest pole radius reported (m)", 0.0),
      param_double("max_rms_sigmas", 3.0, "largest RMS circle residual, in units of range_sigma", 0.0),
  };
}

LaserPolesExtractor::LaserPolesExtractor(const PluginArgs& args) {
  const Params& p = args.params;
  config_.range_sigma = p.get_double("range_sigma");
  config_.min_range = p.get_double("min_range");
  config_.max_range = p.get_double("max_range");
  config_.start_angle = p.get_double("start_angle_deg") * kDegree;
  config_.angle_step = p.get_double("angle_step_deg") * kDegree;
  config_.max_jump = p.get_double("max_jump");
  config_.min_points = static_cast<int>(p.get_int("min_points"));
  config_.min_radius = p.get_double("min_radius");
  config_.max_radius = p.get_double("max_radius");
  config_.max_rms_sigmas = p.get_double("max_rms_sigmas");
  if (config_.min_range > config_.max_range || config_.min_radius > config_.max_radius)
    throw std::invalid_argument("laser_poles: min_range/min_radius must not exceed max_range/max_radius");
}

std::optional<Measurement> LaserPolesExtractor::pole_from_cluster(const Eigen::MatrixX2d& beams, int first,
                                                                  int last) const {
  const int n = last - first + 1;
  if (n < config_.min_points) return std::nullopt;
  Eigen::Matrix2Xd points(2, n);
  double nearest = std::numeric_limits<double>::infinity();
  for (int i = 0; i < n; ++i) {
    const double a = beams(first + i, 0), r = beams(first + i, 1);
    points.col(i) << r * std::cos(a), r * std::sin(a);
    nearest = std::min(nearest, r);
  }
  const std::optional<Circle> circle = fit_circle(points, config_.range_sigma);
  if (!circle || circle->radius < config_.min_radius || circle->radius > config_.max_radius ||
      circle->rms > config_.max_rms_sigmas * config_.range_sigma || circle->centre.norm() <= nearest) {
    return std::nullopt;
  }
  // v = (|c|, atan2(c_y, c_x), 2ρ), J = ∂v/∂(c_x, c_y, ρ).
  const Eigen::Vector2d c = circle->centre;
  const double r2 = c.squaredNorm(), r = std::sqrt(r2);
  Eigen::Matrix3d J;
  J << c.x() / r, c.y() / r, 0.0,  //
      -c.y() / r2, c.x() / r2, 0.0,  //
      0.0, 0.0, 2.0;
  Measurement m;
  m.kind = kRangeBearingDiameter;
  m.v = Eigen::Vector3d(r, std::atan2(c.y(), c.x()), 2.0 * circle->radius);
  const Eigen::Matrix3d C = J * circle->covariance * J.transpose();
  m.C_v = 0.5 * (C + C.transpose());
  m.dense = points;
  return m;
}

void LaserPolesExtractor::extract(const SensorReading& reading, std::vector<Measurement>& out) {
  if (reading.values.size() == 0) return;  // an empty scan has no poles
  const Eigen::MatrixX2d beams = beams_of(reading, config_);
  for (const auto& [first, last] : clusters(beams, config_)) {
    if (std::optional<Measurement> m = pole_from_cluster(beams, first, last)) out.push_back(std::move(*m));
  }
}

std::optional<SampleScene> LaserPolesExtractor::sample_scene(std::uint64_t seed) const {
  SampleScene scene;
  scene.reading.channel = "laser";
  scene.x_ms = sample_planar_pose(seed);
  for (const Trunk& trunk : sample_trunks(seed)) scene.truth.push_back(trunk_shape(trunk, scene.x_ms));
  const auto beams = static_cast<Eigen::Index>(std::floor(std::numbers::pi / config_.angle_step)) + 1;
  const Eigen::VectorXd bearings =
      Eigen::VectorXd::LinSpaced(beams, config_.start_angle, config_.start_angle + config_.angle_step * (beams - 1));
  scene.reading.values = planar_scan(scene.truth, scene.x_ms, bearings, config_.max_range).transpose();
  return scene;
}

}  // namespace mspace::laser_poles
