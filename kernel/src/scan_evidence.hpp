// scan_evidence.hpp — a run's range scans as evidence for loop closing
// (issue 10): where features alone cannot place the local map (a corridor of
// parallel walls whose ends were never seen fixes no position along it), the
// scans still can — door openings, room corners, clutter.
//
// Generic: the kernel names no sensor. A reading counts as a range scan by
// its shape (occupancy_grid.hpp, is_range_scan); its beams' end points are
// kept in the robot frame (through the sensor's mount, eq. 17, planar part).
//
// The old map's end points make a likelihood field: a cell holds
// exp(−d²/2σ²), d the distance from its centre to the nearest old end point
// (cut at 3σ); a cell farther than that which an old beam crossed — space the
// old scans saw empty — holds −miss; a cell no old beam reached holds 0. A
// placement T of the recent end points scores the mean field value under
// them, at most 1: the fraction of the recent scans the old map explains,
// less what it contradicts (an end point where the old scans saw through). The search is exhaustive over the window (every rotation step
// and every cell of translation) and exact, made fast as in Olson's
// correlative scan matching (E. Olson, "Real-time correlative scan
// matching", ICRA 2009, §III-B, multi-resolution): grids of maxima over
// blocks of 2^h × 2^h cells bound the score of every translation in a block,
// and blocks are opened best bound first. Every placement scoring at least
// rival_ratio × the best is found, so the best clearly different one — the
// rival that makes a placement ambiguous — is never missed.
#pragma once

#include <cstddef>
#include <vector>

#include <Eigen/Core>

#include "loop_closing.hpp"
#include "mspace/pose.hpp"

namespace mspace::kernel {

/// The end points of one range scan, in the robot frame.
struct KeptScan {
  std::size_t record = 0;               ///< trajectory index of its step
  double path = 0.0;                    ///< m of travel at its step
  Eigen::Vector2f origin = Eigen::Vector2f::Zero();  ///< the sensor's position, robot frame (m)
  std::vector<Eigen::Vector2f> points;  ///< robot frame (m)
  float range = 0.0f;                   ///< the farthest point's distance from the sensor (m)
};

/// A beam of an old scan in the map frame: from the sensor to its end point.
struct ScanRay {
  Eigen::Vector2d from, to;
};

/// End points of one scan (rows: range m, bearing rad) of a sensor mounted at
/// `mount` (its planar part), in the robot frame. Beams without a return
/// (range ≤ 0 or not finite) and at or beyond `max_range` (when > 0) are left
/// out; a point closer than `spacing` to the last one kept is left out too.
std::vector<Eigen::Vector2f> scan_end_points(const Eigen::MatrixXd& range_bearing, const Pose6& mount,
                                             double max_range, double spacing);

struct ScanSearchOptions {
  double max_translation = 10.0;   ///< m: the window's radius about the current estimate
  double max_rotation = 0.5;       ///< rad: ± this
  double rotation_step = 0.0175;   ///< rad (1°)
  /// Placements scoring at least this fraction of the best are all found.
  double rival_ratio = 0.5;
  /// A rival lies at least this far from the best (m), or is turned this much (rad).
  double distinct_translation = 1.0;
  double distinct_rotation = 0.0873;
  /// Placements that slide along one line: every placement scoring at least
  /// rival_ratio × the best within this distance of the line through the
  /// best (m) and within distinct_rotation of its heading (ScanPlacement::slide).
  double slide_width = 0.45;
};

struct ScanPlacement {
  bool found = false;        ///< some placement scored above zero
  PlanarMotion best;         ///< about the search's pivot
  double score = 0.0;        ///< mean field value under the recent end points, [0, 1]
  PlanarMotion rival;        ///< the best placement clearly different from `best`
  double rival_score = 0.0;  ///< 0 when none scores rival_ratio × score
  /// When the rivals differ from the best only by a slide along one line (a
  /// corridor whose ends the scans did not see): its direction (unit, map
  /// frame) and how far along it the placements as good reach either way (m).
  /// Zero when there is no rival or a rival lies off that line.
  Eigen::Vector2d slide = Eigen::Vector2d::Zero();
  double slide_extent = 0.0;
  int leaves = 0;            ///< placements scored one by one (the search's cost)
};

/// The likelihood field of the old end points (map frame).
class ScanField {
 public:
  /// Over the bounding box of the rays (plus 3σ), cells of `resolution` m;
  /// a contradicted end point scores −miss.
  ScanField(const std::vector<ScanRay>& old_rays, double resolution, double sigma, double miss);

  /// Mean field value under `points` moved by T (points off the field score 0).
  double score(const std::vector<Eigen::Vector2d>& points, const PlanarMotion& T) const;

  /// Every rotation (steps of rotation_step within ±max_rotation) and cell
  /// translation within max_translation about `pivot`: the best placement of
  /// `points` and its best clearly different rival.
  ScanPlacement search(const std::vector<Eigen::Vector2d>& points, const Eigen::Vector2d& pivot,
                       const ScanSearchOptions& options) const;

  double resolution() const { return resolution_; }

 private:
  /// Maximum of level 0 over cells [i, i + 2^h) × [j, j + 2^h) (an upper
  /// bound where the block leaves the field).
  float bound(int h, int i, int j) const;

  double resolution_ = 0.1;
  Eigen::Vector2d origin_ = Eigen::Vector2d::Zero();  ///< lower-left corner of cell (0, 0)
  int width_ = 0, height_ = 0;
  std::vector<std::vector<float>> levels_;  ///< levels_[h]: maxima over 2^h × 2^h blocks
};

}  // namespace mspace::kernel
