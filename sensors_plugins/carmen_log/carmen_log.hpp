// carmen_log.hpp — the `carmen_log` data source: a 2-D laser log (CARMEN
// CLF / GMapping-written log, or the Intel data set's merged table, see
// carmen_reader.hpp) replayed one scan per step.
//
// Each step is one scan:
//   - DataStep::t: the scan's time stamp (+ time_offset);
//   - DataStep::odometry: x_d = (dx, dy, dθ), the odometry motion since the
//     previous scan expressed in the previous odometry pose's frame — the
//     increment of the `odometry2d` motion model (planar_odometry.hpp). The
//     first step has none. With `odometry: scan_matched` the increments are
//     laser odometry (scan_matching/scan_matcher.hpp), seeded with the wheel
//     odometry, for the laser at `laser_offset` (or the log's offset) on the
//     robot, and with `scan_match_covariance: true` DataStep::odometry_covariance
//     is the match's covariance (empty where the match failed and the wheel
//     increment was kept);
//   - one SensorReading on `channel` whose `values` has one row per beam, in
//     beam order: (range, bearing) in m and rad in the laser frame, range 0
//     for a beam with no return (the `laser_lines` extractor relies on the
//     beam order and on seeing the no-return beams);
//   - DataStep::ground_truth: the GMapping-corrected pose when the file has
//     one (table, GMapping log) and `ground_truth: log`; or, with
//     `ground_truth: FILE`, the pose of a TUM trajectory interpolated at the
//     scan time (e.g. a simulator's ground_truth.tum); none with `none`.
// The initial pose is the first scan's ground truth (initial_pose:
// ground_truth, falling back to odometry when there is none), its odometry
// pose, or zero.
#pragma once

#include <cstddef>
#include <string>
#include <vector>

#include "carmen_reader.hpp"
#include "mspace/params.hpp"
#include "mspace/source.hpp"
#include "wheel_check.hpp"

namespace mspace::carmen_log {

class CarmenLogSource final : public DataSource {
 public:
  /// The declared parameters (file, format, variant, channel, …).
  static std::vector<ParamSpec> param_specs();

  /// Reads the whole file (throws std::runtime_error "file:line: problem").
  explicit CarmenLogSource(const PluginArgs& args);
  /// Replays scans read elsewhere (e.g. from a ROS bag) with the same
  /// odometry, laser odometry and ground-truth handling; `file` names them.
  CarmenLogSource(const PluginArgs& args, LogContents contents);

  bool next(DataStep& step) override;
  std::size_t size_hint() const override { return log_.scans.size(); }
  std::size_t skipped_records() const override { return log_.skipped; }
  Pose6 initial_pose() const override { return initial_pose_; }

  const LogContents& contents() const { return log_; }
  /// The laser's offset on the log's recorded channel (ROBOTLASER1 poses or PARAM lines), if any.
  std::vector<RecordedMount> recorded_mounts() const override;
  /// With `odometry: scan_matched`: the increments matched, and those that
  /// kept the wheel odometry by reason (failed, gap, inconsistent), with the
  /// wheels' spread measured (wheel_check.hpp); the same as the log's
  /// "laser odometry:" line. (Not yet in summary.yaml: that needs a
  /// DataSource hook in the SDK.)
  std::vector<std::pair<std::string, double>> figures() const;
  /// The laser pose on the robot used for laser odometry (x, y, θ).
  const Eigen::Vector3d& laser_mount() const { return mount_; }
  /// With `odometry: scan_matched`, per increment (entry k − 1: scan k − 1 to
  /// k): where it came from (the match, or the wheels and why); else empty.
  const std::vector<scan_matching::IncrementSource>& increment_sources() const { return wheel_check_.source; }
  /// With `odometry: scan_matched`: the wheels' check of the matches (spread measured, χ² of each).
  const scan_matching::WheelCheckResult& wheel_check() const { return wheel_check_; }
  /// Per scan: the covariance of the odometry increment to it, where the
  /// laser odometry gives one (fallbacks under the wheel model, fused
  /// increments, matches with scan_match_covariance); zero elsewhere.
  const std::vector<Eigen::Matrix3d>& increment_covariances() const { return covariances_; }
  /// The wheels' errors as the matched increments measured them, used for
  /// the increments that fall back to the wheels (wheel_check.hpp).
  const scan_matching::WheelModel& wheel_model() const { return wheel_model_; }

 private:
  void scan_match_odometry(const Params& params, Logger& log);
  void ground_truth_from_file(const Params& params, const std::string& file, Logger& log);

  std::string file_;
  LogContents log_;
  std::string channel_;
  bool use_ground_truth_ = true;
  Pose6 initial_pose_ = Pose6::Zero();
  std::size_t next_ = 0;
  Logger* log_out_ = nullptr;
  Eigen::Vector3d mount_ = Eigen::Vector3d::Zero();
  scan_matching::WheelCheckResult wheel_check_;
  bool fuse_wheels_ = false;  ///< scan_match_fuse_wheels
  scan_matching::WheelModel wheel_model_;
  std::vector<Eigen::Matrix3d> covariances_;  ///< per scan: the laser odometry increment's covariance (0: none)
};

}  // namespace mspace::carmen_log
