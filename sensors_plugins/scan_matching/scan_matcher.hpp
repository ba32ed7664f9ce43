// scan_matcher.hpp — laser odometry: the motion between two 2-D laser scans by
// point-to-line ICP (iterative closest point), seeded with wheel odometry.
//
// Used by data sources that replay 2-D laser logs (carmen_log's
// `odometry: scan_matched`) to replace poor wheel odometry with the motion
// the laser sees. It is a front end only: the SLAM estimator still treats the
// result as an odometry increment with the motion model's noise.
//
// Method. The reference scan's points get a normal each from a total-least-
// squares line through their neighbouring beams (points whose neighbourhood is
// not a line — corners, clutter — get none and are not used). For an increment
// T = (dx, dy, dθ) (the current scan's pose in the reference scan's frame) each
// current point q is moved to T·q, paired with its nearest reference point p
// within a correspondence distance, and contributes the residual
//   r = nᵀ (T·q − p)
// (its distance to the reference point's tangent line). Wheel odometry's
// heading error (several degrees a step) moves far points by more than any
// sensible pairing distance, so the heading is first searched on a grid of
// ± `heading_search` around the seed for the largest overlap of the scans. Gauss–Newton on the
// Huber-weighted sum of r² plus a weak prior on the seed (so a direction the
// scans do not constrain, along a corridor, stays where the seed put it) gives
// the update of T; the correspondence distance
// shrinks from `max_correspondence` to `min_correspondence` over the iterations.
// The match fails (and the caller keeps its seed) when too few pairs remain or
// the final robust RMS residual is too large.
#pragma once

#include <Eigen/Core>
#include <vector>

namespace mspace::scan_matching {

/// A scan as points in its own frame (m). Beam order is kept: the normals are
/// fitted to neighbouring beams.
using ScanPoints = std::vector<Eigen::Vector2d>;

/// (range, bearing) pairs → points; ranges ≤ 0 or ≥ max_range are dropped.
ScanPoints scan_to_points(const std::vector<double>& ranges, const std::vector<double>& bearings,
                          double max_range);

struct MatchOptions {
  double heading_search = 0.2;       ///< rad: headings within ± this of the seed are tried first (0: none)
  double heading_search_step = 0.01; ///< rad
  double search_radius = 0.3;        ///< m: a point within this of a reference point counts as overlap
  int max_iterations = 30;
  double max_correspondence = 0.5;   ///< m, first iteration
  double min_correspondence = 0.1;   ///< m, reached at the last iterations
  int normal_neighbours = 3;         ///< beams on each side used for a reference point's normal
  double normal_radius = 0.15;       ///< m: largest gap between neighbouring points used for a normal…
  double gap_per_m = 0.05;           ///< …or this times the range, if larger (far beams spread)
  double max_line_rms = 0.02;        ///< m: a neighbourhood rougher than this gives no normal
  double huber = 0.03;               ///< m: residuals beyond this are down-weighted
  double point_sigma = 0.02;         ///< m: σ of one point-to-line residual
  double seed_sigma_xy = 0.1;        ///< m: σ of the seed's translation (a weak prior)
  double seed_sigma_theta = 0.1;     ///< rad: σ of the seed's rotation
  int min_pairs = 20;                ///< fewer paired points: the match fails
  double max_rms = 0.05;             ///< m: larger final robust RMS residual: the match fails
  double converged_step = 1e-5;      ///< stop when the update is below this (m and rad)
};

struct MatchResult {
  Eigen::Vector3d increment = Eigen::Vector3d::Zero();  ///< (dx, dy, dθ) of the current scan in the reference frame
  bool ok = false;   ///< false: keep the seed (too few pairs or a large residual)
  int pairs = 0;     ///< paired points in the last iteration
  double rms = 0.0;  ///< RMS point-to-line residual of the pairs (m)
  int iterations = 0;
};

/// A reference scan prepared once (points sorted for the nearest-neighbour
/// search, normals fitted) and matched against any number of scans.
class ReferenceScan {
 public:
  ReferenceScan(const ScanPoints& points, const MatchOptions& options);

  /// Matches `current` starting from `seed` (current scan's pose in this scan's frame).
  MatchResult match(const ScanPoints& current, const Eigen::Vector3d& seed) const;

  /// Reference points that received a normal.
  int usable_points() const { return static_cast<int>(points_.size()); }

 private:
  /// Σ over current points paired within `radius` of (1 − (d/radius)²) at T.
  double overlap_score(const ScanPoints& current, const Eigen::Vector3d& T, double radius) const;
  /// The seed with the heading of most overlap within ± heading_search.
  Eigen::Vector3d heading_search(const ScanPoints& current, const Eigen::Vector3d& seed) const;
  /// Index into points_ of the nearest point within `max_distance`, or −1.
  int nearest(const Eigen::Vector2d& q, double max_distance) const;

  MatchOptions options_;
  std::vector<Eigen::Vector2d> points_;   ///< usable points, sorted by x
  std::vector<Eigen::Vector2d> normals_;  ///< unit normal of each
};

}  // namespace mspace::scan_matching
