// scan_matcher.cpp — see scan_matcher.hpp.
#include "scan_matcher.hpp"

#include <Eigen/Dense>
#include <algorithm>
#include <cmath>
#include <limits>
#include <numbers>
#include <numeric>

namespace mspace::scan_matching {
namespace {

constexpr double kTwoPi = 2.0 * std::numbers::pi;

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
  // Closed form of the 2 × 2 eigenproblem: the smallest eigenvalue is
  // (a + c)/2 − √(((a − c)/2)² + b²) (the mean squared distance from the
  // line); the line's direction is at φ = ½ atan2(2b, a − c), the normal
  // perpendicular to it.
  const double a = scatter(0, 0), b = scatter(0, 1), c = scatter(1, 1);
  const double half_diff = 0.5 * (a - c);
  const double smallest = 0.5 * (a + c) - std::sqrt(half_diff * half_diff + b * b);
  const double phi = 0.5 * std::atan2(2.0 * b, a - c);
  return {Eigen::Vector2d(-std::sin(phi), std::cos(phi)), std::sqrt(std::max(0.0, smallest))};
}

double median_of(std::vector<double> v) {
  if (v.empty()) return 0.0;
  const auto mid = v.begin() + static_cast<long>(v.size() / 2);
  std::nth_element(v.begin(), mid, v.end());
  return *mid;
}

/// Correspondence distance at iteration `i`: from `max` down to `min` over the
/// first half of the iterations, then `min`.
double correspondence_distance(double max, double min, int max_iterations, int i) {
  const double half = std::max(1.0, 0.5 * max_iterations);
  const double f = std::min(1.0, i / half);
  return max + f * (min - max);
}

/// Every k-th point so that at most `limit` remain (k ≥ 1), beam order kept.
ScanPoints subsample(const ScanPoints& points, int limit) {
  if (limit <= 0 || static_cast<int>(points.size()) <= limit) return points;
  const double stride = static_cast<double>(points.size()) / limit;
  ScanPoints out;
  out.reserve(static_cast<std::size_t>(limit));
  for (int i = 0; i < limit; ++i) out.push_back(points[static_cast<std::size_t>(i * stride)]);
  return out;
}

/// Position of the first of the `count` points (xs[k], ys[k]) nearest to q,
/// or −1 if none is nearer than infinity (q not finite). The same answer as
/// scanning them in order for a strictly smaller squared distance.
int first_nearest(const double* xs, const double* ys, int count, const Eigen::Vector2d& q) {
  int best = -1;
  double best_d2 = std::numeric_limits<double>::infinity();
  for (int k = 0; k < count; ++k) {
    const double dx = xs[k] - q.x(), dy = ys[k] - q.y();
    const double d2 = dx * dx + dy * dy;
    if (d2 < best_d2) {
      best_d2 = d2;
      best = k;
    }
  }
  return best;
}

/// The same for a fixed count (a power of two), written so that the compiler
/// computes the distances and their minimum two at a time: the smallest
/// squared distance by halving, then the first point at it. The distances
/// are the same operations as above, and minima and equality are exact, so
/// the answer is the same.
template <int kCount>
int first_nearest(const double* xs, const double* ys, const Eigen::Vector2d& q) {
  static_assert(kCount > 0 && (kCount & (kCount - 1)) == 0);
  double d2[kCount], lowest[kCount];
  for (int k = 0; k < kCount; ++k) {
    const double dx = xs[k] - q.x(), dy = ys[k] - q.y();
    lowest[k] = d2[k] = dx * dx + dy * dy;
  }
  for (int half = kCount / 2; half > 0; half /= 2)
    for (int k = 0; k < half; ++k) lowest[k] = lowest[k + half] < lowest[k] ? lowest[k + half] : lowest[k];
  if (!(lowest[0] < std::numeric_limits<double>::infinity())) return -1;
  int first = 0;  // found without branching on which it is (that is unpredictable)
  for (int k = kCount - 1; k >= 0; --k) first = d2[k] == lowest[0] ? k : first;
  return first;
}

}  // namespace

Eigen::Vector3d compose(const Eigen::Vector3d& a, const Eigen::Vector3d& b) {
  const Eigen::Vector2d t = a.head<2>() + rotation(a[2]) * b.head<2>();
  return {t.x(), t.y(), wrap(a[2] + b[2])};
}

Eigen::Vector3d inverse(const Eigen::Vector3d& a) {
  const Eigen::Vector2d t = -(rotation(a[2]).transpose() * a.head<2>());
  return {t.x(), t.y(), wrap(-a[2])};
}

ScanPoints scan_to_points(const std::vector<double>& ranges, const std::vector<double>& bearings,
                          double max_range) {
  ScanPoints points;
  points.reserve(ranges.size());
  for (std::size_t i = 0; i < ranges.size() && i < bearings.size(); ++i) {
    const double r = ranges[i];
    if (!(r > 0.0) || !(r < max_range) || !std::isfinite(bearings[i])) continue;
    points.emplace_back(r * std::cos(bearings[i]), r * std::sin(bearings[i]));
  }
  return points;
}

// ---- Reference scan: normals, bearing index, noise --------------------------

