// scan_matcher.hpp — laser odometry: the motion between two 2-D laser scans by
// point-to-line ICP (iterative closest point), seeded with wheel odometry, with
// a coarse-to-fine correlative search when the local match is weak.
//
// Used by data sources that replay 2-D laser logs (carmen_log's
// `odometry: scan_matched`) to replace poor wheel odometry with the motion
// the laser sees, and by tests and benchmarks directly. Any planar laser:
// 180–1080 beams, 0.25–1° apart, interleaved or varying start angles (the
// beam spacing is measured from each scan, not configured), ranges to 80 m,
// no-return and error codes dropped before (scan_to_points).
//
// Method (ReferenceScan::match).
//  1. Reference scan: each point gets a normal from a total-least-squares line
//     through its neighbouring beams; neighbours are taken while consecutive
//     points are closer than max(normal_radius, gap_beams · ρ · δ) — ρ the
//     range, δ the scan's median beam spacing — so sparse far beams on a wall
//     still form a line. A neighbourhood rougher than max(max_line_rms,
//     line_rms_factor · σ_n) gets no normal (corners, clutter); σ_n, the range
//     noise, is estimated from the scan itself (median line-fit RMS).
//  2. Correspondences by angle (projective association): a current point
//     moved into the reference frame, q' = T·q, is looked up by its bearing
//     among the reference points sorted by bearing, and paired with the
//     nearest of the ±association_window reference points around that
//     bearing. The pair is kept when its point-to-line residual
//     r = nᵀ (q' − p) is within the correspondence distance d (shrinking from
//     max_correspondence to max(min_correspondence, 4 σ_n)) and q' is within
//     max(d, gate_beams · ρ_p · δ) of p: where the beams are sparser than d
//     (far away) the nearest beam on the same wall may be half a beam spacing
//     along it, so 80 m beams 1° apart (1.4 m) still pair while near beams
//     keep the tight point distance that also constrains sliding along walls.
//  3. Heading search: wheel odometry's heading error (several degrees) moves
//     far points beyond any pairing distance, so headings within
//     ±heading_search of the seed are scored by overlap first (Σ 1 − (d/R)²
//     over current points within R = max(search_radius, ρ_p · δ) of their
//     partner, at most 180 points).
//  4. Gauss–Newton on the Huber-weighted Σ r²/σ² plus a weak prior on the seed
//     (a direction the scans do not constrain, along a corridor, stays where
//     the seed put it).
//  5. Quality relative to the data: `overlap` is the number of current points
//     that land inside the reference scan's field of view and range at the
//     result; the match is ok when pairs ≥ max(min_pairs, min_pair_fraction ·
//     overlap) and the robust RMS ≤ max(max_rms, 3 σ_n).
//  6. When that local match is weak (not ok, or pairs < weak_pair_fraction ·
//     overlap), a correlative search (Olson 2009, "Real-time correlative scan
//     matching"; what Cartographer and Hector do): the reference scan is drawn
//     into a likelihood grid; every heading in ±correlative_theta and every
//     translation in ±correlative_xy around the seed is scored by the summed
//     likelihood of the current points, coarse-to-fine by branch and bound
//     over a max-pooled grid (exact: the coarse score bounds the fine ones);
//     ICP is rerun from the best pose and the better of the two matches kept.
//  7. Consistency with the seed (seed_gate > 0, off by default): the match's
//     difference from the seed, as χ² under the seed's covariance
//     diag(σ_xy², σ_xy², σ_θ²), above seed_gate means the scans pulled it
//     further than the odometry can be wrong — in a corridor, whose walls
//     leave the along-axis direction free, a person walking past drags the
//     whole match by its own step. Then ICP is rerun from the seed with the
//     final (tight) correspondence distance from the first iteration, so
//     points displaced by more than that stay unpaired; if that match still
//     disagrees, the seed is kept. Needs σ_xy, σ_θ at the odometry's real
//     per-step error (with the weak default prior it would undo the
//     correlative search's recoveries from far seeds).
//  8. Local map (LocalMap, when older scans are given): the Gauss–Newton of
//     4 sums the point-to-line residuals of the current scan against each of
//     the last few key scans too, each placed in the reference's frame by the
//     laser odometry already found, and paired by bearing in that scan's own
//     frame. A person walking along a corridor is then one moving thing
//     against several views of the static walls, and a sparse log (scans
//     1–2 s apart) gets the overlap of several scans instead of one.
//     Each key scan is prepared once, when it is added; per iteration every
//     current point is placed in every reference once, its bearing there
//     shared by the free-space check and the pairing, and looked up by
//     bearings.hpp (an approximate atan2 that defers to std::atan2 near a
//     threshold, a bucket index instead of a binary search): the same
//     results as std::atan2 and std::lower_bound, faster. The 2w beams of a
//     look-up's window are read from coordinate arrays padded at both ends
//     (no bounds checks) and compared two at a time; the overlap is counted
//     once, at the last iteration.
//  9. Free space (free_space_margin > 0): a current point placed in a
//     reference scan (the previous one or a key scan) where that scan's beams
//     passed through and ended well beyond it was not there then: a person
//     walking. Such points are left out of the pairing, re-checked every few
//     iterations at the current estimate. With key scans 0.5 m or more apart a
//     person walking along with the robot is seen through by some of them.
// 10. Moving points (drop_moving, given the scan before the reference and
//     the increment between them): reference points that the older scan saw
//     no surface at are dropped before matching. Alone it is not enough: one
//     slipped increment makes the next filter keep the mover and drop static
//     corners; with the check of 7 the two together leave 1–17 disagreements
//     in 6000–8500 steps instead of 29–97 (bench_scan_slips).
//
// Each result carries its quality: pairs, residual, overlap, the information
// matrix Σ JᵀJ/σ² of the pairs (its smallest eigen-direction is the one the
// scene leaves weak, e.g. along a corridor) and a covariance for the motion
// model (the information deflated for correlated neighbouring residuals, plus
// the seed prior).
//
// LaserOdometry wraps this for a laser mounted at x_rs on the robot: it turns a
// robot seed into a laser seed and the laser increment (and covariance) into
// robot motion, increment_robot = x_rs ⊕ increment_laser ⊖ x_rs.
#pragma once

