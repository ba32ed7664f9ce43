// laser.hpp — the simulated 2-D laser scanner: presets and parameters.
//
// Beam i of scan k points at bearing start + offset(k) + i·resolution in the
// laser frame, where offset(k) = (k mod interleave)·interleave_step: with
// interleave = 4 and a step of 0.25° consecutive scans start at four angles
// 0.25° apart, as the interlaced SICK scans of real ROBOTLASER1 logs. The
// laser sits at mount (x, y, θ) on the robot. A beam's range is the exact
// distance to the first wall, box, pillar or person (ray_caster.hpp) plus
// N(0, range_sigma²); a beam that meets nothing within max_range reads
// `no_return` (the code a real driver writes, 81.83 for CARMEN's SICK driver,
// 50.0 for others), and with probability error_code_probability a beam reads
// one of the SICK error codes just below it (no_return − 0.01·{1, 2, 3}); with
// probability dropout_probability a beam that hit something reads no_return
// anyway (dark or glancing surfaces, glass: 12 % of the beams of a real
// ROBOTLASER1 log).
// Scans are logged every `interval` s (± interval_jitter·interval), and with
// probability gap_probability per scan the log has a gap of gap_min..gap_max s.
//
// Written as ROBOTLASER1 (start angle, resolution, max range in the message)
// or, `format = flaser`, as FLASER lines, which carry no angles: a reader
// assumes n beams centred on the robot's x axis (carmen_reader.hpp), so a
// FLASER laser must be centred, uninterleaved and unmounted.
#pragma once

#include <string>
#include <vector>

namespace mspace::sim_building {

struct LaserSpec {
  std::string preset = "sick181";      ///< name of the preset it started from
  std::string format = "robotlaser1";  ///< robotlaser1 | flaser
  int beams = 181;
  double resolution_deg = 1.0;
  double start_deg = -90.0;  ///< bearing of beam 0 (without the interleave offset)
  int interleave = 1;        ///< number of alternating start offsets
  double interleave_step_deg = 0.25;
  double max_range = 50.0;   ///< m
  double no_return = 81.83;  ///< value written for a beam with no return (m)
  double error_code_probability = 0.001;
  double dropout_probability = 0.0;  ///< a beam with a return reads no_return
  double range_sigma = 0.01;                                    ///< m
  double mount_x = 0.22, mount_y = 0.0, mount_theta_deg = 0.0;  ///< laser pose on the robot (m, deg)
  double interval = 0.2;                                        ///< s between scans
  double interval_jitter = 0.05;                                ///< relative
  double gap_probability = 0.0;                                 ///< per scan
  double gap_min = 2.0, gap_max = 6.0;                          ///< s
  double odom_interval = 0.1;                                   ///< s between ODOM lines

  /// Bearing of beam i of the k-th scan (rad, laser frame).
  double bearing(int i, long k) const;
  /// One "key = value" per line, for README.txt.
  std::string describe() const;
};

/// The presets, in order: name and one-line description.
std::vector<std::pair<std::string, std::string>> laser_presets();

/// The preset `name` (std::invalid_argument listing the choices otherwise).
LaserSpec laser_preset(const std::string& name);

/// Sets one parameter from "key=value" (the LaserSpec member names above;
/// angles in degrees). std::invalid_argument naming the key and the valid keys.
void set_laser_param(LaserSpec& spec, const std::string& key_value);

/// Checks ranges and consistency (std::invalid_argument with the reason).
void validate(const LaserSpec& spec);

}  // namespace mspace::sim_building