ReferenceScan::ReferenceScan(const ScanPoints& points, const MatchOptions& options)
    : options_(options), all_points_(points) {
  const auto n = static_cast<int>(points.size());
  // Beam spacing δ: the median angle between consecutive returns (no-return
  // beams make some gaps multiples of δ; the median ignores them). It is
  // measured, not configured, so 0.25°–1° lasers and varying start angles
  // need no setting.
  std::vector<double> steps, bearing(static_cast<std::size_t>(n));
  for (int i = 0; i < n; ++i) {
    const auto& p = points[static_cast<std::size_t>(i)];
    bearing[static_cast<std::size_t>(i)] = std::atan2(p.y(), p.x());
    max_range_ = std::max(max_range_, p.norm());
  }
  for (int i = 1; i < n; ++i) {
    const double d = std::abs(wrap(bearing[static_cast<std::size_t>(i)] - bearing[static_cast<std::size_t>(i - 1)]));
    if (d > 1e-9) steps.push_back(d);
  }
  spacing_ = steps.empty() ? std::numbers::pi / 180.0 : median_of(steps);

  // Normals: up to `normal_neighbours` beams on each side, walking out while
  // consecutive points are closer than beam_gap(range) (a wall seen at a
  // grazing angle or far away has sparse beams).
  std::vector<Eigen::Vector2d> neighbourhood;
  struct Fit {
    int index;
    Eigen::Vector2d normal;
    double rms;
  };
  std::vector<Fit> fits;
  std::vector<double> rms_all;
  for (int i = 0; i < n; ++i) {
    const auto& p = points[static_cast<std::size_t>(i)];
    neighbourhood.assign(1, p);
    const double max_gap = beam_gap(p.norm());
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
    // The RMS of m points about their own fitted line underestimates σ by
    // √((m − 2)/m) (two line parameters fitted).
    const double m = static_cast<double>(neighbourhood.size());
    const double sigma = rms * std::sqrt(m / (m - 2.0));
    fits.push_back({i, normal, sigma});
    rms_all.push_back(sigma);
  }
  // σ_n: most neighbourhoods lie on walls, so the median fit RMS is the range
  // noise (corners and clutter are the minority above it).
  noise_ = median_of(rms_all);
  const double line_limit = std::max(options_.max_line_rms, options_.line_rms_factor * noise_);
  min_correspondence_ = std::max(options_.min_correspondence, 4.0 * noise_);
  huber_ = std::max(options_.huber, 1.5 * noise_);
  point_sigma_ = std::max(options_.point_sigma, noise_);
  max_rms_ = std::max(options_.max_rms, 3.0 * noise_);

  std::vector<int> order;
  for (std::size_t k = 0; k < fits.size(); ++k)
    if (fits[k].rms <= line_limit) order.push_back(static_cast<int>(k));
  std::sort(order.begin(), order.end(), [&](int a, int b) {
    return bearing[static_cast<std::size_t>(fits[static_cast<std::size_t>(a)].index)] <
           bearing[static_cast<std::size_t>(fits[static_cast<std::size_t>(b)].index)];
  });
  std::vector<double> usable_bearings;
  for (int k : order) {
    const Fit& f = fits[static_cast<std::size_t>(k)];
    const auto& p = points[static_cast<std::size_t>(f.index)];
    points_.push_back(p);
    ranges_.push_back(p.norm());
    normals_.push_back(f.normal);
    usable_bearings.push_back(bearing[static_cast<std::size_t>(f.index)]);
  }
  bearings_ = BearingIndex(std::move(usable_bearings));
  if (n > 0) {
    min_bearing_ = *std::min_element(bearing.begin(), bearing.end());
    max_bearing_ = *std::max_element(bearing.begin(), bearing.end());
  }
  full_circle_ = max_bearing_ - min_bearing_ > kTwoPi - 3.0 * spacing_;
  // Every beam by bearing (ties by range), for the free-space check.
  std::vector<std::pair<double, double>> beams;
  beams.reserve(static_cast<std::size_t>(n));
  for (int i = 0; i < n; ++i)
    beams.emplace_back(bearing[static_cast<std::size_t>(i)], points[static_cast<std::size_t>(i)].norm());
  std::sort(beams.begin(), beams.end());
  std::vector<double> beam_bearings;
  beam_bearings.reserve(beams.size());
  beam_ranges_.reserve(beams.size());
  for (const auto& [b, range] : beams) {
    beam_bearings.push_back(b);
    beam_ranges_.push_back(range);
  }
  beam_bearings_ = BearingIndex(std::move(beam_bearings));
  pad_window();
}

void ReferenceScan::pad_window() {
  // Padded position k holds usable point k − w: around the circle for a
  // full-circle scan (as the window wraps), else a point at infinity, never
  // the nearest.
  const int n = static_cast<int>(points_.size());
  const int w = std::max(1, options_.association_window);
  const double far = std::numeric_limits<double>::infinity();
  window_x_.assign(static_cast<std::size_t>(n + 2 * w), far);
  window_y_.assign(static_cast<std::size_t>(n + 2 * w), far);
  for (int k = 0; k < n + 2 * w; ++k) {
    int j = k - w;
    if (full_circle_ && n > 0) j = ((j % n) + n) % n;
    if (j < 0 || j >= n) continue;
    window_x_[static_cast<std::size_t>(k)] = points_[static_cast<std::size_t>(j)].x();
    window_y_[static_cast<std::size_t>(k)] = points_[static_cast<std::size_t>(j)].y();
  }
}

bool ReferenceScan::sees_through(const Eigen::Vector2d& q, const Bearing& b, double margin) const {
  if (beam_bearings_.empty()) return false;
  const double r = q.norm();
  const auto at = static_cast<long>(beam_bearings_.first_not_below(b));
  const auto count = static_cast<long>(beam_bearings_.size());
  bool any = false;
  // A beam beside a near object's edge ends on the wall behind it: every beam
  // around q's bearing must have ended beyond q, not just the nearest.
  for (long k = at - 2; k <= at + 1; ++k) {
    if (k < 0 || k >= count) continue;
    const auto beam = static_cast<std::size_t>(k);
    if (b.farther_than(beam_bearings_[beam], 1.5 * spacing_)) continue;
    if (beam_ranges_[beam] <= r + margin) return false;
    any = true;
  }
  return any;
}

