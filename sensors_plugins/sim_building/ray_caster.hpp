// ray_caster.hpp — exact 2-D ray casting against line segments and discs.
//
// The distance along a ray to the first segment or disc it meets is computed
// in closed form (below), never by marching in steps. For speed the segments
// are filed in a uniform grid of square buckets (each segment in every bucket
// its bounding box touches), and a ray visits only the buckets it crosses, in
// order (Amanatides & Woo's traversal): once the nearest hit found so far lies
// before the exit of the current bucket, no later bucket can hold a nearer
// one. Discs (pillars, people) are few and tested one by one.
#pragma once

#include <limits>
#include <vector>

#include "floor_plan.hpp"

namespace mspace::sim_building {

/// Distance s ≥ 0 along the ray o + s·d (|d| = 1) to segment [a, b], or +inf
/// when the ray misses it (parallel rays miss).
double ray_segment(const Vec2& o, const Vec2& d, const Segment& seg);

/// Distance s ≥ 0 along the ray o + s·d (|d| = 1) to the circle's boundary,
/// or +inf when it misses; a ray starting inside the disc ignores it.
double ray_disc(const Vec2& o, const Vec2& d, const Disc& disc);

class RayCaster {
 public:
  /// Files the segments in buckets of `bucket` metres.
  RayCaster(std::vector<Segment> segments, std::vector<Disc> discs, double bucket = 1.0);

  /// Distance along the ray from `origin` at angle `angle` (rad, map frame) to
  /// the first segment or disc (static ones and `moving`), or +inf if none
  /// lies within max_range.
  double cast(const Vec2& origin, double angle, double max_range, const std::vector<Disc>& moving = {}) const;

 private:
  double cast_segments(const Vec2& o, const Vec2& d, double max_range) const;

  std::vector<Segment> segments_;
  std::vector<Disc> discs_;
  double bucket_;
  double x0_ = 0.0, y0_ = 0.0;  ///< lower left corner of the bucket grid
  long nx_ = 0, ny_ = 0;
  std::vector<std::vector<int>> buckets_;  ///< segment indices per bucket, row-major
};

}  // namespace mspace::sim_building
