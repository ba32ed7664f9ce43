// scan_evidence.cpp — the likelihood field of old scans and the exhaustive
// multi-resolution placement search (scan_evidence.hpp).
#include "scan_evidence.hpp"

#include <algorithm>
#include <cmath>
#include <numbers>
#include <limits>
#include <queue>

namespace mspace::kernel {

namespace {

/// Root blocks are at most 2^kMaxLevel cells wide.
constexpr int kMaxLevel = 6;
/// A search that has to open more blocks than this gives up and reports its
/// best placement as ambiguous (a featureless window: everything fits).
constexpr int kMaxOpened = 30000;
/// Every this many-th old beam marks the space it crossed as seen empty
/// (neighbouring beams of a scan cross nearly the same cells).
constexpr std::size_t kEmptyRayStride = 2;

Eigen::Matrix2d rotation(double theta) {
  const double c = std::cos(theta), s = std::sin(theta);
  Eigen::Matrix2d R;
  R << c, -s, s, c;
  return R;
}

}  // namespace

std::vector<Eigen::Vector2f> scan_end_points(const Eigen::MatrixXd& range_bearing, const Pose6& mount,
                                             double max_range, double spacing) {
  std::vector<Eigen::Vector2f> out;
  const Eigen::Matrix2d R = rotation(mount[kTheta]);
  const Eigen::Vector2d at(mount[kX], mount[kY]);
  Eigen::Vector2d last(std::nan(""), std::nan(""));
  for (Eigen::Index i = 0; i < range_bearing.rows(); ++i) {
    const double r = range_bearing(i, 0), b = range_bearing(i, 1);
    if (!std::isfinite(r) || !std::isfinite(b) || r <= 0.0 || (max_range > 0.0 && r >= max_range)) continue;
    const Eigen::Vector2d p = at + R * Eigen::Vector2d(r * std::cos(b), r * std::sin(b));
    if (std::isfinite(last.x()) && (p - last).norm() < spacing) continue;
    out.push_back(p.cast<float>());
    last = p;
  }
  return out;
}

ScanField::ScanField(const std::vector<ScanRay>& old_rays, double resolution, double sigma, double miss)
    : resolution_(resolution) {
  if (old_rays.empty()) return;
  const double reach = 3.0 * sigma;
  Eigen::Vector2d lo = old_rays.front().to, hi = lo;
  for (const ScanRay& r : old_rays) {
    lo = lo.cwiseMin(r.to).cwiseMin(r.from);
    hi = hi.cwiseMax(r.to).cwiseMax(r.from);
  }
  origin_ = lo - Eigen::Vector2d::Constant(reach + resolution);
  width_ = static_cast<int>(std::ceil((hi.x() - origin_.x() + reach + resolution) / resolution));
  height_ = static_cast<int>(std::ceil((hi.y() - origin_.y() + reach + resolution) / resolution));
  const auto cell_index = [&](int i, int j) {
    return static_cast<std::size_t>(j) * static_cast<std::size_t>(width_) + static_cast<std::size_t>(i);
  };
  std::vector<float> field(static_cast<std::size_t>(width_) * static_cast<std::size_t>(height_), 0.0f);
  // Space seen empty: the cells a beam crosses before it comes within 3σ of
  // its end (half-cell steps along it).
  std::vector<char> seen_empty(field.size(), 0);
  for (std::size_t k = 0; k < old_rays.size(); k += kEmptyRayStride) {
    const ScanRay& r = old_rays[k];
    const Eigen::Vector2d d = r.to - r.from;
    const double length = d.norm() - reach;
    if (length <= 0.0) continue;
    const Eigen::Vector2d u = d / d.norm();
    for (double s = 0.0; s < length; s += 0.5 * resolution) {
      const Eigen::Vector2d c = (r.from + s * u - origin_) / resolution;
      seen_empty[cell_index(static_cast<int>(c.x()), static_cast<int>(c.y()))] = 1;
    }
  }
  // The nearest old end point of every cell within reach (squared distance),
  // then the field: exp is monotonic, so exp(−min d²/2σ²) is the maximum
  // over the end points, one exp per cell.
  const int r = static_cast<int>(std::ceil(reach / resolution));
  const double inv2s2 = 1.0 / (2.0 * sigma * sigma);
  std::vector<double> nearest(field.size(), std::numeric_limits<double>::infinity());
  for (const ScanRay& ray : old_rays) {
    const Eigen::Vector2d& p = ray.to;
    const Eigen::Vector2d c = (p - origin_) / resolution;
    const int ci = static_cast<int>(std::floor(c.x())), cj = static_cast<int>(std::floor(c.y()));
    for (int j = std::max(0, cj - r); j <= std::min(height_ - 1, cj + r); ++j)
      for (int i = std::max(0, ci - r); i <= std::min(width_ - 1, ci + r); ++i) {
        const Eigen::Vector2d centre = origin_ + resolution * Eigen::Vector2d(i + 0.5, j + 0.5);
        double& d2 = nearest[cell_index(i, j)];
        d2 = std::min(d2, (centre - p).squaredNorm());
      }
  }
  for (std::size_t k = 0; k < field.size(); ++k) {
    if (nearest[k] <= reach * reach)
      field[k] = static_cast<float>(std::exp(-nearest[k] * inv2s2));
    else if (seen_empty[k])
      field[k] = static_cast<float>(-miss);
  }
  levels_.push_back(std::move(field));
  // Level h: the maximum over 2^h × 2^h cells from (i, j) up, from level
  // h − 1's four blocks of half the side.
  for (int h = 1; h <= kMaxLevel; ++h) {
    const std::vector<float>& below = levels_.back();
    const int s = 1 << (h - 1);
    std::vector<float> level(below.size(), 0.0f);
    const auto at = [&](int i, int j) {
      return i < width_ && j < height_
                 ? below[static_cast<std::size_t>(j) * static_cast<std::size_t>(width_) + static_cast<std::size_t>(i)]
                 : 0.0f;
    };
    for (int j = 0; j < height_; ++j)
      for (int i = 0; i < width_; ++i)
        level[static_cast<std::size_t>(j) * static_cast<std::size_t>(width_) + static_cast<std::size_t>(i)] =
            std::max(std::max(at(i, j), at(i + s, j)), std::max(at(i, j + s), at(i + s, j + s)));
    levels_.push_back(std::move(level));
  }
}

float ScanField::bound(int h, int i, int j) const {
  const int side = 1 << h;
  if (i >= width_ || j >= height_ || i + side <= 0 || j + side <= 0) return 0.0f;
  // A block reaching below the field: the block from its edge holds all of
  // its part that lies on the field (and more): still an upper bound.
  return levels_[static_cast<std::size_t>(h)][static_cast<std::size_t>(std::max(j, 0)) * static_cast<std::size_t>(width_) +
                                              static_cast<std::size_t>(std::max(i, 0))];
}

double ScanField::score(const std::vector<Eigen::Vector2d>& points, const PlanarMotion& T) const {
  if (points.empty() || levels_.empty()) return 0.0;
  double sum = 0.0;
  for (const Eigen::Vector2d& p : points) {
    const Eigen::Vector2d c = (T.apply(p) - origin_) / resolution_;
    sum += bound(0, static_cast<int>(std::floor(c.x())), static_cast<int>(std::floor(c.y())));
  }
  return sum / static_cast<double>(points.size());
}

ScanPlacement ScanField::search(const std::vector<Eigen::Vector2d>& points, const Eigen::Vector2d& pivot,
                                const ScanSearchOptions& o) const {
  ScanPlacement out;
  if (points.empty() || levels_.empty()) return out;
  const int n = static_cast<int>(std::ceil(o.max_translation / resolution_));
  int top = 0;
  while ((1 << top) < 2 * n + 1 && top < kMaxLevel) ++top;
  const int steps = static_cast<int>(std::floor(o.max_rotation / o.rotation_step + 1e-9));
  const double inv_n = 1.0 / static_cast<double>(points.size());

  // The cell of every point at every rotation (about the pivot), translation zero.
  std::vector<std::vector<Eigen::Vector2i>> cells;
  for (int k = -steps; k <= steps; ++k) {
    const PlanarMotion T{k * o.rotation_step, Eigen::Vector2d::Zero(), pivot};
    std::vector<Eigen::Vector2i> c;
    c.reserve(points.size());
    for (const Eigen::Vector2d& p : points) {
      const Eigen::Vector2d q = (T.apply(p) - origin_) / resolution_;
      c.emplace_back(static_cast<int>(std::floor(q.x())), static_cast<int>(std::floor(q.y())));
    }
    cells.push_back(std::move(c));
  }
  const auto block_bound = [&](int rot, int h, int dx, int dy) {
    double sum = 0.0;
    for (const Eigen::Vector2i& c : cells[static_cast<std::size_t>(rot)]) sum += bound(h, c.x() + dx, c.y() + dy);
    return sum * inv_n;
  };
  // Whether a block of side 2^h from (dx, dy) has a translation inside the disc of radius n.
  const auto meets_window = [&](int h, int dx, int dy) {
    const int side = 1 << h;
    const int nx = std::clamp(0, dx, dx + side - 1), ny = std::clamp(0, dy, dy + side - 1);
    return static_cast<long>(nx) * nx + static_cast<long>(ny) * ny <= static_cast<long>(n) * n;
  };

  struct Block {
    double bound;
    int rot, h, dx, dy;
    bool operator<(const Block& b) const { return bound < b.bound; }
  };
  std::priority_queue<Block> open;
  for (int rot = 0; rot < static_cast<int>(cells.size()); ++rot)
    for (int dy = -n; dy <= n; dy += 1 << top)
      for (int dx = -n; dx <= n; dx += 1 << top)
        if (meets_window(top, dx, dy)) open.push({block_bound(rot, top, dx, dy), rot, top, dx, dy});

  struct Leaf {
    double score;
    PlanarMotion motion;
  };
  std::vector<Leaf> leaves;
  double best = 0.0;
  int opened = 0;
  bool cut = false;
  while (!open.empty()) {
    const Block b = open.top();
    if (b.bound <= 0.0 || b.bound < o.rival_ratio * best) break;
    open.pop();
    if (b.h == 0) {
      const double theta = (b.rot - steps) * o.rotation_step;
      leaves.push_back({b.bound, PlanarMotion{theta, resolution_ * Eigen::Vector2d(b.dx, b.dy), pivot}});
      best = std::max(best, b.bound);
      continue;
    }
    if (++opened > kMaxOpened) {
      cut = true;
      break;
    }
    const int s = 1 << (b.h - 1);
    for (int a = 0; a < 2; ++a)
      for (int c = 0; c < 2; ++c) {
        const int dx = b.dx + a * s, dy = b.dy + c * s;
        if (dx > n || dy > n || !meets_window(b.h - 1, dx, dy)) continue;
        open.push({block_bound(b.rot, b.h - 1, dx, dy), b.rot, b.h - 1, dx, dy});
      }
  }
  out.leaves = static_cast<int>(leaves.size());
  if (leaves.empty()) return out;
  const auto top_leaf = std::max_element(leaves.begin(), leaves.end(),
                                         [](const Leaf& a, const Leaf& b) { return a.score < b.score; });
  out.found = true;
  out.best = top_leaf->motion;
  out.score = top_leaf->score;
  for (const Leaf& l : leaves) {
    const bool distinct = (l.motion.t - out.best.t).norm() > o.distinct_translation ||
                          std::abs(std::remainder(l.motion.theta - out.best.theta, 2.0 * std::numbers::pi)) > o.distinct_rotation;
    if (distinct && l.score > out.rival_score) {
      out.rival_score = l.score;
      out.rival = l.motion;
    }
  }
  if (cut) {
    out.rival_score = std::max(out.rival_score, out.score);  // not searched to the end: not unique
    return out;
  }
  // Do the placements as good as the rivals lie on one line through the best,
  // at its heading? Then the scans fix the heading and the position across
  // that line, and only the slide along it is ambiguous.
  if (out.rival_score > 0.0) {
    const auto apart = [&](const Leaf& l) { return l.motion.t - out.best.t; };
    const Leaf* farthest = nullptr;
    for (const Leaf& l : leaves)
      if (l.score >= o.rival_ratio * out.score && (!farthest || apart(l).norm() > apart(*farthest).norm())) farthest = &l;
    if (farthest && apart(*farthest).norm() > o.distinct_translation) {
      const Eigen::Vector2d u = apart(*farthest).normalized(), across(-u.y(), u.x());
      bool on_line = true;
      double extent = 0.0;
      for (const Leaf& l : leaves) {
        if (l.score < o.rival_ratio * out.score) continue;
        on_line = on_line && std::abs(across.dot(apart(l))) <= o.slide_width &&
                  std::abs(std::remainder(l.motion.theta - out.best.theta, 2.0 * std::numbers::pi)) <= o.distinct_rotation;
        extent = std::max(extent, std::abs(u.dot(apart(l))));
      }
      if (on_line) {
        out.slide = u;
        out.slide_extent = extent;
      }
    }
  }
  return out;
}

}  // namespace mspace::kernel