double ReferenceScan::beam_gap(double range) const {
  return std::max(options_.normal_radius, options_.gap_beams * range * spacing_);
}

bool ReferenceScan::in_view(const Eigen::Vector2d& q, const Bearing& b) const {
  if (q.squaredNorm() > max_range_ * max_range_) return false;
  if (full_circle_) return true;
  return b.at_least(min_bearing_ - 0.5 * spacing_) && b.at_most(max_bearing_ + 0.5 * spacing_);
}

int ReferenceScan::nearest_by_bearing(const Eigen::Vector2d& q) const {
  return nearest_by_bearing(q, Bearing(q.x(), q.y()));
}

int ReferenceScan::nearest_by_bearing(const Eigen::Vector2d& q, const Bearing& b) const {
  return nearest_in_window(q, static_cast<int>(bearings_.first_not_below(b)));
}

int ReferenceScan::nearest_in_window(const Eigen::Vector2d& q, int at) const {
  const int n = static_cast<int>(points_.size());
  if (n == 0) return -1;
  // Projective association: the reference beams around q's bearing are the
  // ones that could have seen q; the nearest of them is its partner. The
  // window [at − w, at + w) starts at padded position `at` (pad_window), the
  // first of equally near beams in it wins.
  const int w = std::max(1, options_.association_window);
  const double* xs = window_x_.data() + at;
  const double* ys = window_y_.data() + at;
  const int k = w == 4 ? first_nearest<8>(xs, ys, q) : first_nearest(xs, ys, 2 * w, q);
  if (k < 0) return -1;
  const int j = at - w + k;
  return full_circle_ ? ((j % n) + n) % n : j;
}

// ---- Moving objects -----------------------------------------------------------

int ReferenceScan::drop_moving(const ScanPoints& older, const Eigen::Vector3d& older_pose) {
  if (older.empty() || points_.empty()) return 0;
  // The older points by bearing in their own frame; each reference point is
  // moved into that frame, p_o = R_oᵀ (p − t_o) with its normal n_o = R_oᵀ n,
  // and compared with the older points around its bearing there.
  std::vector<std::pair<double, Eigen::Vector2d>> by_bearing;
  by_bearing.reserve(older.size());
  for (const auto& o : older) by_bearing.emplace_back(std::atan2(o.y(), o.x()), o);
  std::sort(by_bearing.begin(), by_bearing.end(), [](const auto& a, const auto& b) { return a.first < b.first; });
  const Eigen::Matrix2d Rt = rotation(older_pose[2]).transpose();
  const double t = std::max(options_.moving_distance, 4.0 * noise_);
  const int w = std::max(1, options_.association_window);
  std::vector<char> keep(points_.size(), 0);
  int dropped = 0;
  for (std::size_t i = 0; i < points_.size(); ++i) {
    const Eigen::Vector2d p = Rt * (points_[i] - older_pose.head<2>());
    const Eigen::Vector2d n = Rt * normals_[i];
    const double b = std::atan2(p.y(), p.x());
    // Along the line, sparse far beams put the nearest older beam on the same
    // wall up to half a beam spacing away (1.5 ρ δ leaves room for the
    // increment's own heading error).
    const double along = std::max(t, 1.5 * p.norm() * spacing_);
    const auto at = std::lower_bound(by_bearing.begin(), by_bearing.end(), b,
                                     [](const auto& e, double v) { return e.first < v; }) -
                    by_bearing.begin();
    const auto count = static_cast<long>(by_bearing.size());
    for (long k = std::max(0L, at - w); k < std::min(count, at + w); ++k) {
      const Eigen::Vector2d d = by_bearing[static_cast<std::size_t>(k)].second - p;
      if (std::abs(n.dot(d)) <= t && d.squaredNorm() <= along * along) {
        keep[i] = 1;
        break;
      }
    }
    dropped += keep[i] ? 0 : 1;
  }
  // Many inconsistent points: the older pose (the previous increment) is
  // wrong, or the scene changed wholesale; then nothing is known to move.
  if (dropped > options_.moving_max_fraction * static_cast<double>(points_.size())) return 0;
  std::size_t j = 0;
  std::vector<double> kept_bearings;
  kept_bearings.reserve(points_.size());
  for (std::size_t i = 0; i < points_.size(); ++i) {
    if (!keep[i]) continue;
    points_[j] = points_[i];
    ranges_[j] = ranges_[i];
    normals_[j] = normals_[i];
    kept_bearings.push_back(bearings_[i]);
    ++j;
  }
  points_.resize(j);
  ranges_.resize(j);
  normals_.resize(j);
  bearings_ = BearingIndex(std::move(kept_bearings));
  pad_window();
  return dropped;
}

// ---- Heading search ----------------------------------------------------------

