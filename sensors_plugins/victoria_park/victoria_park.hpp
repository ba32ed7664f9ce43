// victoria_park.hpp — the `victoria_park` data source: ACFR's Victoria Park
// log (Guivant & Nebot 2001) as mspace data steps.
//
// Files read, relative to `data_dir` (see the data set's README):
//   text/aa3_dr.txt            dead reckoning, 40 Hz: time_ms, encoder speed
//                              (rear-left wheel, m/s), steering (rad)
//   rfs_slam/measurements.dat  tree detections: t_s, range, bearing, diameter
//   text/aa3_gpsx.txt          GPS fixes: time_ms, x (east, m), y (north, m)
// Why the detection file: the raw laser scans are not in the data set, so
// ACFR's own tree detector output (as converted by the RFS-SLAM authors) is
// the only laser data there is; it carries the trunk diameter as well as
// range and bearing. The dead reckoning comes from the lossless text dump of
// ACFR's .mat file (inputs.dat rounds it).
//
// Clocks. The .mat dumps count milliseconds on the vehicle clock; the .dat
// files count seconds since the first GPS fix (20967 ms). Everything here is
// in the second clock: t = (t_ms − 20967)/1000.
//
// Steps. One step per distinct time stamp of a dead-reckoning sample, a scan
// or a GPS fix, in time order. Each step's odometry is the (speed, steering)
// of the newest dead-reckoning sample at or before the previous step: the
// controls are held until the next sample (zero-order hold), so splitting an
// interval at a scan or fix time does not change the integrated motion. Steps
// before the first sample have no odometry.
//
// Readings. A scan becomes one SensorReading on `channel` with one row per
// trunk: (range m, bearing rad, diameter m), the bearing converted to the
// mspace sensor frame (x ahead, y left): the file's bearing − π/2.
//
// Ground truth. A GPS fix becomes the step's ground truth (x, y) with
// ground_truth_known = x and y only. The antenna sits at the laser, not at
// the rear-axle centre the motion model estimates.
#pragma once

#include <Eigen/Core>
#include <filesystem>
#include <string>
#include <vector>

#include "mspace/params.hpp"
#include "mspace/plugin.hpp"
#include "mspace/records.hpp"
#include "mspace/source.hpp"

namespace mspace::victoria_park {

/// Time of the first GPS fix on the vehicle clock: the origin of the .dat files.
inline constexpr double kClockOriginMs = 20967.0;

struct DeadReckoningSample {
  double t = 0.0;         ///< s
  double speed = 0.0;     ///< m/s, rear-left wheel encoder
  double steering = 0.0;  ///< rad, positive = left
};

struct GpsFix {
  double t = 0.0;  ///< s
  double x = 0.0;  ///< m, east
  double y = 0.0;  ///< m, north
};

struct Scan {
  double t = 0.0;              ///< s
  Eigen::MatrixXd detections;  ///< rows (range m, bearing rad in the mspace sensor frame, diameter m)
};

/// The three files in the second clock, each in time order. A malformed line
/// (not exactly its columns of finite numbers, a value out of range, time
/// going backwards, or a time stamp repeated — except that consecutive
/// detection lines with one time stamp are one scan) is reported to
/// `malformed` (an error "file:line: problem", or a counted skip). The GPS is
/// ground truth and always strict (mspace/records.hpp).
std::vector<DeadReckoningSample> read_dead_reckoning(const std::filesystem::path& file,
                                                     records::MalformedRecords& malformed);
std::vector<GpsFix> read_gps(const std::filesystem::path& file);
std::vector<Scan> read_detections(const std::filesystem::path& file, records::MalformedRecords& malformed);

/// The fixes that have another fix at most `max_gap` seconds before or after
/// them. The GPS unit was failing (67 gaps longer than 2 s, jumps): a fix
/// alone between two gaps is where its jumps are (one of them 141 m off).
std::vector<GpsFix> without_isolated_fixes(const std::vector<GpsFix>& fixes, double max_gap);

/// `${VAR}` and `${VAR:-default}` replaced from the environment (the kernel
/// expands values written in the YAML, not parameter defaults). Throws
/// std::invalid_argument for an unset variable without default.
std::string expand_environment(const std::string& text);

class VictoriaParkSource final : public DataSource {
 public:
  /// data_dir, channel, gps_isolated_gap, on_malformed.
  static std::vector<ParamSpec> param_specs();

  /// Reads all three files; throws std::runtime_error naming the missing
  /// directory or the malformed line.
  explicit VictoriaParkSource(const PluginArgs& args);
  /// `isolated_gap` > 0: GPS fixes with no other fix within that many seconds
  /// are not delivered (see without_isolated_fixes).
  VictoriaParkSource(const std::filesystem::path& data_dir, std::string channel, double isolated_gap = 0.0,
                     const std::string& on_malformed = "error");

  bool next(DataStep& step) override;
  std::size_t size_hint() const override { return times_.size(); }
  std::size_t skipped_records() const override { return malformed_.skipped(); }

  const std::vector<DeadReckoningSample>& dead_reckoning() const { return dr_; }
  /// The GPS fixes delivered as ground truth.
  const std::vector<GpsFix>& gps() const { return gps_; }
  /// GPS fixes in the file that were left out as isolated.
  std::size_t isolated_fixes() const { return isolated_fixes_; }
  const std::vector<Scan>& scans() const { return scans_; }

 private:
  void merge_times();

  std::string channel_;
  records::MalformedRecords malformed_;
  std::vector<DeadReckoningSample> dr_;
  std::vector<GpsFix> gps_;
  std::size_t isolated_fixes_ = 0;
  std::vector<Scan> scans_;
  std::vector<double> times_;  ///< distinct step times, ascending
  std::size_t step_ = 0, next_dr_ = 0, next_gps_ = 0, next_scan_ = 0;
  /// The controls in effect from the previous step on (index into dr_, or −1).
  long held_dr_ = -1;
};

}  // namespace mspace::victoria_park
