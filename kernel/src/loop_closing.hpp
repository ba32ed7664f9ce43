// loop_closing.hpp — map matching for loop closure when the robot's pose is
// too uncertain (or its covariance too optimistic) for the gate (issue 10,
// item 3).
//
// When the odometry has drifted further than the association gate allows, a
// robot that comes back to a mapped place does not re-observe the old
// features: it maps them again. The kernel then has two copies of the place,
// the recent one (the *local map*: features created in the last few metres of
// travel) and the old one (features not seen for a long way). Map matching
// looks for the planar rigid motion that lays the local map onto the old map:
//
//   1. hypotheses   for every rotation in the search window (a grid of
//                   angles), every pair (local feature, old feature of the
//                   same type) votes for the translations that make the two
//                   coincide (a Hough transform on a grid of cells): one
//                   translation when the pair fixes both directions (a
//                   point block), a line of them when it leaves one free (a
//                   line-like feature whose end points may slide along it);
//   2. verification the strongest cells are refined by Gauss–Newton on the
//                   three motion parameters with the local features paired
//                   one to one to their nearest compatible old features,
//                   and kept only if the pairing is jointly compatible —
//                   D² = Σ rᵢᵀ Sᵢ⁻¹ rᵢ ≤ χ²(p, Σ dim rᵢ − 3), Neira & Tardós
//                   2001 applied to the aligned maps — and fixes all three
//                   motion parameters;
//   3. uniqueness   a hypothesis is accepted only when no clearly different
//                   one is nearly as good, searched in a window twice as
//                   large: in a symmetric building the local map fits
//                   several places and none is taken.
//
// Everything is generic: a feature is seen only through its coordinate blocks
// (mspace/coords.hpp; a rigid motion moves every point block and leaves
// scalars alone) and its symmetry directions (Feature::symmetry_directions:
// coordinates that may differ between two copies of the same object, e.g.
// unmeasured end points that may slide along a line). The residual of a pair
// is the difference of their coordinates with those directions projected
// out. The kernel never names a feature type.
#pragma once

#include <functional>
#include <limits>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include <Eigen/Core>

#include "mspace/coords.hpp"

namespace mspace::kernel {

/// A feature as map matching sees it: its coordinates and what they leave free.
struct FeatureShape {
  int feature = 0;  ///< the caller's key (an index into its map)
  int type = 0;     ///< only shapes of the same type are paired
  const CoordLayout* layout = nullptr;
  Eigen::VectorXd x;     ///< x_f, n coordinates
  Eigen::MatrixXd free;  ///< n × s symmetry directions (may have no columns)
  Eigen::MatrixXd cov;   ///< n × n covariance of x_f (B̃ P B̃ᵀ); empty: zero
  /// When the robot observed the feature, first and last, in metres of its
  /// travel (MapMatchOptions::pass_gap); NaN: not known (a loaded map).
  double seen_first = std::numeric_limits<double>::quiet_NaN();
  double seen_last = std::numeric_limits<double>::quiet_NaN();
  /// At most this many metres of travel since the robot last observed it
  /// (MapMatchOptions::drift_per_metre); NaN: not known (any reach).
  double travel_unseen = std::numeric_limits<double>::quiet_NaN();
};

/// A planar rigid motion about a pivot: p ↦ R(θ) (p − pivot) + pivot + t.
struct PlanarMotion {
  double theta = 0.0;
  Eigen::Vector2d t = Eigen::Vector2d::Zero();
  Eigen::Vector2d pivot = Eigen::Vector2d::Zero();