Eigen::Vector3d ReferenceScan::heading_search(const ScanPoints& current, const Eigen::Vector3d& seed) const {
  Eigen::Vector3d best = seed;
  if (options_.heading_search <= 0.0 || points_.empty()) return best;
  // Overlap score Σ (1 − (d/R)²) over current points whose distance d to
  // their partner is below R = max(search_radius, ρ_p · δ) (one beam spacing
  // where beams are sparser than search_radius). At most 180 points are
  // scored: a heading needs the scene's shape, not every beam.
  const ScanPoints scored = subsample(current, 180);
  const double R = options_.search_radius;
  auto score = [&](const Eigen::Vector3d& T) {
    const Eigen::Matrix2d Rot = rotation(T[2]);
    double s = 0.0;
    for (const auto& q : scored) {
      const Eigen::Vector2d moved = Rot * q + T.head<2>();
      const int j = nearest_by_bearing(moved);
      if (j < 0) continue;
      const Eigen::Vector2d& p = points_[static_cast<std::size_t>(j)];
      const double d = (moved - p).norm();
      const double radius = std::max(R, ranges_[static_cast<std::size_t>(j)] * spacing_);
      if (d >= radius) continue;
      s += 1.0 - (d / radius) * (d / radius);
    }
    return s;
  };
  double best_score = score(seed);
  const int steps = static_cast<int>(std::ceil(options_.heading_search / options_.heading_search_step));
  for (int k = -steps; k <= steps; ++k) {
    if (k == 0) continue;
    Eigen::Vector3d T = seed;
    T[2] += k * options_.heading_search_step;
    const double s = score(T);
    if (s > best_score) {
      best_score = s;
      best = T;
    }
  }
  return best;
}

// ---- Correlative search (Olson 2009) ----------------------------------------

Eigen::Vector3d ReferenceScan::correlative_search(const ScanPoints& current, const Eigen::Vector3d& seed) const {
  const double res = std::max(options_.correlative_resolution, 2.0 * noise_);
  const int k = std::max(1, options_.correlative_coarse);
  const double cmax = options_.correlative_max_range;
  const int window = static_cast<int>(std::ceil(options_.correlative_xy / res));  // fine offsets ± window
  const int kernel = 2;                                                           // cells of the likelihood kernel

  // Samples of the reference surface: the points, and points along the
  // segment between consecutive beams on one surface (closer than the beam
  // gap), so sparse far beams draw a continuous wall, not dots.
  std::vector<Eigen::Vector2d> samples;
  for (std::size_t i = 0; i < all_points_.size(); ++i) {
    const auto& p = all_points_[i];
    if (p.norm() > cmax) continue;
    samples.push_back(p);
    if (i + 1 < all_points_.size()) {
      const auto& q = all_points_[i + 1];
      const double d = (q - p).norm();
      if (q.norm() <= cmax && d <= beam_gap(p.norm()) && d > res) {
        const int m = static_cast<int>(std::ceil(d / (0.5 * res)));
        for (int s = 1; s < m; ++s) samples.push_back(p + (q - p) * (static_cast<double>(s) / m));
      }
    }
  }
  if (samples.empty()) return seed;
  Eigen::Vector2d lo = samples.front(), hi = samples.front();
  for (const auto& s : samples) {
    lo = lo.cwiseMin(s);
    hi = hi.cwiseMax(s);
  }
  // Margin: the search window, a coarse block and the kernel, so that every
  // scored cell index stays inside the grid.
  const int margin = window + k + kernel + 1;
  lo.array() -= margin * res;
  hi.array() += margin * res;
  const int nx = static_cast<int>(std::ceil((hi.x() - lo.x()) / res)) + 1;
  const int ny = static_cast<int>(std::ceil((hi.y() - lo.y()) / res)) + 1;
  // Likelihood grid: exp(−d²/2s²) of the distance to the nearest surface
  // sample, s = one cell (the max over samples within the kernel).
  std::vector<float> grid(static_cast<std::size_t>(nx) * static_cast<std::size_t>(ny), 0.0f);
  auto at = [nx](int ix, int iy) { return static_cast<std::size_t>(iy) * static_cast<std::size_t>(nx) + static_cast<std::size_t>(ix); };
  for (const auto& s : samples) {
    const double fx = (s.x() - lo.x()) / res, fy = (s.y() - lo.y()) / res;
    const int cx = static_cast<int>(std::floor(fx)), cy = static_cast<int>(std::floor(fy));
    for (int iy = cy - kernel; iy <= cy + kernel; ++iy)
      for (int ix = cx - kernel; ix <= cx + kernel; ++ix) {
        const double dx = ix + 0.5 - fx, dy = iy + 0.5 - fy;
        const auto v = static_cast<float>(std::exp(-0.5 * (dx * dx + dy * dy)));
        float& cell = grid[at(ix, iy)];
        cell = std::max(cell, v);
      }
  }
  // Max-pooled grid (Cartographer's precomputation grid): pooled(i, j) = max
  // of grid over the k × k cells from (i, j). A block of fine offsets
  // {o, …, o + k − 1}² then scores at most Σ pooled(cell + o): the coarse
  // score bounds every fine score in its block, which makes the branch and
  // bound below exact.
  std::vector<float> rows(grid.size(), 0.0f), pooled(grid.size(), 0.0f);
  for (int iy = 0; iy < ny; ++iy)
    for (int ix = 0; ix < nx; ++ix) {
      float m = 0.0f;
      for (int d = 0; d < k && ix + d < nx; ++d) m = std::max(m, grid[at(ix + d, iy)]);
      rows[at(ix, iy)] = m;
    }
  for (int iy = 0; iy < ny; ++iy)
    for (int ix = 0; ix < nx; ++ix) {
      float m = 0.0f;
      for (int d = 0; d < k && iy + d < ny; ++d) m = std::max(m, rows[at(ix, iy + d)]);
      pooled[at(ix, iy)] = m;
    }

  ScanPoints scored;
  for (const auto& q : current)
    if (q.norm() <= cmax) scored.push_back(q);
  scored = subsample(scored, options_.correlative_max_points);
  if (scored.empty()) return seed;
  double far = 0.0;
  for (const auto& q : scored) far = std::max(far, q.norm());
  // Heading step: the farthest scored point moves by at most one cell.
  const double dtheta = std::max(res / std::max(far, res), 1e-4);
  const int nth = static_cast<int>(std::ceil(options_.correlative_theta / dtheta));
  const int blocks = (2 * window + 1 + k - 1) / k;  // coarse blocks per axis

  struct Candidate {
    float score;
    int th, bx, by;
  };
  std::vector<Candidate> candidates;
  candidates.reserve(static_cast<std::size_t>(2 * nth + 1) * static_cast<std::size_t>(blocks * blocks));
  std::vector<std::vector<std::size_t>> cells(static_cast<std::size_t>(2 * nth + 1));
  for (int t = -nth; t <= nth; ++t) {
    const Eigen::Matrix2d R = rotation(seed[2] + t * dtheta);
    auto& c = cells[static_cast<std::size_t>(t + nth)];
    c.reserve(scored.size());
    for (const auto& q : scored) {
      const Eigen::Vector2d m = R * q + seed.head<2>();
      const int ix = static_cast<int>(std::floor((m.x() - lo.x()) / res)) - window;
      const int iy = static_cast<int>(std::floor((m.y() - lo.y()) / res)) - window;
      // Cells that leave the grid for some offset are off the reference surface for all.
      if (ix < 0 || iy < 0 || ix + 2 * window + k >= nx || iy + 2 * window + k >= ny) continue;
      c.push_back(at(ix, iy));
    }
    for (int by = 0; by < blocks; ++by)
      for (int bx = 0; bx < blocks; ++bx) {
        const std::size_t off = at(bx * k, by * k);
        float s = 0.0f;
        for (std::size_t cell : c) s += pooled[cell + off];
        candidates.push_back({s, t, bx, by});
      }
  }
  std::sort(candidates.begin(), candidates.end(), [](const Candidate& a, const Candidate& b) { return a.score > b.score; });

  // Branch and bound: refine blocks in order of their bound until the bound
  // falls below the best fine score. A small prior on the distance from the
  // seed breaks ties (a corridor's flat direction) towards the seed.
  const double n_points = static_cast<double>(scored.size());
  double best = -std::numeric_limits<double>::infinity();
  Eigen::Vector3d best_pose = seed;
  for (const Candidate& cand : candidates) {
    if (cand.score <= best) break;
    const auto& c = cells[static_cast<std::size_t>(cand.th + nth)];
    for (int oy = cand.by * k; oy < cand.by * k + k && oy <= 2 * window; ++oy)
      for (int ox = cand.bx * k; ox < cand.bx * k + k && ox <= 2 * window; ++ox) {
        const std::size_t off = at(ox, oy);
        float s = 0.0f;
        for (std::size_t cell : c) s += grid[cell + off];
        const double dx = (ox - window) * res, dy = (oy - window) * res, dt = cand.th * dtheta;
        const double penalty = 0.01 * n_points *
                               ((dx * dx + dy * dy) / (options_.correlative_xy * options_.correlative_xy) +
                                dt * dt / (options_.correlative_theta * options_.correlative_theta));
        const double value = s - penalty;
        if (value > best) {
          best = value;
          best_pose = {seed[0] + dx, seed[1] + dy, wrap(seed[2] + dt)};
        }
      }
  }
  return best_pose;
}

