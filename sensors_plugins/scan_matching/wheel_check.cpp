// wheel_check.cpp — see wheel_check.hpp.
#include "wheel_check.hpp"

#include "scan_matcher.hpp"

#include <Eigen/Dense>
#include <algorithm>
#include <cmath>
#include <limits>
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
    case IncrementSource::fused: return "fused";
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

std::optional<CombinedIncrement> combine_increments(const Eigen::Vector3d& w, const Eigen::Matrix3d& C_w,
                                                    const Eigen::Vector3d& m, const Eigen::Matrix3d& C_m, double gate) {
  Eigen::Vector3d e = m - w;
  e[2] = std::remainder(e[2], 2.0 * std::numbers::pi);
  const Eigen::LDLT<Eigen::Matrix3d> S(C_m + C_w);
  if (S.info() != Eigen::Success || !S.isPositive() || !(e.dot(S.solve(e)) <= gate)) return std::nullopt;
  const Eigen::Matrix3d C = C_w - C_w * S.solve(C_w);
  return CombinedIncrement{w + C_w * S.solve(e), 0.5 * (C + C.transpose())};
}

Eigen::Vector3d WheelModel::correct(const Eigen::Vector3d& wheel) const {
  return {(1.0 + scale) * wheel[0], (1.0 + scale) * wheel[1], (1.0 + turn_scale) * wheel[2] + bias_per_m * wheel[0]};
}

double WheelModel::path_of(const Eigen::Vector3d& increment) const {
  return increment.head<2>().norm() + turn_length * std::abs(increment[2]);
}

Eigen::Matrix3d WheelModel::covariance(const Eigen::Vector3d& increment, double path) const {
  if (used == 0) return Eigen::Matrix3d::Zero();
  const double own = path_of(increment);
  const double L = std::max(path, own);
  const int K = std::clamp(static_cast<int>(std::ceil(L / std::max(median_path, 1e-3))), 1, 400);
  // A robot that wandered (path > its own proxy) drove and turned more than
  // the net increment shows: its sub-steps' noise is scaled up alike.
  const double wander = own > 0.0 ? L / own : 1.0;
  Eigen::Vector3d noise = increment / K * wander;
  if (own <= 0.0) noise = Eigen::Vector3d(L / K, 0.0, 0.0);
  return propagate(std::vector<Eigen::Vector3d>(static_cast<std::size_t>(K), increment / K),
                   std::vector<Eigen::Vector3d>(static_cast<std::size_t>(K), noise));
}

Eigen::Vector3d WheelModel::correct_along(const std::vector<Eigen::Vector3d>& steps) const {
  Eigen::Vector3d p = Eigen::Vector3d::Zero();
  for (const Eigen::Vector3d& w : steps) p = compose(p, correct(w));  // scan_matcher.hpp's planar ⊕
  return p;
}

Eigen::Matrix3d WheelModel::covariance_along(const std::vector<Eigen::Vector3d>& steps) const {
  if (used == 0) return Eigen::Matrix3d::Zero();
  std::vector<Eigen::Vector3d> corrected;
  for (const Eigen::Vector3d& w : steps) corrected.push_back(correct(w));
  // The random walk, plus the parameters' own uncertainty carried through
  // the composition: J Σ_k Jᵀ with J = ∂ correct_along / ∂(k_s, k_t, b) by
  // central differences (the composition is smooth in them). A systematic
  // error acts on every sub-step alike, so it grows with the turning and
  // driving of the whole stretch, not with its square root.
  Eigen::Matrix3d J;
  for (int p = 0; p < 3; ++p) {
    const double h = 1e-5;
    WheelModel plus = *this, minus = *this;
    double* const plus_value = p == 0 ? &plus.scale : p == 1 ? &plus.turn_scale : &plus.bias_per_m;
    double* const minus_value = p == 0 ? &minus.scale : p == 1 ? &minus.turn_scale : &minus.bias_per_m;
    *plus_value += h;
    *minus_value -= h;
    Eigen::Vector3d d = plus.correct_along(steps) - minus.correct_along(steps);
    d[2] = std::remainder(d[2], 2.0 * std::numbers::pi);
    J.col(p) = d / (2.0 * h);
  }
  const Eigen::Matrix3d systematic = J * parameter_covariance * J.transpose();
  return propagate(corrected, steps) + 0.5 * (systematic + systematic.transpose());
}

