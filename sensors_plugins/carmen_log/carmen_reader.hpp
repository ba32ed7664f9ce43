// carmen_reader.hpp — parsing of 2-D laser logs into scans with odometry.
//
// Two file formats are understood:
//
//  * CARMEN logs (CLF, and the variant GMapping writes). One message per line;
//    the messages read are
//      FLASER n r_1..r_n x y θ odom_x odom_y odom_θ t host logger_t
//      ROBOTLASER1 type start fov resolution max_range accuracy remission_mode
//                  n r_1..r_n m rem_1..rem_m laser_x laser_y laser_θ
//                  robot_x robot_y robot_θ tv rv forward side turn_axis t host logger_t
//      ODOM x y θ tv rv accel t host logger_t
//      PARAM name value host logger_t
//    and every other message type (SYNC, NEFF, RAWLASER…, comments) is
//    ignored. FLASER beams span the field of view `flaser_fov` centred on the
//    robot's x axis, counter-clockwise: with n beams the spacing is fov/n for
//    even n (180 beams: −90°, −89°, …, 89°, as in the Intel data set) and
//    fov/(n−1) for odd n (181 beams: −90° … 90°).
//    In a CLF (`Variant::Clf`) the odometry of a scan is the odom_* (FLASER)
//    or robot_* (ROBOTLASER1) pose; there is no ground truth. In a GMapping
//    log (`Variant::GMapping`, recognised by its NEFF lines) the FLASER pose is
//    GMapping's corrected pose (the ground truth of the scan) and the odometry
//    of a scan is the newest ODOM line before it; GMapping re-anchors those,
//    so they are not raw odometry (the reader warns). In a CLF the ODOM poses
//    between two scans are kept with the later scan (Scan::odometry_between).
//
//  * The merged table of the Intel data set (`intel_910_scans.txt`): `#`
//    comments, then one scan per line,
//      t odom_x odom_y odom_θ gt_x gt_y gt_θ r_0 … r_{n−1}
//    with beam i at −90° + i·(180°/n).
//
// What the log says about its laser (LogContents::laser, resolved after the
// whole file is read):
//  * the no-return value: the range value that a large share of beams have
//    exactly, with (almost) nothing above it (detected from the ranges), else
//    PARAM robot_front_laser_max, else the ROBOTLASER1 maximum-range field;
//    `no_return_range` 0 takes it from the log, a configured value that the
//    data contradicts is a warning, or an error naming file:line when ≥ 5 % of
//    the ranges sit exactly at one value below it (they would be read as real
//    walls); SICK error codes (values repeated exactly within 1 % below the
//    no-return value) are no return too;
//  * the laser's offset on the robot: the median of the ROBOTLASER1 laser pose
//    expressed in its robot pose (the PARAM value when that agrees within
//    1 cm / 0.5°, else rounded to 1 mm / 0.01°: logged poses have few digits
//    and a configuration must be able to repeat it), else PARAM robot_frontlaser_offset /
//    robot_frontlaser_side_offset / robot_frontlaser_angular_offset; a
//    configured `laser_offset` that differs is an error against the
//    ROBOTLASER1 poses and a warning against a PARAM.
// A range at or beyond the no-return value, an error code, or a range beyond
// a ROBOTLASER1's own maximum range, is "no return" and stored as 0.
// A malformed line throws std::runtime_error "file:line: problem", or, with
// `skip_malformed`, is skipped and counted in LogContents::skipped.
#pragma once

#include <Eigen/Core>
#include <cstddef>
#include <filesystem>
#include <map>
#include <optional>
#include <string>
#include <vector>

namespace mspace::carmen_log {

enum class Format { Auto, Table, Carmen };
enum class Variant { Auto, Clf, GMapping };

struct ReaderOptions {
  Format format = Format::Auto;    ///< Auto: "Table" for files whose first data line starts with a number
  Variant variant = Variant::Auto;  ///< Auto: GMapping when the log has NEFF lines
  double no_return_range = 81.0;   ///< ranges ≥ this are "no return" (m); 0: from the log (see above)
  std::optional<Eigen::Vector3d> laser_offset;  ///< configured laser pose on the robot (x, y, θ), checked against the log
  double flaser_fov = 3.14159265358979323846;  ///< field of view of FLASER scans (rad)
  double time_offset = 0.0;        ///< added to every time stamp (s)
  bool skip_malformed = false;
};

/// A planar pose (x, y, θ).
using Pose2 = Eigen::Vector3d;

struct Scan {
  double t = 0.0;
  int line = 0;                    ///< line number in the file (for messages)
  Pose2 odometry = Pose2::Zero();  ///< odometry pose at the scan
  std::optional<Pose2> ground_truth;
  std::vector<double> ranges;      ///< m; 0 = no return
  std::vector<double> bearings;    ///< rad, in the laser frame
  double max_range = 0.0;          ///< ROBOTLASER1 maximum-range field (0: none)
  std::optional<Pose2> laser_offset;  ///< ROBOTLASER1: the laser pose in the robot pose's frame
  /// CLF logs: the ODOM poses logged after the previous scan and before this
  /// one (by time stamp), oldest first — the path the wheels measured between
  /// two scans, which matters across a logging gap of the laser.
  std::vector<Pose2> odometry_between;
};

/// A PARAM line's value and line number.
struct LogParam {
  std::string value;
  int line = 0;
};

/// What the log says about its laser (resolved by read_log).
struct LaserFacts {
  double no_return = 81.0;           ///< ranges ≥ this were stored as 0
  std::string no_return_origin;      ///< where no_return comes from (configured, file:line PARAM, detected…)
  std::optional<double> detected_no_return;  ///< the value many ranges have exactly, nothing above
  double detected_fraction = 0.0;    ///< share of all ranges at detected_no_return
  std::vector<double> error_codes;   ///< values just below no_return read as no return
  std::size_t error_code_ranges = 0; ///< ranges that had one of them
  std::optional<Pose2> offset;       ///< the laser's pose on the robot recorded by the log
  std::string offset_origin;         ///< "file:line (ROBOTLASER1 laser vs robot pose)" or "file:line (PARAM …)"
  std::vector<std::string> warnings; ///< configured values the data contradicts (the source logs them)
};

struct LogContents {
  std::vector<Scan> scans;
  std::size_t skipped = 0;     ///< malformed lines skipped (skip_malformed)
  std::string first_problem;   ///< "file:line: problem" of the first skipped line
  Format format = Format::Auto;
  Variant variant = Variant::Auto;
  std::map<std::string, LogParam> params;  ///< PARAM lines by name
  LaserFacts laser;
};

/// Reads a whole log (throws std::runtime_error when the file cannot be
/// opened or, without skip_malformed, at the first malformed line).
LogContents read_log(const std::filesystem::path& file, const ReaderOptions& options);

/// The increment x_d = (dx, dy, dθ) of the planar odometry model: the motion
/// from `from` to `to` expressed in the frame of `from`, dθ wrapped to (−π, π].
Eigen::Vector3d odometry_increment(const Pose2& from, const Pose2& to);

}  // namespace mspace::carmen_log