// ---- ICP ---------------------------------------------------------------------

struct ReferenceScan::Local {
  Eigen::Vector3d T = Eigen::Vector3d::Zero();
  int pairs = 0, overlap = 0, iterations = 0;
  double rms = std::numeric_limits<double>::infinity();
  Eigen::Matrix3d information = Eigen::Matrix3d::Zero();
};

namespace {

/// A current point moved into one reference scan's frame, and its bearing there.
struct PlacedPoint {
  Eigen::Vector2d local;
  Bearing bearing;
};

/// The current points, moved to the estimate in the matching frame (`moved`:
/// R q + t), placed in the frame of `layer` (at layer.pose in the matching
/// frame): P⁻¹ (R q + t) = R_Pᵀ (R q + t − t_P), each with its bearing there
/// (shared by the free-space check, the overlap count and the pairing).
void place_in(const PlacedReference& layer, const std::vector<Eigen::Vector2d>& moved,
              std::vector<PlacedPoint>& out) {
  const Eigen::Matrix2d Rpt = rotation(layer.pose[2]).transpose();
  out.clear();
  for (const Eigen::Vector2d& m : moved) {
    const Eigen::Vector2d local = Rpt * (m - layer.pose.head<2>());
    out.push_back({local, Bearing(local.x(), local.y())});
  }
}

}  // namespace

