// wheel_check.cpp — see wheel_check.hpp.
#include "wheel_check.hpp"

#include <Eigen/Dense>
#include <algorithm>
#include <cmath>
#include <numbers>

namespace mspace::scan_matching {
namespace {

double median(std::vector<double> v) {
  if (v.empty()) return 0.0;
  const auto mid = v.begin() + static_cast<long>(v.size() / 2);
  std::nth_element(v.begin(), mid, v.end());
  return *mid;
}

}  // namespace

const char* to_string(IncrementSource source) {
  switch (source) {
    case IncrementSource::matched: return "matched";
    case IncrementSource::failed: return "failed";
    case IncrementSource::gap: return "gap";
    case IncrementSource::inconsistent: return "inconsistent";
  }
  return "?";
}

std::vector<bool> logging_gaps(const std::vector<double>& times, double gap_factor) {
  std::vector<bool> gap(times.size(), false);
  if (times.size() < 2 || gap_factor <= 0.0) return gap;
  std::vector<double> spans;
  for (std::size_t i = 1; i < times.size(); ++i) spans.push_back(times[i] - times[i - 1]);
  const double limit = gap_factor * median(spans);
  for (std::size_t i = 1; i < times.size(); ++i) gap[i] = times[i] - times[i - 1] > limit;
  return gap;
}

std::size_t WheelCheckResult::count(IncrementSource s) const {
  return static_cast<std::size_t>(std::count(source.begin(), source.end(), s));
}

WheelCheckResult check_against_wheels(const std::vector<Eigen::Vector3d>& wheel,
                                      const std::vector<Eigen::Vector3d>& matched,
                                      const std::vector<IncrementSource>& source, const WheelCheckOptions& options) {
  WheelCheckResult r;
  r.source = source;
  r.chi2.assign(source.size(), 0.0);
  const std::size_t n = std::min({wheel.size(), matched.size(), source.size()});
  // The path proxy of each increment, without L̄.
  std::vector<double> path(n);
  for (std::size_t i = 0; i < n; ++i) path[i] = wheel[i].head<2>().norm() + options.turn_length * std::abs(wheel[i][2]);
  r.median_path = median(path);
  const double floor_path = std::max(r.median_path, 1e-3);  // L̄, never 0 (a log standing still)
  std::vector<double> xy, theta;
  std::vector<Eigen::Vector3d> diff(n, Eigen::Vector3d::Zero());
  for (std::size_t i = 0; i < n; ++i) {
    if (source[i] != IncrementSource::matched) continue;
    diff[i] = matched[i] - wheel[i];
    diff[i][2] = std::remainder(diff[i][2], 2.0 * std::numbers::pi);
    const double root = std::sqrt(path[i] + floor_path);
    xy.push_back(diff[i].head<2>().norm() / root);
    theta.push_back(std::abs(diff[i][2]) / root);
  }
  if (xy.empty() || options.gate <= 0.0) return r;
  // Robust spreads (Rayleigh median σ√(2 ln 2); half-normal median 0.6745 σ), floored.
  const double root_median = std::sqrt(2.0 * floor_path);  // √L of a median increment
  r.sigma_xy = std::max(median(xy) / std::sqrt(2.0 * std::numbers::ln2), options.floor_xy / root_median);
  r.sigma_theta = std::max(median(theta) / 0.6745, options.floor_theta / root_median);
  for (std::size_t i = 0; i < n; ++i) {
    if (source[i] != IncrementSource::matched) continue;
    const double L = path[i] + floor_path;
    r.chi2[i] = diff[i].head<2>().squaredNorm() / (r.sigma_xy * r.sigma_xy * L) +
                diff[i][2] * diff[i][2] / (r.sigma_theta * r.sigma_theta * L);
    if (r.chi2[i] > options.gate) r.source[i] = IncrementSource::inconsistent;
  }
  return r;
}

Eigen::Vector3d WheelModel::correct(const Eigen::Vector3d& wheel) const {
  return {(1.0 + scale) * wheel[0], (1.0 + scale) * wheel[1], (1.0 + turn_scale) * wheel[2] + bias_per_m * wheel[0]};
}

double WheelModel::path_of(const Eigen::Vector3d& increment) const {
  return increment.head<2>().norm() + turn_length * std::abs(increment[2]);
}

Eigen::Matrix3d WheelModel::covariance(const Eigen::Vector3d& increment, double path) const {
  if (used == 0) return Eigen::Matrix3d::Zero();
  const double L = std::max(path, path_of(increment));
  const int K = std::clamp(static_cast<int>(std::ceil(L / std::max(median_path, 1e-3))), 1, 400);
  return propagate(std::vector<Eigen::Vector3d>(static_cast<std::size_t>(K), increment / K),
                   std::vector<double>(static_cast<std::size_t>(K), L / K));
}

Eigen::Vector3d WheelModel::correct_along(const std::vector<Eigen::Vector3d>& steps) const {
  Eigen::Vector3d p = Eigen::Vector3d::Zero();
  for (const Eigen::Vector3d& w : steps) {
    const Eigen::Vector3d u = correct(w);
    const double c = std::cos(p[2]), s = std::sin(p[2]);
    p += Eigen::Vector3d(c * u[0] - s * u[1], s * u[0] + c * u[1], u[2]);
  }
  p[2] = std::remainder(p[2], 2.0 * std::numbers::pi);
  return p;
}

Eigen::Matrix3d WheelModel::covariance_along(const std::vector<Eigen::Vector3d>& steps) const {
  if (used == 0) return Eigen::Matrix3d::Zero();
  std::vector<Eigen::Vector3d> corrected;
  std::vector<double> paths;
  for (const Eigen::Vector3d& w : steps) {
    corrected.push_back(correct(w));
    paths.push_back(path_of(w));
  }
  return propagate(corrected, paths);
}

Eigen::Matrix3d WheelModel::propagate(const std::vector<Eigen::Vector3d>& steps, const std::vector<double>& paths) const {
  const Eigen::Vector3d rate(sigma_xy * sigma_xy, sigma_xy * sigma_xy, sigma_theta * sigma_theta);
  // The per-increment floor s²·L̄ of the variance model, once, at the start.
  Eigen::Matrix3d sigma = Eigen::Matrix3d(rate.asDiagonal()) * std::max(median_path, 1e-3);
  Eigen::Vector3d p = Eigen::Vector3d::Zero();
  // Σ' = J_p Σ J_pᵀ + J_u Q J_uᵀ for p' = p ⊕ u (p in the increment's start frame).
  for (std::size_t k = 0; k < steps.size(); ++k) {
    const Eigen::Vector3d& u = steps[k];
    const double c = std::cos(p[2]), s = std::sin(p[2]);
    Eigen::Matrix3d Jp = Eigen::Matrix3d::Identity();
    Jp(0, 2) = -s * u[0] - c * u[1];
    Jp(1, 2) = c * u[0] - s * u[1];
    Eigen::Matrix3d Ju = Eigen::Matrix3d::Identity();
    Ju.topLeftCorner<2, 2>() << c, -s, s, c;
    sigma = Jp * sigma * Jp.transpose() + Ju * Eigen::Matrix3d(rate.asDiagonal()) * paths[k] * Ju.transpose();
    p += Eigen::Vector3d(c * u[0] - s * u[1], s * u[0] + c * u[1], u[2]);
  }
  return 0.5 * (sigma + sigma.transpose());
}

WheelModel fit_wheel_model(const std::vector<Eigen::Vector3d>& wheel, const std::vector<Eigen::Vector3d>& matched,
                           const WheelCheckResult& check, const WheelCheckOptions& options) {
  WheelModel model;
  model.turn_length = options.turn_length;
  model.median_path = check.median_path;
  const std::size_t n = std::min({wheel.size(), matched.size(), check.source.size()});
  const double floor_path = std::max(check.median_path, 1e-3);
  std::vector<std::size_t> kept;
  for (std::size_t i = 0; i < n; ++i)
    if (check.source[i] == IncrementSource::matched) kept.push_back(i);
  if (kept.size() < 20) return model;
  // Weighted least squares, weight 1/L (the variance grows with the path).
  double ww = 0.0, wd = 0.0;
  Eigen::Matrix2d A = Eigen::Matrix2d::Zero();
  Eigen::Vector2d rhs = Eigen::Vector2d::Zero();
  for (std::size_t i : kept) {
    const double weight = 1.0 / (model.path_of(wheel[i]) + floor_path);
    const Eigen::Vector2d w = wheel[i].head<2>();
    ww += weight * w.squaredNorm();
    wd += weight * w.dot(matched[i].head<2>() - w);
    const Eigen::Vector2d a(wheel[i][2], wheel[i][0]);
    A += weight * a * a.transpose();
    rhs += weight * a * std::remainder(matched[i][2] - wheel[i][2], 2.0 * std::numbers::pi);
  }
  if (ww > 0.0) model.scale = wd / ww;
  // A turn-scale or drift term the data cannot separate (a robot that only
  // turned in place, or only drove straight) is left at zero.
  const Eigen::Vector2d diag = A.diagonal();
  if (diag.minCoeff() > 1e-9 * std::max(1.0, diag.maxCoeff()) && A.determinant() > 1e-12 * diag.prod()) {
    const Eigen::Vector2d x = A.ldlt().solve(rhs);
    model.turn_scale = x[0];
    model.bias_per_m = x[1];
  } else if (diag[0] > 0.0 && diag[1] <= 1e-9 * diag[0]) {
    model.turn_scale = rhs[0] / diag[0];
  } else if (diag[1] > 0.0) {
    model.bias_per_m = rhs[1] / diag[1];
  }
  // The spreads of what the correction leaves, as the check measures them.
  std::vector<double> xy, theta;
  for (std::size_t i : kept) {
    const Eigen::Vector3d c = model.correct(wheel[i]);
    const double root = std::sqrt(model.path_of(wheel[i]) + floor_path);
    xy.push_back((matched[i].head<2>() - c.head<2>()).norm() / root);
    theta.push_back(std::abs(std::remainder(matched[i][2] - c[2], 2.0 * std::numbers::pi)) / root);
  }
  const double root_median = std::sqrt(2.0 * floor_path);
  model.sigma_xy = std::max(median(xy) / std::sqrt(2.0 * std::numbers::ln2), options.floor_xy / root_median);
  model.sigma_theta = std::max(median(theta) / 0.6745, options.floor_theta / root_median);
  model.used = kept.size();
  return model;
}

}  // namespace mspace::scan_matching
