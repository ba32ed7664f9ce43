// scan_matcher.cpp — see scan_matcher.hpp.
#include "scan_matcher.hpp"

#include <Eigen/Dense>
#include <algorithm>
#include <cmath>
#include <numbers>
#include <numeric>

namespace mspace::scan_matching {
namespace {

Eigen::Matrix2d rotation(double a) {
  const double c = std::cos(a), s = std::sin(a);
  Eigen::Matrix2d R;
  R << c, -s, s, c;
  return R;
}

/// Unit normal of the total-least-squares line through `pts` and the RMS
/// distance of the points from it.
std::pair<Eigen::Vector2d, double> fit_line(const std::vector<Eigen::Vector2d>& pts) {
  Eigen::Vector2d mean = Eigen::Vector2d::Zero();
  for (const auto& p : pts) mean += p;
  mean /= static_cast<double>(pts.size());
  Eigen::Matrix2d scatter = Eigen::Matrix2d::Zero();
  for (const auto& p : pts) scatter += (p - mean) * (p - mean).transpose();
  scatter /= static_cast<double>(pts.size());
  const Eigen::SelfAdjointEigenSolver<Eigen::Matrix2d> eig(scatter);
  // Smallest eigenvalue first: its eigenvector is the normal, its value the
  // mean squared distance from the line.
  return {eig.eigenvectors().col(0), std::sqrt(std::max(0.0, eig.eigenvalues()[0]))};
}

/// Correspondence distance at iteration `i`: from `max` down to `min` over the
/// first half of the iterations, then `min`.
double correspondence_distance(const MatchOptions& o, int i) {
  const double half = std::max(1.0, 0.5 * o.max_iterations);
  const double f = std::min(1.0, i / half);
  return o.max_correspondence + f * (o.min_correspondence - o.max_correspondence);
}

}  // namespace

ScanPoints scan_to_points(const std::vector<double>& ranges, const std::vector<double>& bearings,
                          double max_range) {
  ScanPoints points;
  points.reserve(ranges.size());
  for (std::size_t i = 0; i < ranges.size() && i < bearings.size(); ++i) {
    const double r = ranges[i];
    if (!(r > 0.0) || r >= max_range) continue;
    points.emplace_back(r * std::cos(bearings[i]), r * std::sin(bearings[i]));
  }
  return points;
}

ReferenceScan::ReferenceScan(const ScanPoints& points, const MatchOptions& options) : options_(options) {
  // A normal from up to `normal_neighbours` beams on each side, walking out
  // while consecutive points are closer than normal_radius or, far away where
  // the beams spread, than gap_per_m × range.
  std::vector<Eigen::Vector2d> neighbourhood;
  std::vector<std::pair<Eigen::Vector2d, Eigen::Vector2d>> usable;
  const auto n = static_cast<int>(points.size());
  for (int i = 0; i < n; ++i) {
    neighbourhood.assign(1, points[static_cast<std::size_t>(i)]);
    const auto& p = points[static_cast<std::size_t>(i)];
    const double max_gap = std::max(options_.normal_radius, options_.gap_per_m * p.norm());
    for (int step : {-1, 1}) {
      const Eigen::Vector2d* last = &p;
      for (int j = i + step, taken = 0; j >= 0 && j < n && taken < options_.normal_neighbours; j += step, ++taken) {
        const auto& q = points[static_cast<std::size_t>(j)];
        if ((q - *last).norm() > max_gap) break;
        neighbourhood.push_back(q);
        last = &q;
      }
    }
    if (neighbourhood.size() < 3) continue;
    const auto [normal, rms] = fit_line(neighbourhood);
    if (rms > options_.max_line_rms) continue;
    usable.emplace_back(p, normal);
  }
  std::sort(usable.begin(), usable.end(), [](const auto& a, const auto& b) { return a.first.x() < b.first.x(); });
  for (const auto& [p, normal] : usable) {
    points_.push_back(p);
    normals_.push_back(normal);
  }
}

int ReferenceScan::nearest(const Eigen::Vector2d& q, double max_distance) const {
  const auto first = std::lower_bound(points_.begin(), points_.end(), q.x() - max_distance,
                                      [](const Eigen::Vector2d& p, double x) { return p.x() < x; });
  int best = -1;
  double best_d2 = max_distance * max_distance;
  for (auto it = first; it != points_.end() && it->x() <= q.x() + max_distance; ++it) {
    const double d2 = (*it - q).squaredNorm();
    if (d2 < best_d2) {
      best_d2 = d2;
      best = static_cast<int>(it - points_.begin());
    }
  }
  return best;
}

double ReferenceScan::overlap_score(const ScanPoints& current, const Eigen::Vector3d& T, double radius) const {
  const Eigen::Matrix2d R = rotation(T[2]);
  double score = 0.0;
  for (const auto& q : current) {
    const Eigen::Vector2d moved = R * q + T.head<2>();
    const int j = nearest(moved, radius);
    if (j < 0) continue;
    const double d = (moved - points_[static_cast<std::size_t>(j)]).norm() / radius;
    score += 1.0 - d * d;
  }
  return score;
}

Eigen::Vector3d ReferenceScan::heading_search(const ScanPoints& current, const Eigen::Vector3d& seed) const {
  Eigen::Vector3d best = seed;
  if (options_.heading_search <= 0.0) return best;
  double best_score = overlap_score(current, seed, options_.search_radius);
  const int steps = static_cast<int>(std::ceil(options_.heading_search / options_.heading_search_step));
  for (int k = -steps; k <= steps; ++k) {
    if (k == 0) continue;
    Eigen::Vector3d T = seed;
    T[2] += k * options_.heading_search_step;
    const double score = overlap_score(current, T, options_.search_radius);
    if (score > best_score) {
      best_score = score;
      best = T;
    }
  }
  return best;
}

MatchResult ReferenceScan::match(const ScanPoints& current, const Eigen::Vector3d& seed) const {
  MatchResult result;
  Eigen::Vector3d T = heading_search(current, seed);
  for (int it = 0; it < options_.max_iterations; ++it) {
    const double max_distance = correspondence_distance(options_, it);
    const Eigen::Matrix2d R = rotation(T[2]);
    const Eigen::Matrix2d dR = rotation(T[2] + 0.5 * std::numbers::pi);  // ∂R/∂θ
    Eigen::Matrix3d H = Eigen::Matrix3d::Zero();
    Eigen::Vector3d g = Eigen::Vector3d::Zero();
    double weighted_r2 = 0.0, weight_sum = 0.0;
    int pairs = 0;
    for (const auto& q : current) {
      const Eigen::Vector2d moved = R * q + T.head<2>();
      const int j = nearest(moved, max_distance);
      if (j < 0) continue;
      const Eigen::Vector2d& n = normals_[static_cast<std::size_t>(j)];
      const double r = n.dot(moved - points_[static_cast<std::size_t>(j)]);
      const double w = std::abs(r) <= options_.huber ? 1.0 : options_.huber / std::abs(r);
      // ∂r/∂(dx, dy, dθ) = (nᵀ, nᵀ ∂R/∂θ q).
      const Eigen::Vector3d J(n.x(), n.y(), n.dot(dR * q));
      H += w * J * J.transpose();
      g += w * J * r;
      weighted_r2 += w * r * r;
      weight_sum += w;
      ++pairs;
    }
    result.pairs = pairs;
    result.iterations = it + 1;
    if (pairs < options_.min_pairs) return result;  // ok = false: keep the seed
    result.rms = std::sqrt(weighted_r2 / weight_sum);
    // Gauss–Newton step on  Σ w r²/σ_p² + (T − seed)ᵀ Λ (T − seed): the weak
    // prior Λ = diag(1/σ_xy², 1/σ_xy², 1/σ_θ²) on the seed keeps a direction
    // the walls do not constrain (along a corridor) where the seed put it.
    const double point_weight = 1.0 / (options_.point_sigma * options_.point_sigma);
    const Eigen::Vector3d prior(1.0 / (options_.seed_sigma_xy * options_.seed_sigma_xy),
                                1.0 / (options_.seed_sigma_xy * options_.seed_sigma_xy),
                                1.0 / (options_.seed_sigma_theta * options_.seed_sigma_theta));
    const Eigen::Matrix3d A = point_weight * H + Eigen::Matrix3d(prior.asDiagonal());
    const Eigen::Vector3d b = point_weight * g + prior.cwiseProduct(T - seed);
    const Eigen::Vector3d step = -A.ldlt().solve(b);
    T += step;
    const bool at_final_distance = max_distance <= options_.min_correspondence + 1e-12;
    if (at_final_distance && step.head<2>().norm() < options_.converged_step &&
        std::abs(step[2]) < options_.converged_step)
      break;
  }
  result.increment = T;
  result.ok = result.rms <= options_.max_rms;
  return result;
}

}  // namespace mspace::scan_matching