ReferenceScan::Local ReferenceScan::icp(const ScanPoints& current, const Eigen::Vector3d& start,
                                        const Eigen::Vector3d& seed, const std::vector<PlacedReference>& older,
                                        double first_distance) const {
  Local out;
  Eigen::Vector3d T = start;
  // The weak prior Λ = diag(1/σ_xy², 1/σ_xy², 1/σ_θ²) on the seed keeps a
  // direction the walls do not constrain (along a corridor) where the seed put it.
  const Eigen::Vector3d prior(1.0 / (options_.seed_sigma_xy * options_.seed_sigma_xy),
                              1.0 / (options_.seed_sigma_xy * options_.seed_sigma_xy),
                              1.0 / (options_.seed_sigma_theta * options_.seed_sigma_theta));
  const double point_weight = 1.0 / (point_sigma_ * point_sigma_);
  // The references: this scan (at the identity) and the local map's older
  // scans at their poses P in this frame.
  std::vector<PlacedReference> layers{{this, Eigen::Vector3d::Zero()}};
  for (const PlacedReference& o : older)
    if (o.scan != nullptr && !o.scan->points_.empty()) layers.push_back(o);
  // Step 9: current points some reference saw through (moving), re-checked
  // every few iterations at the estimate so far.
  const double free_margin =
      options_.free_space_margin > 0.0 ? std::max(options_.free_space_margin, 10.0 * noise_) : 0.0;
  std::vector<char> moving(current.size(), 0);
  // Each iteration moves the current points to the estimate once (R q + t,
  // and ∂R/∂θ q for the Jacobians) and places them in each layer (buffers
  // kept across iterations).
  std::vector<Eigen::Vector2d> moved(current.size()), turned(current.size());
  std::vector<std::vector<PlacedPoint>> placed(layers.size());
  // Per layer: where each point's bearing falls among the layer's (the
  // window of its look-up), then the index of its partner there (or −1).
  std::vector<int> window(current.size()), partner(current.size());
  auto mark_moving = [&] {
    for (std::size_t i = 0; i < current.size(); ++i) {
      moving[i] = 0;
      for (std::size_t l = 0; l < layers.size() && !moving[i]; ++l)
        moving[i] = layers[l].scan->sees_through(placed[l][i].local, placed[l][i].bearing, free_margin);
    }
  };
  // Current points inside some layer's view, counted (once, for the result)
  // at the placement of the last iteration.
  auto count_overlap = [&] {
    int overlap = 0;
    for (std::size_t l = 0; l < layers.size(); ++l)
      for (const PlacedPoint& p : placed[l]) overlap += layers[l].scan->in_view(p.local, p.bearing) ? 1 : 0;
    return overlap;
  };
  for (int it = 0; it < options_.max_iterations; ++it) {
    const Eigen::Matrix2d R = rotation(T[2]);
    const Eigen::Matrix2d dR = rotation(T[2] + 0.5 * std::numbers::pi);  // ∂R/∂θ
    for (std::size_t i = 0; i < current.size(); ++i) {
      moved[i] = R * current[i] + T.head<2>();
      turned[i] = dR * current[i];
    }
    for (std::size_t l = 0; l < layers.size(); ++l) place_in(layers[l], moved, placed[l]);
    if (free_margin > 0.0 && it % 5 == 0) mark_moving();
    const double max_distance =
        correspondence_distance(std::max(first_distance > 0.0 ? first_distance : options_.max_correspondence,
                                         min_correspondence_),
                                min_correspondence_,
                                options_.max_iterations, it);
    Eigen::Matrix3d H = Eigen::Matrix3d::Zero(), H_own = Eigen::Matrix3d::Zero();
    Eigen::Vector3d g = Eigen::Vector3d::Zero();
    double weighted_r2 = 0.0, weight_sum = 0.0;
    int pairs = 0;
    for (std::size_t l = 0; l < layers.size(); ++l) {
      const PlacedReference& layer = layers[l];
      const ReferenceScan& ref = *layer.scan;
      const double layer_weight = layer.scan == this ? 1.0 : options_.local_map_weight;
      // A point q' in this frame is P⁻¹ q' = R_Pᵀ (q' − t_P) in the layer's
      // own frame (place_in), where it is paired by bearing (that scan's beams
      // could have seen it). Its partner's normal n there is R_P n here.
      const Eigen::Matrix2d Rp = rotation(layer.pose[2]);
      // The look-ups in passes of their own: independent of each other, they
      // overlap in the processor instead of waiting on each pair's arithmetic.
      for (std::size_t i = 0; i < current.size(); ++i)
        window[i] = static_cast<int>(ref.bearings_.first_not_below(placed[l][i].bearing));
      for (std::size_t i = 0; i < current.size(); ++i)
        partner[i] = moving[i] ? -1 : ref.nearest_in_window(placed[l][i].local, window[i]);
      for (std::size_t i = 0; i < current.size(); ++i) {
        const int j = partner[i];
        if (j < 0) continue;
        const Eigen::Vector2d& local = placed[l][i].local;
        const Eigen::Vector2d& p = ref.points_[static_cast<std::size_t>(j)];
        const Eigen::Vector2d d = local - p;
        const Eigen::Vector2d& n_local = ref.normals_[static_cast<std::size_t>(j)];
        const double r = n_local.dot(d);  // across the line
        // Gate: the point-to-line residual within the correspondence distance,
        // and the partner within that distance too or, where the beams are
        // sparser (far away), within gate_beams beam spacings at its range: the
        // nearest beam on the same wall can be that far along it.
        const double gate =
            std::max(max_distance, options_.gate_beams * ref.ranges_[static_cast<std::size_t>(j)] * ref.spacing_);
        if (std::abs(r) > max_distance || d.squaredNorm() > gate * gate) continue;
        const double w = layer_weight * (std::abs(r) <= huber_ ? 1.0 : huber_ / std::abs(r));
        // ∂r/∂(dx, dy, dθ) = (n'ᵀ, n'ᵀ ∂R/∂θ q) with n' = R_P n (eq. of the
        // residual n'ᵀ(R q + t − R_P p − t_P)).
        const Eigen::Vector2d n = Rp * n_local;
        const Eigen::Vector3d J(n.x(), n.y(), n.dot(turned[i]));
        H.noalias() += w * J * J.transpose();
        if (l > 0 && layer.scan == this) H_own.noalias() += w * J * J.transpose();
        g += w * J * r;
        weighted_r2 += w * r * r;
        weight_sum += w;
        ++pairs;
      }
      // Layer 0 is this scan: H holds exactly its pairs' sum so far.
      if (l == 0) H_own = H;
    }
    out.pairs = pairs;
    out.iterations = it + 1;
    out.T = T;
    // The key scans pair the same current points again: their residuals
    // share the current scan's noise and are no independent evidence, so the
    // information reported (and the covariance) counts this scan's pairs only.
    out.information = point_weight * H_own;
    if (pairs < std::max(3, options_.min_pairs)) {
      out.rms = std::numeric_limits<double>::infinity();
      out.overlap = count_overlap();
      return out;
    }
    out.rms = std::sqrt(weighted_r2 / weight_sum);
    // Gauss–Newton step on  Σ w r²/σ_p² + (T − seed)ᵀ Λ (T − seed).
    const Eigen::Matrix3d A = point_weight * H + Eigen::Matrix3d(prior.asDiagonal());
    const Eigen::Vector3d b = point_weight * g + prior.cwiseProduct(T - seed);
    const Eigen::Vector3d step = -A.ldlt().solve(b);
    T += step;
    T[2] = wrap(T[2]);
    out.T = T;
    const bool at_final_distance = max_distance <= min_correspondence_ + 1e-12;
    if (at_final_distance && step.head<2>().norm() < options_.converged_step &&
        std::abs(step[2]) < options_.converged_step)
      break;
  }
  out.overlap = count_overlap();
  return out;
}

