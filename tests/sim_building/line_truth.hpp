// line_truth.hpp — laser_lines scored against the floor plan of a generated
// building (issue 18 item 3: precision and recall of lines per laser variant).
//
// Each scan of a simulation is run through the extractor as carmen_log hands
// it over (the no-return value and error codes as 0, bearings with their
// interleave offset), and its segments are placed in the plan with the TRUE laser pose
// (x_ms = x_mr ⊕ x_rs, eq. 17). Against the plan's static segments (wall
// faces and box sides):
//   precision  an extracted segment is right when both its ends lie within
//              kLineDistance of one static segment's line, its direction
//              within kLineAngle, and within that segment's extent (to
//              kEndDistance: a segment across a doorway is wrong);
//   recall     a visible piece of wall — a run of at least min_points
//              consecutive beams whose noise-free ray (people included as
//              occluders) meets the same static segment within max_range,
//              at least min_length long — is found when a right segment on
//              that static segment covers half of it;
//   real ends  an end flagged real (corner or depth jump) is right when it
//              lies within kEndDistance of an end of its static segment; a
//              found piece that reaches an end of its static segment offers
//              that end, found when the segment flags it real there.
// The tolerances are stated below; nothing is fitted to the results.
#pragma once

#include <cstddef>
#include <numbers>
#include <string>

#include "building_log.hpp"
#include "line_extraction.hpp"

namespace mspace::sim_building {

/// A right segment's ends lie this close to the wall's line (m): 5σ of the
/// presets' range noise, well below the 0.2 m thickness of a wall.
inline constexpr double kLineDistance = 0.05;
/// …and its direction this close to the wall's (rad, 3°).
inline constexpr double kLineAngle = 3.0 * std::numbers::pi / 180.0;
/// A real end lies this close to an end of its wall (m): the beam spacing
/// at 8 m with 1° resolution.
inline constexpr double kEndDistance = 0.15;

struct LineScore {
  std::size_t scans = 0;
  std::size_t extracted = 0, right = 0;          ///< segments, and right ones
  std::size_t visible = 0, found = 0;            ///< visible wall pieces, found ones
  std::size_t real_ends = 0, right_real_ends = 0;  ///< ends flagged real, and right ones
  std::size_t offered_ends = 0, found_ends = 0;  ///< wall ends in found pieces, flagged real there

  double precision() const { return extracted ? static_cast<double>(right) / extracted : 1.0; }
  double recall() const { return visible ? static_cast<double>(found) / visible : 1.0; }
  double end_precision() const { return real_ends ? static_cast<double>(right_real_ends) / real_ends : 1.0; }
  double end_recall() const { return offered_ends ? static_cast<double>(found_ends) / offered_ends : 1.0; }
  LineScore& operator+=(const LineScore& o);
};

/// Scores `config` on every `stride`-th scan of `sim`.
/// With sigma_from_data each scan is cut with the range noise measured on the
/// scored scans before it (laser_lines' range_sigma_from_data).
LineScore score_lines(const Simulation& sim, const laser_lines::LineConfig& config, std::size_t stride = 1,
                      bool sigma_from_data = false);

/// The extractor settings of config/intel_walls.yaml (the configuration the
/// generated buildings are run with).
laser_lines::LineConfig intel_walls_line_config();

}  // namespace mspace::sim_building
