// mspace/source.hpp — data sources: logs, data sets, simulators. A step carries the
// dead-reckoning increment x_d of T-RO eq. 25, the sensor readings and optional ground truth.
#pragma once

#include <cstdint>
#include <optional>
#include <string>
#include <vector>

#include <Eigen/Core>

#include "mspace/extractor.hpp"
#include "mspace/plugin.hpp"
#include "mspace/pose.hpp"

namespace mspace {

/// Bit mask of all six pose coordinates (see DataStep::ground_truth_known).
inline constexpr std::uint8_t kAllPoseCoords = 0x3F;

/// Everything that happened between the previous step and time t.
struct DataStep {
  double t = 0.0;
  /// Dead-reckoning increment x_d(t, t−1) for the motion model (empty: none).
  Eigen::VectorXd odometry;
  std::vector<SensorReading> readings;
  /// True robot pose at t, when the source knows it (evaluation only).
  std::optional<Pose6> ground_truth;
  /// Which coordinates of ground_truth are known, as bits (1 << PoseIndex):
  /// all six by default; a GPS fix knows only (1 << kX) | (1 << kY).
  std::uint8_t ground_truth_known = kAllPoseCoords;
  /// Covariance of `odometry` for this step when the source knows it (d × d,
  /// e.g. laser odometry from the scan match's information, see
  /// sensors_plugins/scan_matching); empty: the motion model's own noise C_d.
  /// A kernel that honours it uses it as C_d in eq. 26 in place of the model's.
  Eigen::MatrixXd odometry_covariance;
};

/// A sensor mount recorded with the data (e.g. in a camera calibration file).
struct RecordedMount {
  std::string channel;         ///< the channel of that sensor's readings
  Pose6 mount = Pose6::Zero(); ///< x_rs (m, radians)
  std::string origin;          ///< where it is recorded, e.g. "/data/seq/camera.yaml"
};

class DataSource : public PluginObject {
 public:
  /// Fills the next step; false at the end of the data. Malformed input
  /// throws std::runtime_error naming file and line.
  virtual bool next(DataStep& step) = 0;
  /// Number of steps if known in advance (for progress), else 0.
  virtual std::size_t size_hint() const { return 0; }
  /// Initial robot pose in the map frame.
  virtual Pose6 initial_pose() const { return Pose6::Zero(); }
  /// Malformed records skipped so far (when the source is configured to skip
  /// rather than fail); reported in the run summary.
  virtual std::size_t skipped_records() const { return 0; }
  /// Ground-truth landmark positions if known (3 × N), for pictures only.
  virtual Eigen::MatrixXd true_landmarks() const { return {}; }
  /// Sensor mounts the data records. The kernel refuses a run whose
  /// sensors.<name>.mount differs from the recorded mount of its channel (a
  /// configuration that silently disagrees with the calibration is wrong).
  virtual std::vector<RecordedMount> recorded_mounts() const { return {}; }
};

}  // namespace mspace