MatchResult ReferenceScan::match(const ScanPoints& all_current, const Eigen::Vector3d& seed,
                                 const std::vector<PlacedReference>& older) const {
  // Neighbouring beams of a dense scan (0.25°) on one wall add little: at most
  // max_points evenly spread beams are matched.
  // A local map that cannot be matched (its key scans misplaced by an
  // earlier error, or showing another room) must not cost the increment:
  // the previous scan alone decides then.
  if (!older.empty()) {
    MatchResult with_map = match_once(all_current, seed, older);
    if (with_map.ok) return with_map;
  }
  return match_once(all_current, seed, {});
}

MatchResult ReferenceScan::match_once(const ScanPoints& all_current, const Eigen::Vector3d& seed,
                                      const std::vector<PlacedReference>& older) const {
  const ScanPoints current = subsample(all_current, options_.max_points);
  MatchResult result;
  result.noise = noise_;
  result.increment = seed;
  auto ok = [&](const Local& l) {
    const double needed = std::max(static_cast<double>(options_.min_pairs), options_.min_pair_fraction * l.overlap);
    return l.pairs >= needed && l.rms <= max_rms_;
  };
  auto weak = [&](const Local& l) { return !ok(l) || l.pairs < options_.weak_pair_fraction * l.overlap; };

  Local best = icp(current, heading_search(current, seed), seed, older);
  bool from_correlative = false;
  if (options_.correlative && weak(best)) {
    const Local other = icp(current, correlative_search(current, seed), seed, older);
    // The better match: a valid one over an invalid one; between two valid
    // ones the correlative one only with clearly more pairs (a quarter more):
    // with about as many, the scene is ambiguous and the match nearer the
    // seed (the local one) is the safer choice.
    if ((ok(other) && !ok(best)) || (ok(other) && ok(best) && other.pairs > 1.25 * best.pairs) ||
        (!ok(other) && !ok(best) && other.pairs > best.pairs)) {
      best = other;
      from_correlative = true;
    }
  }
  // Consistency with the seed: e = T − seed, d² = eᵀ S⁻¹ e with S the seed's
  // covariance diag(σ_xy², σ_xy², σ_θ²). A match the scans alone pulled
  // further than that (moving people, which a wall-less corridor direction
  // lets drag the whole scan along) is replaced by the match from the seed
  // whose correspondences never reach beyond min_correspondence: the moving
  // points, displaced by more than that, stay unpaired and the static ones
  // decide. If that match fails, the seed is kept (ok = false).
  if (options_.seed_gate > 0.0 && ok(best)) {
    auto disagrees = [&](const Local& l) {
      Eigen::Vector3d e = l.T - seed;
      e[2] = wrap(e[2]);
      const double sxy2 = options_.seed_sigma_xy * options_.seed_sigma_xy;
      const double sth2 = options_.seed_sigma_theta * options_.seed_sigma_theta;
      return (e[0] * e[0] + e[1] * e[1]) / sxy2 + e[2] * e[2] / sth2 > options_.seed_gate;
    };
    if (disagrees(best)) {
      best = icp(current, seed, seed, older, min_correspondence_);
      from_correlative = false;
      result.disagreed = true;
      // Still pulled beyond the seed's uncertainty (something moving by less
      // than min_correspondence per scan): the seed is the better estimate.
      if (disagrees(best)) best.rms = std::numeric_limits<double>::infinity();
    }
  }
  result.pairs = best.pairs;
  result.overlap = best.overlap;
  result.rms = std::isfinite(best.rms) ? best.rms : 0.0;
  result.iterations = best.iterations;
  result.correlative = from_correlative;
  result.information = best.information;
  result.ok = ok(best);
  if (result.ok) result.increment = best.T;
  const Eigen::Vector3d prior(1.0 / (options_.seed_sigma_xy * options_.seed_sigma_xy),
                              1.0 / (options_.seed_sigma_xy * options_.seed_sigma_xy),
                              1.0 / (options_.seed_sigma_theta * options_.seed_sigma_theta));
  // Covariance of the increment: the pairs' information at the residual
  // scale this match measured, s² = max(rms, σ_n)² (it holds both scans' noise
  // and whatever the line model misses: clutter, corners), in place of the
  // nominal point_sigma; deflated for the correlation of neighbouring beams on
  // one wall (information_deflation, calibrated so that the increments' NEES
  // is 3 on simulated buildings); plus the seed prior.
  const double scale = std::max(result.rms, noise_);
  const double to_measured = scale > 0.0 ? point_sigma_ * point_sigma_ / (scale * scale) : 1.0;
  Eigen::Matrix3d info = result.ok ? Eigen::Matrix3d(best.information * to_measured / options_.information_deflation)
                                   : Eigen::Matrix3d::Zero();
  // A direction with next to no information (below 1e-3 of the trace: along a
  // featureless corridor) holds only what the fitted normals' own noise puts
  // there; it is left to the seed prior rather than claimed.
  if (result.ok) {
    const Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> split(info);
    Eigen::Vector3d values = split.eigenvalues();
    for (int k = 0; k < 3; ++k)
      if (values[k] < 1e-3 * info.trace()) values[k] = 0.0;
    info = split.eigenvectors() * values.asDiagonal() * split.eigenvectors().transpose();
  }
  result.covariance = (info + Eigen::Matrix3d(prior.asDiagonal())).inverse();
  // Weakest direction: the information's smallest eigenpair, θ in metres at
  // 1 m (D = diag(1, 1, 1/1 m) leaves the numbers as they are).
  const Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> eig(best.information);
  result.weakest_information = eig.eigenvalues()[0];
  result.weakest_direction = eig.eigenvectors().col(0);
  return result;
}

