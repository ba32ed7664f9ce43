// wheel_check.cpp — see wheel_check.hpp.
#include "wheel_check.hpp"

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

}  // namespace mspace::scan_matching