#include <Eigen/Core>
#include <vector>

#include "bearings.hpp"

namespace mspace::scan_matching {

/// A scan as points in its own frame (m). Beam order is kept: the normals are
/// fitted to neighbouring beams and correspondences are looked up by bearing.
using ScanPoints = std::vector<Eigen::Vector2d>;

/// (range, bearing) pairs → points; ranges ≤ 0 or ≥ max_range (and non-finite
/// ones) are dropped.
ScanPoints scan_to_points(const std::vector<double>& ranges, const std::vector<double>& bearings,
                          double max_range);

struct MatchOptions {
  double heading_search = 0.2;        ///< rad: headings within ± this of the seed are tried first (0: none)
  double heading_search_step = 0.01;  ///< rad
  double search_radius = 0.3;         ///< m: overlap radius of the heading search (or the beam gap, if larger)
  int max_iterations = 30;
  int max_points = 400;             ///< current points matched, evenly subsampled (0: all)
  double max_correspondence = 0.5;  ///< m, first iteration
  double min_correspondence = 0.1;  ///< m, reached at the last iterations (at least 4 σ_n)
  int normal_neighbours = 3;        ///< beams on each side used for a reference point's normal
  double gate_beams = 0.5;          ///< pairs may be this many beam spacings apart (at the partner's range) where that exceeds the correspondence distance
  int association_window = 4;       ///< usable reference beams on each side of a point's bearing searched for its partner
  double normal_radius = 0.15;      ///< m: largest gap between neighbouring points used for a normal…
  /// …or this many beam spacings at the point's range, if larger: 2.865 beams
  /// = a gap of 0.05 rad × range, i.e. walls seen at up to 70° incidence (at
  /// the Intel laser's 1° the 0.05 m per m the matcher used before).
  double gap_beams = 2.865;
  double max_line_rms = 0.02;       ///< m: a neighbourhood rougher than this (or line_rms_factor σ_n) gives no normal
  double line_rms_factor = 3.0;
  double huber = 0.03;              ///< m: residuals beyond this (or 1.5 σ_n) are down-weighted
  double point_sigma = 0.02;        ///< m: σ of one point-to-line residual (at least σ_n)
  double seed_sigma_xy = 0.1;       ///< m: σ of the seed's translation (a weak prior)
  double seed_sigma_theta = 0.1;    ///< rad: σ of the seed's rotation
  int min_pairs = 10;               ///< absolute floor of paired points for a match
  double min_pair_fraction = 0.15;  ///< …and at least this fraction of the overlapping points (cluttered Intel scans: correct matches down to 0.19)
  double max_rms = 0.05;            ///< m: larger final robust RMS (and > 3 σ_n) fails the match
  double converged_step = 1e-5;     ///< stop when the update is below this (m and rad)
  /// Residuals of neighbouring beams on one wall are correlated (a wall is one
  /// measurement, not N): the information Σ JᵀJ/s² (s the match's measured
  /// residual RMS) is divided by this for the covariance handed to the motion
  /// model. 1.6: the mean NEES of the increments was 4.81 with 1 on a
  /// simulated building (l_ring, seed 3, 150 m, no people, bench_scan_slips),
  /// 3 is right for 3 dof.
  double information_deflation = 1.6;
  // Correlative search (fallback when the local match is weak).
  bool correlative = true;
  double weak_pair_fraction = 0.5;     ///< pairs below this fraction of the overlap: search
  double correlative_xy = 0.6;         ///< m: translation window ± around the seed
  double correlative_theta = 0.5;      ///< rad: heading window ± around the seed
  double correlative_resolution = 0.05;  ///< m: fine grid cell (at least 2 σ_n)
  int correlative_coarse = 4;          ///< fine cells per coarse cell (each way)
  double correlative_max_range = 20.0; ///< m: points beyond are not drawn or scored
  int correlative_max_points = 300;    ///< current points scored (evenly subsampled)
  /// Consistency with the seed: a match whose difference e from the seed has
  /// eᵀ S⁻¹ e above this (S = diag(seed_sigma_xy², seed_sigma_xy²,
  /// seed_sigma_theta²), χ² with 3 degrees of freedom; 16.27 = 0.1 %) moved
  /// further than the seed's own uncertainty allows: something that moved
  /// (a person walking past) or a wrong peak pulled it. It is replaced by a
  /// tight match from the seed (min_correspondence from the first iteration),
  /// or the seed when that fails. 0: no check (the default: with the weak
  /// default prior a far seed is what the correlative search is for). The
  /// check is only as good as seed_sigma_*: set them to the wheel odometry's
  /// real per-step error.
  double seed_gate = 0.0;
  /// Free-space check (step 9; 0: off): a current point that a reference
  /// scan's beams saw through — the beam at its bearing, and its neighbours,
  /// ended more than this (m, or 10 σ_n) beyond it — was not there when that
  /// scan was taken: something moving (a person), left out of the ICP.
  double free_space_margin = 0.0;
  double local_map_weight = 1.0;
  // Moving objects (ReferenceScan::drop_moving, when an older scan is given).
  double moving_distance = 0.05;       ///< m: a reference point farther than this (or 4 σ_n) from the older scan's surface has moved
  double moving_max_fraction = 0.3;    ///< more of the usable points than this inconsistent: the older pose is wrong, keep all
};

struct MatchResult {
  Eigen::Vector3d increment = Eigen::Vector3d::Zero();  ///< (dx, dy, dθ) of the current scan in the reference frame
  bool ok = false;       ///< false: keep the seed (too few pairs or a large residual)
  int pairs = 0;         ///< paired points in the last iteration
  int overlap = 0;       ///< current points inside the reference's field of view and range at the result
  double rms = 0.0;      ///< robust RMS point-to-line residual of the pairs (m)
  int iterations = 0;
  bool correlative = false;  ///< the correlative search seeded the kept match
  bool disagreed = false;    ///< the match disagreed with the seed (seed_gate): the tight match from the seed (or the seed) kept
  double noise = 0.0;        ///< σ_n: range noise estimated from the reference scan (m)
  /// Σ JᵀJ/σ² over the pairs with the reference scan (no prior, not the
  /// local map's key scans), in (m, m, rad): what the laser alone says.
  Eigen::Matrix3d information = Eigen::Matrix3d::Zero();
  /// (information · σ_p²/s² / information_deflation + seed prior)⁻¹: the
  /// increment's covariance (σ_p the point sigma the information used, s the
  /// match's residual RMS, at least σ_n).
  Eigen::Matrix3d covariance = Eigen::Matrix3d::Identity();
  /// Smallest eigenvalue of the information with θ expressed in metres at 1 m
  /// (so translation and rotation compare), and its unit eigenvector (dx, dy, dθ·1 m):
  /// the direction the scene constrains least (along a corridor: ≈ the corridor's axis).
  double weakest_information = 0.0;
  Eigen::Vector3d weakest_direction = Eigen::Vector3d::Zero();
};

class ReferenceScan;

/// An older reference scan placed in the matching frame (the frame of the
/// reference scan `match` is called on): `pose` is the older scan's pose there.
struct PlacedReference {
  const ReferenceScan* scan = nullptr;
  Eigen::Vector3d pose = Eigen::Vector3d::Zero();
};

/// A reference scan prepared once (normals fitted, points indexed by bearing,
/// noise estimated) and matched against any number of scans.
class ReferenceScan {
 public:
  ReferenceScan(const ScanPoints& points, const MatchOptions& options);

