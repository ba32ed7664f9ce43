// line_extraction.cpp — see line_extraction.hpp.
#include "line_extraction.hpp"

#include <Eigen/LU>

#include <algorithm>
#include <cmath>
#include <numbers>
#include <optional>
#include <utility>

namespace mspace::laser_lines {
namespace {

using line_segment::EndReason;
using Vec2 = Eigen::Vector2d;

/// The scan as points, with which beams have a usable return.
struct ScanPoints {
  const Eigen::VectorXd& ranges;
  const Eigen::VectorXd& bearings;
  Eigen::Matrix2Xd p;
  std::vector<bool> valid;
  int size() const { return static_cast<int>(valid.size()); }
};

/// Total-least-squares line through points first..last.
struct LineFit {
  double rho = 0.0, alpha = 0.0;
  Vec2 centroid = Vec2::Zero();
  double rms = 0.0, max_residual = 0.0;
  double sum_s2 = 0.0;  ///< Σ (t·(p − c))²
  int n = 0;
  Vec2 u() const { return {std::cos(alpha), std::sin(alpha)}; }
  Vec2 t() const { return {std::sin(alpha), -std::cos(alpha)}; }
  double residual(const Vec2& q) const { return u().dot(q) - rho; }
};

LineFit fit_line(const ScanPoints& scan, int first, int last) {
  LineFit fit;
  fit.n = last - first + 1;
  const auto block = scan.p.middleCols(first, fit.n);
  fit.centroid = block.rowwise().mean();
  const Eigen::Matrix2Xd d = block.colwise() - fit.centroid;
  const double sxx = d.row(0).squaredNorm(), syy = d.row(1).squaredNorm(), sxy = d.row(0).dot(d.row(1));
  const double direction = 0.5 * std::atan2(2.0 * sxy, sxx - syy);  // principal axis
  Vec2 normal(-std::sin(direction), std::cos(direction));
  double rho = normal.dot(fit.centroid);
  if (rho < 0.0) {
    normal = -normal;
    rho = -rho;
  }
  fit.rho = rho;
  fit.alpha = std::atan2(normal.y(), normal.x());
  double sum_r2 = 0.0;
  for (int i = 0; i < fit.n; ++i) {
    const double r = normal.dot(block.col(i)) - rho;
    sum_r2 += r * r;
    fit.max_residual = std::max(fit.max_residual, std::abs(r));
    const double s = fit.t().dot(d.col(i));
    fit.sum_s2 += s * s;
  }
  fit.rms = std::sqrt(sum_r2 / fit.n);
  return fit;
}

/// A beam without any return: range 0 (what the sources write for the
/// laser's no-return and error codes), negative or not finite. Unlike a
/// return beyond max_range (the beam went through an opening) it says
/// nothing about what lies there: a dropout.
bool no_return(double range) { return !(range > 0.0) || !std::isfinite(range); }

/// Step 1: runs of beams with a return split at adaptive breakpoints. `dense`
/// holds only the usable beams of `scan`, `beam_of` their indices in it: a
/// run goes on across at most c.bridge_no_returns beams without any return (a
/// dropout inside a wall; the breakpoint test then spans the wider angle),
/// never across a return that is too far or too close.
std::vector<std::pair<int, int>> clusters(const ScanPoints& scan, const ScanPoints& dense,
                                          const std::vector<int>& beam_of, const LineConfig& c) {
  std::vector<std::pair<int, int>> out;
  if (dense.size() == 0) return out;
  int start = 0;
  for (int i = 1; i < dense.size(); ++i) {
    const int from = beam_of[static_cast<std::size_t>(i) - 1], to = beam_of[static_cast<std::size_t>(i)];
    bool breaks = to - from - 1 > c.bridge_no_returns;
    for (int j = from + 1; j < to && !breaks; ++j) breaks = !no_return(scan.ranges[j]);
    const double dphi = std::abs(dense.bearings[i] - dense.bearings[i - 1]);
    breaks = breaks || dphi >= c.breakpoint_lambda;
    if (!breaks) {
      const double r = std::min(dense.ranges[i], dense.ranges[i - 1]);
      const double sigma = std::max(c.range_sigma, c.breakpoint_sigma);
      const double limit = r * std::sin(dphi) / std::sin(c.breakpoint_lambda - dphi) + 3.0 * sigma;
      breaks = (dense.p.col(i) - dense.p.col(i - 1)).norm() > limit;
    }
    if (breaks) {
      out.emplace_back(start, i - 1);
      start = i;
    }
  }
  out.emplace_back(start, dense.size() - 1);
  return out;
}

/// Distance of q from the chord a–b.
double chord_distance(const Vec2& a, const Vec2& b, const Vec2& q) {
  const Vec2 d = b - a;
  const double len = d.norm();
  if (len < 1e-12) return (q - a).norm();
  return std::abs(d.x() * (q.y() - a.y()) - d.y() * (q.x() - a.x())) / len;
}

/// Step 2: iterative end-point fit; pieces share their split point.
void split(const ScanPoints& scan, int first, int last, double threshold, std::vector<std::pair<int, int>>& out) {
  if (last - first >= 2) {
    int worst = first;
    double worst_d = 0.0;
    for (int k = first + 1; k < last; ++k) {
      const double d = chord_distance(scan.p.col(first), scan.p.col(last), scan.p.col(k));
      if (d > worst_d) {
        worst_d = d;
        worst = k;
      }
    }
    if (worst_d > threshold) {
      split(scan, first, worst, threshold, out);
      split(scan, worst, last, threshold, out);
      return;
    }
  }
  out.emplace_back(first, last);
}

/// Step 3: merges neighbouring pieces whose joint fit stays within threshold.
void merge(const ScanPoints& scan, double threshold, std::vector<std::pair<int, int>>& pieces) {
  for (std::size_t i = 0; i + 1 < pieces.size();) {
    if (pieces[i].second >= pieces[i + 1].first &&
        fit_line(scan, pieces[i].first, pieces[i + 1].second).max_residual <= threshold) {
      pieces[i].second = pieces[i + 1].second;
      pieces.erase(pieces.begin() + static_cast<std::ptrdiff_t>(i) + 1);
    } else {
      ++i;
    }
  }
}

/// Step 4: trims ends farther than `limit` from the fitted line (a few points at most).
LineFit trim(const ScanPoints& scan, int& first, int& last, double limit) {
  LineFit fit = fit_line(scan, first, last);
  for (int round = 0; round < 3 && last - first >= 2; ++round) {
    const bool bad_first = std::abs(fit.residual(scan.p.col(first))) > limit;
    const bool bad_last = std::abs(fit.residual(scan.p.col(last))) > limit;
    if (!bad_first && !bad_last) break;
    if (bad_first) ++first;
    if (bad_last) --last;
    fit = fit_line(scan, first, last);
  }
  return fit;
}

/// Where beam `beam` crosses the line, as a range; NaN when the beam is grazing or points away.
double expected_range(const LineFit& fit, double bearing, const LineConfig& c) {
  const double cosine = std::cos(bearing - fit.alpha);
  if (cosine < std::cos(c.max_incidence)) return std::numeric_limits<double>::quiet_NaN();
  return fit.rho / cosine;
}

/// Smallest angle between two lines (0 … π/2).
double line_angle(double a, double b) {
  const double d = std::abs(std::remainder(a - b, std::numbers::pi));
  return d;
}

/// Intersection of two lines in (ρ, α) form; false when nearly parallel.
bool intersect(const Segment& a, const Segment& b, Vec2& q) {
  Eigen::Matrix2d A;
  A << std::cos(a.alpha), std::sin(a.alpha), std::cos(b.alpha), std::sin(b.alpha);
  if (std::abs(A.determinant()) < 1e-6) return false;
  q = A.inverse() * Vec2(a.rho, b.rho);
  return true;
}

Vec2 end_point(const Segment& s, double along) {
  const Vec2 u(std::cos(s.alpha), std::sin(s.alpha)), t(std::sin(s.alpha), -std::cos(s.alpha));
  return s.rho * u + along * t;
}

/// Where segment `self` meets another segment at a corner at the end whose
/// last inlier is beam `end_beam`: the two lines' intersection; none when no
/// segment within two beams (plus the bridged no-returns) meets it at
/// min_corner_angle or more.
std::optional<Vec2> corner_point(const std::vector<Segment>& segs, std::size_t self, int end_beam, double end_s,
                                 const LineConfig& c) {
  for (std::size_t k = 0; k < segs.size(); ++k) {
    if (k == self) continue;
    const Segment& o = segs[k];
    const int beam_gap = std::min(std::abs(o.first - end_beam), std::abs(o.last - end_beam));
    if (beam_gap > 2 + c.bridge_no_returns || line_angle(o.alpha, segs[self].alpha) < c.min_corner_angle) continue;
    Vec2 q;
    if (intersect(segs[self], o, q) && (q - end_point(segs[self], end_s)).norm() <= c.corner_distance) return q;
  }
  return std::nullopt;
}

/// The beam that tells why a segment stops at its end beam `end_beam` (`step`
/// = ±1 points outwards): the next one, or, past up to c.bridge_no_returns
/// beams without any return (no_return(): a dropout says nothing about the
/// wall), the first usable one. When none within reach is, the next beam.
int beam_beyond(const ScanPoints& scan, int end_beam, int step, const LineConfig& c) {
  int j = end_beam + step;
  for (int skipped = 0; skipped < c.bridge_no_returns && j >= 0 && j < scan.size() && no_return(scan.ranges[j]);
       ++skipped)
    j += step;
  return j >= 0 && j < scan.size() && scan.valid[j] ? j : end_beam + step;
}

/// Why segment `self` stops at its end with last inlier `end_beam`; `step` = ±1 points outwards.
EndReason classify_end(const ScanPoints& scan, const std::vector<Segment>& segs, const std::vector<LineFit>& fits,
                       std::size_t self, int end_beam, int step, double end_s, const LineConfig& c) {
  const int j = beam_beyond(scan, end_beam, step, c);
  if (j < 0 || j >= scan.size()) return EndReason::Fov;
  const double r = scan.ranges[j];
  if (!scan.valid[j]) return r > 0.0 && r < c.min_range ? EndReason::Occluded : EndReason::MaxRange;
  if (corner_point(segs, self, end_beam, end_s, c)) return EndReason::Corner;
  const double expected = expected_range(fits[self], scan.bearings[j], c);
  if (!std::isfinite(expected)) return EndReason::Unknown;
  if (r < expected - c.depth_jump) return EndReason::Occluded;
  if (r > expected + c.depth_jump) return EndReason::Depth;
  return EndReason::Unknown;
}

/// Where the end lies along the line and its variance. The wall ends
/// somewhere between the last inlier and where the next beam crosses the
/// line (the gap): for a Depth end the estimate is the gap's middle with
/// variance σ² + gap²/12 (uniform over the gap), not the last inlier, which
/// is short by gap/2 on average; for a Corner end it is the intersection
/// with the other wall (σ² + gap²/12 kept as a conservative bound); other
/// ends stay at the last inlier.
struct EndEstimate {
  double s = 0.0, variance = 0.0;
};
EndEstimate end_estimate(const ScanPoints& scan, const std::vector<Segment>& segs, const LineFit& fit,
                         std::size_t self, int end_beam, int step, double end_s, EndReason reason, double sigma2,
                         const LineConfig& c) {
  constexpr double kMaxGap = 1.0;
  const int j = beam_beyond(scan, end_beam, step, c);
  double gap = scan.ranges[end_beam] * std::abs(scan.bearings[std::clamp(j, 0, scan.size() - 1)] -
                                                scan.bearings[end_beam]);
  std::optional<double> next_crossing;
  if (j >= 0 && j < scan.size()) {
    const double expected = expected_range(fit, scan.bearings[j], c);
    if (std::isfinite(expected)) {
      const Vec2 q = expected * Vec2(std::cos(scan.bearings[j]), std::sin(scan.bearings[j]));
      next_crossing = fit.t().dot(q);
      gap = std::abs(*next_crossing - end_s);
    }
  }
  gap = std::min(gap, kMaxGap);
  EndEstimate out{end_s, sigma2 + gap * gap / 12.0};
  if (reason == EndReason::Corner) {
    if (const std::optional<Vec2> q = corner_point(segs, self, end_beam, end_s, c)) out.s = fit.t().dot(*q);
  } else if (reason == EndReason::Depth && next_crossing && std::abs(*next_crossing - end_s) <= kMaxGap) {
    out.s = 0.5 * (end_s + *next_crossing);
  }
  return out;
}

/// (ρ, α) covariance of a fit (see header) with the configured floors.
Eigen::Matrix2d line_covariance(const LineFit& fit, double sigma2, const LineConfig& c) {
  const double var_offset = sigma2 / fit.n;
  const double var_alpha = sigma2 / std::max(fit.sum_s2, 1e-12);
  // ρ = u(α)·c at the centroid: δρ = δd + (t'·c) δα with t' = du/dα.
  const double lever = Vec2(-std::sin(fit.alpha), std::cos(fit.alpha)).dot(fit.centroid);
  Eigen::Matrix2d J;
  J << 1.0, lever, 0.0, 1.0;
  Eigen::Matrix2d C = J * Eigen::Vector2d(var_offset, var_alpha).asDiagonal() * J.transpose();
  C(0, 0) += c.distance_sigma_floor * c.distance_sigma_floor;
  C(1, 1) += c.angle_sigma_floor * c.angle_sigma_floor;
  return C;
}

}  // namespace

std::vector<Segment> extract_segments(const Eigen::VectorXd& ranges, const Eigen::VectorXd& bearings,
                                      const LineConfig& c) {
  ScanPoints scan{ranges, bearings, Eigen::Matrix2Xd(2, ranges.size()), std::vector<bool>(ranges.size())};
  for (Eigen::Index i = 0; i < ranges.size(); ++i) {
    scan.valid[i] = std::isfinite(ranges[i]) && ranges[i] >= c.min_range && ranges[i] <= c.max_range;
    scan.p.col(i) = ranges[i] * Vec2(std::cos(bearings[i]), std::sin(bearings[i]));
  }

  // Lines are fitted to the beams with a return (`dense`; beam_of: their
  // indices in the scan), so that a segment may span a dropout (clusters());
  // its ends are classified on the whole scan.
  std::vector<int> beam_of;
  for (int i = 0; i < scan.size(); ++i)
    if (scan.valid[i]) beam_of.push_back(i);
  const auto n_dense = static_cast<Eigen::Index>(beam_of.size());
  Eigen::VectorXd dense_ranges(n_dense), dense_bearings(n_dense);
  ScanPoints dense{dense_ranges, dense_bearings, Eigen::Matrix2Xd(2, n_dense),
                   std::vector<bool>(beam_of.size(), true)};
  for (Eigen::Index i = 0; i < n_dense; ++i) {
    const int beam = beam_of[static_cast<std::size_t>(i)];
    dense_ranges[i] = ranges[beam];
    dense_bearings[i] = bearings[beam];
    dense.p.col(i) = scan.p.col(beam);
  }

  std::vector<std::pair<int, int>> pieces;
  for (const auto& [first, last] : clusters(scan, dense, beam_of, c)) {
    std::vector<std::pair<int, int>> cluster_pieces;
    split(dense, first, last, c.split_distance, cluster_pieces);
    merge(dense, c.split_distance, cluster_pieces);
    pieces.insert(pieces.end(), cluster_pieces.begin(), cluster_pieces.end());
  }

  const double trim_limit = std::max(3.0 * c.range_sigma, 0.5 * c.split_distance);
  std::vector<Segment> segs;
  std::vector<LineFit> fits;
  for (auto [first, last] : pieces) {
    if (last - first + 1 < c.min_points) continue;
    const LineFit fit = trim(dense, first, last, trim_limit);
    if (fit.n < c.min_points || fit.rms > c.max_rms || fit.rho < 1e-3) continue;
    Segment s;
    s.first = beam_of[static_cast<std::size_t>(first)];
    s.last = beam_of[static_cast<std::size_t>(last)];
    s.rho = fit.rho;
    s.alpha = fit.alpha;
    s.rms = fit.rms;
    s.inliers = dense.p.middleCols(first, fit.n);
    const double s_first = fit.t().dot(dense.p.col(first)), s_last = fit.t().dot(dense.p.col(last));
    s.s_a = std::min(s_first, s_last);
    s.s_b = std::max(s_first, s_last);
    if (s.s_b - s.s_a < c.min_length) continue;
    segs.push_back(std::move(s));
    fits.push_back(fit);
  }

  std::vector<EndEstimate> ends_a(segs.size()), ends_b(segs.size());
  for (std::size_t k = 0; k < segs.size(); ++k) {
    Segment& s = segs[k];
    const LineFit& fit = fits[k];
    const double sigma2 = std::max(fit.rms * fit.rms * fit.n / std::max(1, fit.n - 2), c.range_sigma * c.range_sigma);
    // Which beam end is the s_a end: s decreases as the bearing grows when
    // t·(beam direction) does, so compare the two ends directly.
    const bool first_is_a = fit.t().dot(scan.p.col(s.first)) <= fit.t().dot(scan.p.col(s.last));
    const int beam_a = first_is_a ? s.first : s.last, step_a = first_is_a ? -1 : 1;
    const int beam_b = first_is_a ? s.last : s.first, step_b = -step_a;
    s.end_a = classify_end(scan, segs, fits, k, beam_a, step_a, s.s_a, c);
    s.end_b = classify_end(scan, segs, fits, k, beam_b, step_b, s.s_b, c);
    s.C.topLeftCorner<2, 2>() = line_covariance(fit, sigma2, c);
    ends_a[k] = end_estimate(scan, segs, fit, k, beam_a, step_a, s.s_a, s.end_a, sigma2, c);
    ends_b[k] = end_estimate(scan, segs, fit, k, beam_b, step_b, s.s_b, s.end_b, sigma2, c);
  }
  // Applied after all ends are classified: corner tests use the inlier ends.
  for (std::size_t k = 0; k < segs.size(); ++k) {
    segs[k].s_a = ends_a[k].s;
    segs[k].s_b = ends_b[k].s;
    segs[k].C(2, 2) = ends_a[k].variance;
    segs[k].C(3, 3) = ends_b[k].variance;
  }
  return segs;
}

std::optional<double> range_noise_of_segment(const Segment& segment, double max_incidence) {
  constexpr int kMinPoints = 20;
  const Vec2 u(std::cos(segment.alpha), std::sin(segment.alpha));  // the line's normal
  const double min_cos = std::cos(max_incidence);
  double sum = 0.0;
  int n = 0;
  for (Eigen::Index i = 0; i < segment.inliers.cols(); ++i) {
    const Vec2 p = segment.inliers.col(i);
    const double range = p.norm();
    if (range <= 0.0) continue;
    const double cos_incidence = std::abs(u.dot(p)) / range;  // beam direction · normal
    if (cos_incidence < min_cos) continue;
    const double along_beam = (u.dot(p) - segment.rho) / cos_incidence;
    sum += along_beam * along_beam;
    ++n;
  }
  if (n < kMinPoints) return std::nullopt;
  return std::sqrt(sum / (n - 2));
}

void RangeNoiseTracker::add(const std::vector<Segment>& segments, double max_incidence) {
  for (const Segment& s : segments)
    if (const auto sigma = range_noise_of_segment(s, max_incidence)) {
      samples_.push_back(*sigma);
      if (samples_.size() > kWindow) samples_.pop_front();
    }
}

std::optional<double> RangeNoiseTracker::median() const {
  if (samples_.size() < kMinSamples) return std::nullopt;
  std::vector<double> sorted(samples_.begin(), samples_.end());
  const auto middle = sorted.begin() + static_cast<std::ptrdiff_t>(sorted.size() / 2);
  std::nth_element(sorted.begin(), middle, sorted.end());
  return *middle;
}

}  // namespace mspace::laser_lines