// ---- Mounted laser ------------------------------------------------------------

Eigen::Vector3d LaserOdometry::robot_increment(const Eigen::Vector3d& d_l, Eigen::Matrix3d* jacobian) const {
  // Robot poses R1, R2; laser poses L = R ⊕ m. d_l = L1⁻¹ ⊕ L2 = m⁻¹ ⊕ d_r ⊕ m,
  // so d_r = m ⊕ d_l ⊕ m⁻¹:  t_r = t_m + R(φ_m) t_l − R(θ_l) t_m, θ_r = θ_l
  // (planar rotations commute).
  const Eigen::Vector3d d_r = compose(compose(mount_, d_l), inverse(mount_));
  if (jacobian != nullptr) {
    // ∂t_r/∂t_l = R(φ_m), ∂t_r/∂θ_l = −R'(θ_l) t_m, ∂θ_r/∂θ_l = 1.
    jacobian->setZero();
    jacobian->topLeftCorner<2, 2>() = rotation(mount_[2]);
    jacobian->block<2, 1>(0, 2) = -(rotation(d_l[2] + 0.5 * std::numbers::pi) * mount_.head<2>());
    (*jacobian)(2, 2) = 1.0;
  }
  return d_r;
}

Eigen::Vector3d LaserOdometry::laser_increment(const Eigen::Vector3d& d_r) const {
  return compose(compose(inverse(mount_), d_r), mount_);
}

OdometryResult LaserOdometry::match(const ScanPoints& previous, const ScanPoints& current,
                                    const Eigen::Vector3d& robot_seed) const {
  return match(ReferenceScan(previous, options_), current, robot_seed);
}

ReferenceScan LaserOdometry::reference(const ScanPoints& previous, const ScanPoints& older,
                                       const Eigen::Vector3d& robot_older_increment) const {
  ReferenceScan reference(previous, options_);
  // The older laser pose in the previous laser frame: ⊖(older → previous).
  reference.drop_moving(older, inverse(laser_increment(robot_older_increment)));
  return reference;
}

OdometryResult LaserOdometry::match(const ReferenceScan& previous, const ScanPoints& current,
                                    const Eigen::Vector3d& robot_seed, const std::vector<PlacedReference>& older) const {
  OdometryResult out;
  out.match = previous.match(current, laser_increment(robot_seed), older);
  Eigen::Matrix3d J;
  out.increment = out.match.ok ? robot_increment(out.match.increment, &J) : robot_seed;
  if (!out.match.ok) robot_increment(out.match.increment, &J);
  // C_r = J C_l Jᵀ (first order; exact for the translation part).
  out.covariance = J * out.match.covariance * J.transpose();
  return out;
}

// ---- Local map ---------------------------------------------------------------

void LocalMap::add(std::size_t index, const ScanPoints& points, const Eigen::Vector3d& robot_pose) {
  if (options_.scans <= 0) return;
  const Eigen::Vector3d laser_pose = compose(robot_pose, mount_);
  if (!keys_.empty()) {
    const Eigen::Vector3d d = compose(inverse(keys_.back().laser_pose), laser_pose);
    if (d.head<2>().norm() < options_.key_distance && std::abs(d[2]) < options_.key_turn) return;
  }
  keys_.push_back({index, ReferenceScan(points, match_options_), laser_pose});
  if (static_cast<int>(keys_.size()) > options_.scans) keys_.erase(keys_.begin());
}

std::vector<PlacedReference> LocalMap::placed(std::size_t index, const Eigen::Vector3d& robot_pose) const {
  std::vector<PlacedReference> out;
  const Eigen::Vector3d frame = inverse(compose(robot_pose, mount_));
  for (const Key& key : keys_) {
    if (key.index == index) continue;  // the reference scan itself
    const Eigen::Vector3d pose = compose(frame, key.laser_pose);
    if (pose.head<2>().norm() > options_.max_distance) continue;
    out.push_back({&key.scan, pose});
  }
  return out;
}

}  // namespace mspace::scan_matching