Eigen::Matrix3d WheelModel::propagate(const std::vector<Eigen::Vector3d>& steps,
                                      const std::vector<Eigen::Vector3d>& noise_of) const {
  auto variance = [](const Rates& r, const Eigen::Vector3d& u) {
    return r.per_m * u.head<2>().norm() + r.per_rad * std::abs(u[2]);
  };
  // The per-increment floor, once, at the start.
  Eigen::Matrix3d sigma = Eigen::Vector3d(xy_rates.floor, xy_rates.floor, theta_rates.floor).asDiagonal();
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
    const double q_xy = variance(xy_rates, noise_of[k]);
    const Eigen::Vector3d q(q_xy, q_xy, variance(theta_rates, noise_of[k]));
    sigma = Jp * sigma * Jp.transpose() + Ju * q.asDiagonal() * Ju.transpose();
    p += Eigen::Vector3d(c * u[0] - s * u[1], s * u[0] + c * u[1], u[2]);
  }
  return 0.5 * (sigma + sigma.transpose());
}

namespace {

/// (k_s, k_t, b) by least squares (weights 1/L) over the increments `kept`;
/// a term the data cannot separate (a robot that only turned in place, or
/// only drove straight) keeps the value in `fallback`.
Eigen::Vector3d fit_systematic(const std::vector<Eigen::Vector3d>& wheel, const std::vector<Eigen::Vector3d>& matched,
                               const std::vector<std::size_t>& kept, const WheelModel& model, double floor_path,
                               const Eigen::Vector3d& fallback) {
  Eigen::Vector3d k = fallback;
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
  if (ww > 0.0) k[0] = wd / ww;
  const Eigen::Vector2d diag = A.diagonal();
  const double scale = std::max(diag.maxCoeff(), 1e-300);
  const bool turns = diag[0] > 1e-9 * scale, drives = diag[1] > 1e-9 * scale;
  if (turns && drives && A.determinant() > 1e-6 * diag.prod()) {
    const Eigen::Vector2d x = A.ldlt().solve(rhs);
    k[1] = x[0];
    k[2] = x[1];
  } else if (turns) {
    k[1] = (rhs[0] - A(0, 1) * k[2]) / diag[0];
  } else if (drives) {
    k[2] = (rhs[1] - A(1, 0) * k[1]) / diag[1];
  }
  return k;
}

/// Variance rates (per m, per rad, floor) ≥ 0 with E[e²] = a d + c |θ| + f,
/// by least squares on the squares over every subset of the three terms
/// (the best fit whose coefficients are all non-negative).
WheelModel::Rates fit_rates(const std::vector<Eigen::Vector3d>& regressors, const std::vector<double>& squares) {
  WheelModel::Rates best;
  double best_sse = std::numeric_limits<double>::infinity();
  for (int mask = 1; mask < 8; ++mask) {
    std::vector<int> cols;
    for (int c = 0; c < 3; ++c)
      if (mask & (1 << c)) cols.push_back(c);
    const auto m = static_cast<Eigen::Index>(cols.size());
    Eigen::MatrixXd A = Eigen::MatrixXd::Zero(m, m);
    Eigen::VectorXd b = Eigen::VectorXd::Zero(m);
    for (std::size_t i = 0; i < squares.size(); ++i)
      for (Eigen::Index r = 0; r < m; ++r) {
        b[r] += regressors[i][cols[static_cast<std::size_t>(r)]] * squares[i];
        for (Eigen::Index c = 0; c < m; ++c)
          A(r, c) += regressors[i][cols[static_cast<std::size_t>(r)]] * regressors[i][cols[static_cast<std::size_t>(c)]];
      }
    const Eigen::VectorXd x = A.ldlt().solve(b);
    if (!x.allFinite() || (x.array() < 0.0).any()) continue;
    Eigen::Vector3d full = Eigen::Vector3d::Zero();
    for (Eigen::Index r = 0; r < m; ++r) full[cols[static_cast<std::size_t>(r)]] = x[r];
    double sse = 0.0;
    for (std::size_t i = 0; i < squares.size(); ++i) sse += std::pow(regressors[i].dot(full) - squares[i], 2);
    if (sse < best_sse) {
      best_sse = sse;
      best = {full[0], full[1], full[2]};
    }
  }
  return best;
}

}  // namespace

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
  const Eigen::Vector3d k = fit_systematic(wheel, matched, kept, model, floor_path, Eigen::Vector3d::Zero());
  model.scale = k[0];
  model.turn_scale = k[1];
  model.bias_per_m = k[2];
  // How well the log pins the three down: the same fit on each of
  // kChunks consecutive stretches of it. Their spread holds both the fit's
  // noise on a stretch and how the wheels change along the log (floors,
  // load); it is taken, undivided, as the uncertainty of the parameters
  // for any one stretch — what a fallback across a gap must allow for.
  constexpr std::size_t kChunks = 8;
  if (kept.size() >= kChunks * 20) {
    std::vector<Eigen::Vector3d> estimates;
    for (std::size_t c = 0; c < kChunks; ++c) {
      const std::vector<std::size_t> chunk(kept.begin() + static_cast<long>(c * kept.size() / kChunks),
                                           kept.begin() + static_cast<long>((c + 1) * kept.size() / kChunks));
      estimates.push_back(fit_systematic(wheel, matched, chunk, model, floor_path, k));
    }
    Eigen::Vector3d mean = Eigen::Vector3d::Zero();
    for (const Eigen::Vector3d& e : estimates) mean += e / static_cast<double>(kChunks);
    Eigen::Matrix3d spread = Eigen::Matrix3d::Zero();
    for (const Eigen::Vector3d& e : estimates) spread += (e - mean) * (e - mean).transpose();
    model.parameter_covariance = spread / static_cast<double>(kChunks - 1);
  } else {
    // Too few increments to split: the parameters are taken as unknown to
    // their own size (an error as large as the correction itself).
    model.parameter_covariance = Eigen::Vector3d(k[0] * k[0], k[1] * k[1], k[2] * k[2]).asDiagonal();
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
  // The variance rates, from the squared corrected residuals (per axis for
  // x and y: half the squared distance).
  std::vector<Eigen::Vector3d> regressors;
  std::vector<double> xy_squares, theta_squares;
  for (std::size_t i : kept) {
    const Eigen::Vector3d c = model.correct(wheel[i]);
    regressors.emplace_back(wheel[i].head<2>().norm(), std::abs(wheel[i][2]), 1.0);
    xy_squares.push_back(0.5 * (matched[i].head<2>() - c.head<2>()).squaredNorm());
    theta_squares.push_back(std::pow(std::remainder(matched[i][2] - c[2], 2.0 * std::numbers::pi), 2));
  }
  model.xy_rates = fit_rates(regressors, xy_squares);
  model.theta_rates = fit_rates(regressors, theta_squares);
  // Never below the check's floors (the matcher's resolution over a median increment).
  model.xy_rates.floor = std::max(model.xy_rates.floor, options.floor_xy * options.floor_xy);
  model.theta_rates.floor = std::max(model.theta_rates.floor, options.floor_theta * options.floor_theta);
  model.used = kept.size();
  return model;
}

}  // namespace mspace::scan_matching
