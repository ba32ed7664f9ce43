// bearings.hpp — bearings of laser points, fast but exact.
//
// The scan matcher looks every current point up by its bearing in every
// reference scan of the local map at every ICP iteration (tens of thousands
// of look-ups per increment). Two things make that cheap without changing a
// single result:
//  - Bearing: atan2(y, x) of a point, decided by a polynomial approximation
//    (error < 1.2e-5 rad) wherever that settles the comparison asked —
//    nearly always, as beams are 0.25–1° (4e-3–2e-2 rad) apart — and by
//    std::atan2 only within kApproximationMargin of the threshold. Every
//    answer is the one std::atan2 gives.
//  - BearingIndex: a scan's bearings, sorted, with a bucket table, so that
//    the first bearing at or after b (std::lower_bound's answer) takes O(1).
#pragma once

#include <cmath>
#include <cstddef>
#include <numbers>
#include <vector>

namespace mspace::scan_matching {

/// a wrapped into [−π, π] (std::remainder(a, 2π)). std::remainder is exact,
/// so for |a| ≤ π, nearly every call, it returns a itself: the call is
/// skipped, the result the same.
inline double wrap(double a) {
  return std::abs(a) <= std::numbers::pi ? a : std::remainder(a, 2.0 * std::numbers::pi);
}

/// atan2(y, x) to within 1.2e-5 rad without calling atan2; NaN at (0, 0).
inline double approximate_atan2(double y, double x) {
  // t = the smaller of |x|, |y| over the larger, in [0, 1]: atan t by the
  // odd polynomial of Abramowitz & Stegun 4.4.49 (|error| ≤ 1.15e-5 with
  // these rounded coefficients, measured on a grid of 2e8 points), then the
  // octant by atan2 = π/2 − atan t (|y| > |x|), π − … (x < 0), −… (y < 0).
  const double ax = std::abs(x), ay = std::abs(y);
  const bool steep = ay > ax;
  const double t = (steep ? ax : ay) / (steep ? ay : ax);  // NaN at (0, 0)
  const double t2 = t * t;
  const double a = t * (0.9998660 + t2 * (-0.3302995 + t2 * (0.1801410 + t2 * (-0.0851330 + t2 * 0.0208351))));
  const double octant = steep ? 0.5 * std::numbers::pi - a : a;
  const double half = std::signbit(x) ? std::numbers::pi - octant : octant;
  return std::signbit(y) ? -half : half;
}

/// The bearing std::atan2(y, x) of the point (x, y), as comparisons that
/// call std::atan2 only when the approximation cannot settle them.
class Bearing {
 public:
  Bearing(double x, double y) : x_(x), y_(y), approximate_(approximate_atan2(y, x)) {}

  /// Exactly std::atan2(y, x) < c (below), > c (above), ≥ c (at_least), ≤ c (at_most).
  bool below(double c) const {
    const int s = settle(c);
    return s != 0 ? s < 0 : exact() < c;
  }
  bool above(double c) const {
    const int s = settle(c);
    return s != 0 ? s > 0 : exact() > c;
  }
  bool at_least(double c) const {
    const int s = settle(c);
    return s != 0 ? s > 0 : exact() >= c;
  }
  bool at_most(double c) const {
    const int s = settle(c);
    return s != 0 ? s < 0 : exact() <= c;
  }
  /// Exactly |wrap(other − std::atan2(y, x))| > limit: bearing `other` is
  /// more than `limit` from this one.
  bool farther_than(double other, double limit) const {
    // |wrap(d)| is the distance from d to the nearest multiple of 2π (exact),
    // which moves no more than d does: with the approximate bearing it is
    // within the margin (plus a rounding of other − b, ~1e-15) of the exact one.
    const double approximate_distance = std::abs(wrap(other - approximate_));
    if (approximate_distance > limit + kApproximationMargin) return true;
    if (approximate_distance < limit - kApproximationMargin) return false;
    return std::abs(wrap(other - exact())) > limit;
  }

  /// std::atan2(y, x), computed on first use.
  double exact() const {
    if (!have_exact_) {
      exact_ = std::atan2(y_, x_);
      have_exact_ = true;
    }
    return exact_;
  }
  double approximate() const { return approximate_; }

  /// What the comparisons take |approximate() − exact()| to be below: four
  /// times the approximation's largest error (checked in tests/scan_matching).
  static constexpr double kApproximationMargin = 5e-5;

 private:
  /// −1: the bearing is surely below c; +1: surely above; 0: too close to
  /// tell from the approximation (or it is NaN).
  int settle(double c) const {
    if (approximate_ + kApproximationMargin < c) return -1;
    if (approximate_ - kApproximationMargin > c) return 1;
    return 0;
  }

  double x_, y_;
  double approximate_;
  mutable double exact_ = 0.0;
  mutable bool have_exact_ = false;
};

class BearingIndex {
 public:
  BearingIndex() = default;
  /// `sorted`: bearings (rad), ascending.
  explicit BearingIndex(std::vector<double> sorted);

  /// Index of the first bearing not below b's exact bearing (size() if
  /// none): std::lower_bound(bearings().begin(), bearings().end(), b.exact()).
  std::size_t first_not_below(const Bearing& b) const {
    if (bearings_.empty()) return 0;
    // The exact bearing is at least approximate − margin, so every bearing
    // before first_[bucket_of(approximate − margin)] lies in a lower bucket
    // than it, hence (buckets being non-decreasing in the bearing) below it:
    // the answer is at or after that index, and a short walk finds it.
    std::size_t i = first_[bucket_of(b.approximate() - Bearing::kApproximationMargin)];
    while (i < bearings_.size() && b.above(bearings_[i])) ++i;
    return i;
  }

  double operator[](std::size_t i) const { return bearings_[i]; }
  std::size_t size() const { return bearings_.size(); }
  bool empty() const { return bearings_.empty(); }

 private:
  /// Bucket of bearing b: ⌊(b − origin) · buckets / span⌋, clamped to the table.
  std::size_t bucket_of(double b) const {
    const double f = (b - origin_) * buckets_per_radian_;
    if (!(f > 0.0)) return 0;  // below the origin (or NaN)
    const double last = static_cast<double>(first_.size() - 1);
    return f >= last ? first_.size() - 1 : static_cast<std::size_t>(f);
  }

  std::vector<double> bearings_;
  /// first_[k]: index of the first bearing whose bucket is ≥ k.
  std::vector<std::size_t> first_;
  double origin_ = 0.0;
  double buckets_per_radian_ = 0.0;
};

}  // namespace mspace::scan_matching