  Eigen::Vector2d apply(const Eigen::Vector2d& p) const;
  /// The coordinates `x` (with `layout`) moved: the (x, y) of every point
  /// block; heights and scalar blocks are unchanged.
  Eigen::VectorXd apply(const CoordLayout& layout, const Eigen::VectorXd& x) const;
  /// Directions (columns in x_f space) rotated with the motion.
  Eigen::MatrixXd rotate(const CoordLayout& layout, const Eigen::MatrixXd& directions) const;
  /// The same kind of motion scaled by `fraction` (θ and t), same pivot.
  PlanarMotion scaled(double fraction) const;
};

/// The residual of "shape a, moved by T, is the same object as shape b".
struct CoincidenceResidual {
  Eigen::VectorXd r;  ///< Nᵀ (T(x_a) − x_b), N an orthonormal basis of what no symmetry leaves free
  Eigen::MatrixXd N;  ///< n × m
  Eigen::MatrixXd S;  ///< m × m covariance of r: Nᵀ (R Σ_a Rᵀ + Σ_b) N + floor² I
  Eigen::MatrixXd J;  ///< m × 3: ∂r/∂(θ, t_x, t_y)
};

/// The free directions of a pair: b's symmetry directions and those of a
/// (rotated by T) that touch only blocks b leaves fixed. (Using both on one
/// block would let two crossing lines "coincide" at their intersection.)
/// False when nothing is left to compare (m = 0) or the layouts differ.
bool coincidence_residual(const FeatureShape& a, const FeatureShape& b, const PlanarMotion& T, double floor_sigma,
                          CoincidenceResidual& out);

/// How far apart two shapes are once each is moved by its own motion — for
/// ground-truth checks, each feature taken to the true frame through a pose
/// that saw it (G = gt ∘ est⁻¹ there): its estimate relative to that pose is
/// local, so a map's global distortion cancels, and two copies of one
/// object land on each other. The largest |residual| of the pair (m, the
/// symmetry directions projected out; e.g. two parallel walls 2 m apart:
/// 2); nothing when the shapes cannot be compared.
std::optional<double> distance_apart(const FeatureShape& a, const PlanarMotion& a_motion, const FeatureShape& b,
                                     const PlanarMotion& b_motion);

/// Whether two shapes, each moved by its own motion, lie in one place: their
/// footprints (the discs about the mean of their point blocks that hold those
/// blocks) no further apart than `margin`; false when either has no point
/// block. With distance_apart, for ground-truth checks: two segments far
/// apart on one line are the same line (distance 0), not the same object.
bool footprints_overlap(const FeatureShape& a, const PlanarMotion& a_motion, const FeatureShape& b,
                        const PlanarMotion& b_motion, double margin);

/// Whether two shapes, each moved by its own motion, have their point blocks
/// arranged the same way: every two point blocks pointing the same way, on
/// one line to `tolerance` (m): the same side of an object whose two sides
/// are features of their own — two parallel sides 0.2 m apart lie closer than
/// most tolerances but run opposite ways.
/// For ground-truth checks, with distance_apart and footprints_overlap.
bool arranged_alike(const FeatureShape& a, const PlanarMotion& a_motion, const FeatureShape& b,
                    const PlanarMotion& b_motion, double tolerance);

struct MapMatchOptions;

/// Diagnostics (the debug log's ground-truth verdicts): why the search would
/// not pair local feature `a`, moved by T, with old feature `b` — another
/// type, not the same place (footprints apart, point blocks the other way
/// round), nothing to compare, or the residual beyond the pairwise gate —
/// or "" when it would (before the one-to-one choice and the reach).
std::string pair_refusal(const FeatureShape& a, const FeatureShape& b, const PlanarMotion& T,
                         const MapMatchOptions& options);

struct MapMatchOptions {
  double max_translation = 10.0;    ///< m: the search window's radius about the current estimate
  double max_rotation = 0.5;        ///< rad: ± this about the current estimate
  double rotation_step = 0.0349;    ///< rad (2°): the hypothesis grid's angle step
  double cell = 0.25;               ///< m: the translation grid's cell side
  double floor_sigma = 0.05;        ///< m: σ added to every residual row (the local map's own distortion)
  double probability = 0.99;        ///< pairwise gate and joint compatibility
  int min_matches = 4;              ///< local features paired, at least
  /// …and at least this fraction of the local map: a revisit makes most of
  /// it duplicates, while a periodic corridor in new territory lines up a
  /// few doors with older ones.
  double min_fraction = 0.5;
  double ambiguity_ratio = 0.7;     ///< reject when a different hypothesis has this fraction of the matches
  double max_translation_std = 0.1; ///< m: the pairing must fix the translation this well (1σ)
  double max_rotation_std = 0.02;   ///< rad: and the rotation
  int max_hypotheses = 24;          ///< grid peaks verified
  /// Rivals are looked for in a window this many times larger than the one
  /// a hypothesis must lie in: where the structure repeats (a ladder of
  /// corridors, rooms in a row), a window that happens to hold one copy
  /// and not the next must not make the one it holds look unique.
  double rival_window_factor = 2.0;
  // Dense evidence (Slam: the range scans, scan_evidence.hpp); all optional.
  /// A placement's score by other evidence, higher is better; empty: features alone decide.
  std::function<double(const PlanarMotion&)> dense_score;
  /// A hypothesis scoring below this is contradicted by that evidence: it is
  /// never accepted and is no rival.
  double dense_floor = -std::numeric_limits<double>::infinity();
  /// Placements the other evidence found unique by itself (about the same
  /// pivot): verified like the transform's peaks, and acceptable even when
  /// the pairing leaves a direction of the motion free (a corridor's walls
  /// without ends: the other evidence fixed it).
  std::vector<PlanarMotion> seeds;
  /// A hypothesis refined from a seed needs only this many pairs (the seed's
  /// evidence placed the local map; the pairs say which features are the same).
  int seeded_min_matches = 2;
  /// A hypothesis refined from a seed is dropped when the pairing pulled the
  /// pivot farther than this from where the seed put it (m), or turned it
  /// more (rad): the features then disagree with the seed's evidence.
  double seed_tolerance_translation = 0.45;
  double seed_tolerance_rotation = 0.035;
  /// One pass of the old map (m of travel; 0: off). Two old features
  /// observed (FeatureShape::seen_first to seen_last) at times more than
  /// this far apart in travel, with no paired feature observed in between,
  /// belong to different passes: nothing observed ties them, so they may
  /// disagree with each other by the whole drift in between, and where they
  /// lie relative to each other in the estimate says nothing about the
  /// objects. A feature observed on both passes ties them (its observations
  /// span the gap). A pairing keeps the pass with the most pairs (ties: the
  /// better-fitting; features never timed join any) and pairs again within
  /// it; a local feature that fit a feature of another pass stays unpaired.
  double pass_gap = 0.0;
  /// The drift between two sightings of one object (m and rad per metre of
  /// travel; 0: off). The odometry cannot have moved the robot against an
  /// old feature by more than it drifts over the travel since the robot
  /// last observed that feature, so a hypothesis is accepted only when its
  /// motion is within pair_base_translation + drift_per_metre ×
  /// old.travel_unseen of translation (about the pivot), and the same for
  /// rotation, for every old feature it pairs: a feature tracked a few
  /// metres ago pairs only near the estimate, one last seen a kilometre ago
  /// anywhere in the window. A structure that repeats every 14 m cannot then
  /// lay the robot 14 m along features it saw 30 m ago. The search and the
  /// rivals are not held to it (a repeated place stays ambiguous).
  double drift_per_metre = 0.0;
  double drift_rad_per_metre = 0.0;
  /// What every pair may move by in any case (m, rad): the robot's own 3σ and
  /// the drift since it was last anchored (Slam::close_loops).
  double pair_base_translation = 0.0;
  double pair_base_rotation = 0.0;
  /// Diagnostics (the debug log's ground-truth verdicts): MapMatch::verified
  /// then holds every verified hypothesis with why it was not acceptable.
  bool keep_verified = false;
  /// Diagnostics: the votes the transform gave the cell of this motion
  /// (MapMatch::probe_votes), e.g. the one the ground truth needs.
  std::optional<PlanarMotion> probe;
};

/// One verified hypothesis.
struct MapMatchHypothesis {
  PlanarMotion motion;
  std::vector<std::pair<int, int>> pairs;  ///< (position in local, position in old)
  std::vector<double> pair_d2;             ///< each pair's own D², in the order of `pairs`
  /// Each pair's rivals in the gate: other old features its local one is
  /// compatible with, plus other local features its old one is compatible with.
  std::vector<int> pair_rivals;
  double d2 = 0.0;                         ///< joint D² of the pairing
  int dof = 0;                             ///< Σ dim rᵢ − 3
  bool jointly_compatible = false;
  bool determined = false;  ///< the pairing fixes θ, t_x, t_y to max_*_std
  bool seeded = false;      ///< refined from one of MapMatchOptions::seeds
  double dense_score = 0.0; ///< MapMatchOptions::dense_score of the motion (0 without)
  double sigma_translation = 0.0, sigma_rotation = 0.0;
};

struct MapMatch {
  bool accepted = false;
  MapMatchHypothesis best;  ///< the accepted one, or the best candidate
  int best_matches = 0;
  int rival_matches = 0;  ///< matches of the best clearly different hypothesis
  int hypotheses = 0;     ///< grid peaks verified
  std::string reason;     ///< why nothing was accepted
  /// With MapMatchOptions::keep_verified: every verified hypothesis, and for
  /// each why it is not acceptable by itself ("" when it is).
  std::vector<std::pair<MapMatchHypothesis, std::string>> verified;
  /// With MapMatchOptions::probe: the votes at the probe's cell and angle
  /// (the most within one cell), and how many peaks of the transform had more.
  int probe_votes = -1;
  int probe_outvoted = -1;
};

/// Searches the motion that lays `local` onto `old` (rotations about `pivot`,
/// usually the robot's position) within the window of `options`.
MapMatch match_local_map(const std::vector<FeatureShape>& local, const std::vector<FeatureShape>& old,
                         const Eigen::Vector2d& pivot, const MapMatchOptions& options);

/// Global localization (the kidnapped robot, docs/maps.md): the placement of
/// `local` anywhere in `old`, at any heading. The local map is first moved so
/// that `robot` (its own position) lies at the centre of the old map's
/// extent; the window is then the disc that holds every old feature, every
/// heading is searched, and rivals are looked for in the same window (the
/// whole map: a second place that fits as well makes the answer ambiguous).
/// Of `options` the window fields are ignored; the motion returned turns
/// about `robot`.
MapMatch locate_local_map(const std::vector<FeatureShape>& local, const std::vector<FeatureShape>& old,
                          const Eigen::Vector2d& robot, MapMatchOptions options);

/// Whether two placements of one local map agree: the robot's position and
/// heading under both within 3σ of their difference (σ of each placement,
/// plus `floor_sigma` for the local map's own distortion). `moved` and
/// `turned` receive how far apart they put the robot.
bool placements_agree(const PlanarMotion& a, double a_sigma_translation, double a_sigma_rotation,
                      const MapMatchHypothesis& b, const Eigen::Vector2d& robot, double floor_sigma, double& moved,
                      double& turned);

}  // namespace mspace::kernel
