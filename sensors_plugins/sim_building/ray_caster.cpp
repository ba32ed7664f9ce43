// ray_caster.cpp — see ray_caster.hpp.
#include "ray_caster.hpp"

#include <algorithm>
#include <cmath>

#include "mspace/scene.hpp"

namespace mspace::sim_building {
namespace {

constexpr double kInf = std::numeric_limits<double>::infinity();

}  // namespace

// The closed forms are the SDK's (mspace/scene.hpp), shared with the
// extractors' conformance scenes.
double ray_segment(const Vec2& o, const Vec2& d, const Segment& seg) { return ray_segment_distance(o, d, seg.a, seg.b); }

double ray_disc(const Vec2& o, const Vec2& d, const Disc& disc) {
  return ray_circle_distance(o, d, disc.centre, disc.radius);
}

RayCaster::RayCaster(std::vector<Segment> segments, std::vector<Disc> discs, double bucket)
    : segments_(std::move(segments)), discs_(std::move(discs)), bucket_(bucket) {
  if (segments_.empty()) return;
  double x1 = -kInf, y1 = -kInf;
  x0_ = y0_ = kInf;
  for (const Segment& s : segments_) {
    x0_ = std::min({x0_, s.a.x(), s.b.x()});
    y0_ = std::min({y0_, s.a.y(), s.b.y()});
    x1 = std::max({x1, s.a.x(), s.b.x()});
    y1 = std::max({y1, s.a.y(), s.b.y()});
  }
  x0_ -= bucket_, y0_ -= bucket_;
  nx_ = static_cast<long>(std::floor((x1 - x0_) / bucket_)) + 2;
  ny_ = static_cast<long>(std::floor((y1 - y0_) / bucket_)) + 2;
  buckets_.assign(static_cast<std::size_t>(nx_ * ny_), {});
  for (std::size_t k = 0; k < segments_.size(); ++k) {
    const Segment& s = segments_[k];
    const long i0 = static_cast<long>(std::floor((std::min(s.a.x(), s.b.x()) - x0_) / bucket_));
    const long i1 = static_cast<long>(std::floor((std::max(s.a.x(), s.b.x()) - x0_) / bucket_));
    const long j0 = static_cast<long>(std::floor((std::min(s.a.y(), s.b.y()) - y0_) / bucket_));
    const long j1 = static_cast<long>(std::floor((std::max(s.a.y(), s.b.y()) - y0_) / bucket_));
    // A segment on a bucket border is filed on both sides (the −1/+1), so
    // rounding cannot hide it from a ray that travels along that border.
    for (long j = std::max(0L, j0 - 1); j <= std::min(ny_ - 1, j1 + 1); ++j)
      for (long i = std::max(0L, i0 - 1); i <= std::min(nx_ - 1, i1 + 1); ++i)
        buckets_[static_cast<std::size_t>(j * nx_ + i)].push_back(static_cast<int>(k));
  }
}

double RayCaster::cast_segments(const Vec2& o, const Vec2& d, double max_range) const {
  double best = kInf;
  if (segments_.empty()) return best;
  long i = static_cast<long>(std::floor((o.x() - x0_) / bucket_));
  long j = static_cast<long>(std::floor((o.y() - y0_) / bucket_));
  if (i < 0 || j < 0 || i >= nx_ || j >= ny_) {  // outside the grid: test everything
    for (const Segment& s : segments_) best = std::min(best, ray_segment(o, d, s));
    return best;
  }
  // Amanatides–Woo: t_max = ray distance to the next vertical / horizontal bucket
  // border, t_delta = distance between two such borders.
  const int step_i = d.x() > 0 ? 1 : -1, step_j = d.y() > 0 ? 1 : -1;
  const double next_x = x0_ + static_cast<double>(i + (step_i > 0 ? 1 : 0)) * bucket_;
  const double next_y = y0_ + static_cast<double>(j + (step_j > 0 ? 1 : 0)) * bucket_;
  double t_max_x = d.x() != 0.0 ? (next_x - o.x()) / d.x() : kInf;
  double t_max_y = d.y() != 0.0 ? (next_y - o.y()) / d.y() : kInf;
  const double t_delta_x = d.x() != 0.0 ? bucket_ / std::abs(d.x()) : kInf;
  const double t_delta_y = d.y() != 0.0 ? bucket_ / std::abs(d.y()) : kInf;
  while (true) {
    for (int k : buckets_[static_cast<std::size_t>(j * nx_ + i)])
      best = std::min(best, ray_segment(o, d, segments_[static_cast<std::size_t>(k)]));
    const double t_exit = std::min(t_max_x, t_max_y);
    if (best <= t_exit || t_exit > max_range) return best;
    if (t_max_x < t_max_y) {
      i += step_i;
      t_max_x += t_delta_x;
    } else {
      j += step_j;
      t_max_y += t_delta_y;
    }
    if (i < 0 || j < 0 || i >= nx_ || j >= ny_) return best;
  }
}

double RayCaster::cast(const Vec2& origin, double angle, double max_range, const std::vector<Disc>& moving) const {
  const Vec2 d(std::cos(angle), std::sin(angle));
  double best = cast_segments(origin, d, max_range);
  for (const Disc& c : discs_) best = std::min(best, ray_disc(origin, d, c));
  for (const Disc& c : moving) best = std::min(best, ray_disc(origin, d, c));
  return best <= max_range ? best : kInf;
}

}  // namespace mspace::sim_building