  /// Matches `current` starting from `seed` (current scan's pose in this scan's
  /// frame). `older`: further reference scans of the local map, placed in this
  /// scan's frame, whose residuals join the ICP's (step 8); the heading and
  /// correlative searches use this scan alone. When the match with them is
  /// not ok, the match with this scan alone is returned.
  MatchResult match(const ScanPoints& current, const Eigen::Vector3d& seed,
                    const std::vector<PlacedReference>& older = {}) const;

  /// Drops the reference points that are not where an older scan of the same
  /// place saw a surface: things that moved between the two scans (people
  /// walking past), which would otherwise pull the match along with them.
  /// `older_pose` is the older scan's pose in this scan's frame (the previous
  /// increment, inverted). A point p is kept when some older point o, moved
  /// into this frame, lies within t = max(moving_distance, 4 σ_n) of p's line
  /// (|nᵀ(o − p)| ≤ t) and within max(t, 1.5 ρ δ) of p (sparse far beams);
  /// points that no older beam came near (newly seen, or occluded before)
  /// are dropped too — at scan rates they are few. When more than
  /// moving_max_fraction of the points would go, the older pose is taken to
  /// be wrong and nothing is dropped. Returns the number dropped.
  int drop_moving(const ScanPoints& older, const Eigen::Vector3d& older_pose);

  /// Reference points that received a normal.
  int usable_points() const { return static_cast<int>(points_.size()); }
  /// σ_n: median RMS of the line fits (m), a range-noise estimate.
  double noise() const { return noise_; }
  /// Median angular spacing of consecutive beams (rad).
  double beam_spacing() const { return spacing_; }

 private:
  struct Local;  // one ICP run's result
  /// match() with the given references (no fallback to this scan alone).
  MatchResult match_once(const ScanPoints& current, const Eigen::Vector3d& seed,
                         const std::vector<PlacedReference>& older) const;
  /// Point-to-line ICP from `start` (the prior stays on `seed`).
  /// `first_distance` > 0: the correspondence distance of the first
  /// iteration (else max_correspondence).
  Local icp(const ScanPoints& current, const Eigen::Vector3d& start, const Eigen::Vector3d& seed,
            const std::vector<PlacedReference>& older, double first_distance = 0.0) const;
  /// The seed with the heading of most overlap within ± heading_search.
  Eigen::Vector3d heading_search(const ScanPoints& current, const Eigen::Vector3d& seed) const;
  /// Best pose of the correlative search around `seed` (Olson 2009), or the seed.
  Eigen::Vector3d correlative_search(const ScanPoints& current, const Eigen::Vector3d& seed) const;
  /// Index into points_ of the nearest reference point among those around
  /// q's bearing, or −1 (q in the reference frame).
  int nearest_by_bearing(const Eigen::Vector2d& q) const;
  /// The same for q whose bearing atan2(q_y, q_x) is already known.
  int nearest_by_bearing(const Eigen::Vector2d& q, const Bearing& bearing) const;
  /// The same for q whose bearing lies just below bearings_[at]
  /// (bearings_.first_not_below gives `at`).
  int nearest_in_window(const Eigen::Vector2d& q, int at) const;
  /// Fills window_x_, window_y_ from points_ (after every change of points_).
  void pad_window();
  /// Largest gap between neighbouring beams at range ρ (m).
  double beam_gap(double range) const;
  /// Whether this scan's beams passed q (in this frame) and ended more than
  /// `margin` beyond it: every beam within 1.5 spacings of q's bearing, at
  /// least one (step 9). `bearing`: q's, atan2(q_y, q_x).
  bool sees_through(const Eigen::Vector2d& q, const Bearing& bearing, double margin) const;
  /// Whether q (bearing atan2(q_y, q_x)) lies within this scan's field of view and range.
  bool in_view(const Eigen::Vector2d& q, const Bearing& bearing) const;

  MatchOptions options_;
  std::vector<Eigen::Vector2d> points_;   ///< usable points, sorted by bearing
  std::vector<double> ranges_;            ///< range |p| of each
  std::vector<Eigen::Vector2d> normals_;  ///< unit normal of each
  BearingIndex bearings_;                 ///< bearing of each (ascending)
  /// x and y of each, padded with association_window positions on each side
  /// (pad_window), so that a look-up's window needs no bounds checks and its
  /// distances can be computed side by side (nearest_in_window).
  std::vector<double> window_x_, window_y_;
  ScanPoints all_points_;                 ///< every reference point, in beam order (for the correlative grid)
  BearingIndex beam_bearings_;            ///< bearing of every point, ascending (free space)…
  std::vector<double> beam_ranges_;       ///< …and its range
  double noise_ = 0.0;
  double spacing_ = 0.0;
  double min_bearing_ = 0.0, max_bearing_ = 0.0, max_range_ = 0.0;
  bool full_circle_ = false;
  // Effective thresholds (the options' floors raised by the measured noise).
  double min_correspondence_ = 0.1, huber_ = 0.03, point_sigma_ = 0.02, max_rms_ = 0.05;
};

/// Planar pose algebra on (x, y, θ).
Eigen::Vector3d compose(const Eigen::Vector3d& a, const Eigen::Vector3d& b);  ///< a ⊕ b
Eigen::Vector3d inverse(const Eigen::Vector3d& a);                            ///< ⊖ a

/// Laser odometry for a laser mounted at x_rs = (x, y, θ) on the robot.
struct OdometryResult {
  Eigen::Vector3d increment = Eigen::Vector3d::Zero();  ///< robot motion (dx, dy, dθ) in the previous robot frame
  Eigen::Matrix3d covariance = Eigen::Matrix3d::Identity();  ///< of `increment` (robot frame)
  MatchResult match;  ///< the laser-frame match and its quality figures
};

class LaserOdometry {
 public:
  LaserOdometry(const Eigen::Vector3d& mount, const MatchOptions& options) : mount_(mount), options_(options) {}

  /// Robot motion from `previous` to `current` (points in the laser frame),
  /// seeded with the robot motion `robot_seed` (wheel odometry). When the match
  /// fails, increment = robot_seed and match.ok = false.
  OdometryResult match(const ScanPoints& previous, const ScanPoints& current, const Eigen::Vector3d& robot_seed) const;
  /// `older`: the local map's key scans placed in `previous`'s laser frame (LocalMap::placed).
  OdometryResult match(const ReferenceScan& previous, const ScanPoints& current, const Eigen::Vector3d& robot_seed,
                       const std::vector<PlacedReference>& older = {}) const;
  /// The laser scan `previous` prepared as a reference with its moving points
  /// dropped against `older` (the scan before it), `robot_older_increment`
  /// being the robot motion from `older` to `previous` (ReferenceScan::drop_moving).
  ReferenceScan reference(const ScanPoints& previous, const ScanPoints& older,
                          const Eigen::Vector3d& robot_older_increment) const;

  /// d_r = x_rs ⊕ d_l ⊖ x_rs and its Jacobian ∂d_r/∂d_l.
  Eigen::Vector3d robot_increment(const Eigen::Vector3d& laser_increment, Eigen::Matrix3d* jacobian = nullptr) const;
  /// d_l = ⊖x_rs ⊕ d_r ⊕ x_rs.
  Eigen::Vector3d laser_increment(const Eigen::Vector3d& robot_increment) const;

  const Eigen::Vector3d& mount() const { return mount_; }
  const MatchOptions& options() const { return options_; }

 private:
  Eigen::Vector3d mount_;
  MatchOptions options_;
};

/// The local map of step 8: the last few key scans of a laser odometry with
/// their robot poses in the odometry's frame. A matched scan becomes a key
/// scan when it lies at least key_distance (or key_turn) from the newest one;
/// the oldest go beyond `scans`, and keys farther than max_distance from the
/// scan being matched are left out (they see other rooms).
struct LocalMapOptions {
  int scans = 0;              ///< key scans kept (0: no local map, the previous scan alone)
  double key_distance = 0.5;  ///< m
  double key_turn = 0.35;     ///< rad
  double max_distance = 5.0;  ///< m
};

class LocalMap {
 public:
  LocalMap(const LaserOdometry& odometry, const LocalMapOptions& options)
      : mount_(odometry.mount()), match_options_(odometry.options()), options_(options) {}

  /// Scan `index` (points in its laser frame), matched, at robot pose `robot_pose`.
  void add(std::size_t index, const ScanPoints& points, const Eigen::Vector3d& robot_pose);
  /// The key scans other than scan `index`, placed in the laser frame of the
  /// scan `index` at robot pose `robot_pose` (for LaserOdometry::match with
  /// that scan as the reference).
  std::vector<PlacedReference> placed(std::size_t index, const Eigen::Vector3d& robot_pose) const;
  /// Forgets every key scan (the odometry chain broke, e.g. a failed match).
  void clear() { keys_.clear(); }
  std::size_t size() const { return keys_.size(); }

 private:
  struct Key {
    std::size_t index;
    ReferenceScan scan;
    Eigen::Vector3d laser_pose;  ///< in the odometry frame: robot pose ⊕ mount
  };
  Eigen::Vector3d mount_;
  MatchOptions match_options_;
  LocalMapOptions options_;
  std::vector<Key> keys_;  ///< oldest first
};

}  // namespace mspace::scan_matching
