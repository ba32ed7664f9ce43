// outputs.hpp — what a run writes: trajectory (TUM), map (YAML), run summary
// (YAML + a one-screen text), and a picture (PNG, picture.cpp).
#pragma once

#include <filesystem>
#include <cstdint>
#include <functional>
#include <map>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "covariance_health.hpp"
#include "evaluation.hpp"
#include "relations.hpp"

namespace mspace::kernel {

class Slam;

/// Everything the summary reports, computed once at the end of a run.
struct RunSummary {
  std::string run_name;
  std::string config_file;
  long long steps = 0;
  double data_seconds = 0.0;  ///< time span covered by the data
  double wall_seconds = 0.0;  ///< elapsed (real) time of the whole run, from its first step
  double source_load_seconds = 0.0;  ///< before the first step: Slam::source_load_seconds()
  int state_dimension = 0;
  /// feature-type instance → M-space dimension → count
  std::map<std::string, std::map<int, int>> features_by_dim;
  std::optional<TrajectoryErrors> errors;  ///< when the source gave ground truth
  double mean_nees = 0.0;
  int nees_dof = 0;
  std::optional<RelationErrors> relations;  ///< when the configuration names a relations file
  /// The dead-reckoning baseline (Slam::dead_reckoning()) measured the same
  /// way as the estimate, when the source gave odometry: against the ground
  /// truth and the relations, whichever the run has.
  struct DeadReckoning {
    std::string odometry;  ///< Slam::odometry_description()
    std::optional<TrajectoryErrors> errors;
    std::optional<RelationErrors> relations;
  };
  std::optional<DeadReckoning> dead_reckoning;
  std::size_t skipped_records = 0;          ///< malformed input records the source skipped
  /// Empty for a complete run; else e.g. "interrupted at step 20000 of 73159 (SIGINT)".
  std::string interrupted;
  /// Empty unless an error stopped the run: the error's message.
  std::string stopped_by_error;
  /// The covariance checks of the run, and the whole covariance at its end
  /// (final_covariance; final_covariance_problem says why it is missing).
  CovarianceHealthReport covariance_health;
  std::optional<CovarianceFigures> final_covariance;
  std::string final_covariance_problem;
};

RunSummary summarize(const Slam& slam, double wall_seconds);

/// Writes `file` atomically: `write` fills a temporary file beside it
/// ("<stem>.writing<ext>"), which then replaces `file` by a rename, so no
/// crash leaves a half-written file under the final name.
void write_atomically(const std::filesystem::path& file,
                      const std::function<void(const std::filesystem::path& temporary)>& write);

/// The trajectory as the run goes: poses are appended to
/// "trajectory.partial.tum" and flushed at least every `flush_seconds` of clock
/// time, so a killed run loses at most that. These are the poses as estimated
/// at each step (a smoother may correct them later); the complete run writes
/// trajectory.tum and removes the partial file.
class TrajectoryStream {
 public:
  /// `frame` is the header's description of the poses (pose_file_frame()).
  TrajectoryStream(const std::filesystem::path& dir, double flush_seconds, const std::string& frame);
  ~TrajectoryStream();
  TrajectoryStream(const TrajectoryStream&) = delete;
  TrajectoryStream& operator=(const TrajectoryStream&) = delete;
  /// Appends the poses from index `written()` on.
  void append(const std::vector<StampedPose>& poses);
  std::size_t written() const { return written_; }
  /// Removes the partial file (after the final trajectory is written).
  void discard();

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
  std::size_t written_ = 0;
};

/// `t x y z qx qy qz qw` per line (TUM RGB-D benchmark format), after '#'
/// header lines: the columns, then `header` (one '#' line per line of it).
/// Positions have 9 decimals (nm), so a third-party tool's ATE on the file
/// agrees with the summary's to ~1e-9 m.
void write_tum(const std::filesystem::path& file, const std::vector<StampedPose>& poses, const std::string& header);

// ---- Pose files and their frames (pose_files.cpp) ---------------------------

/// Which poses a pose file holds.
enum class PoseFile {
  Robot,           ///< trajectory.tum: the robot's estimated poses
  EvaluatedSensor, ///< trajectory_<sensor>.tum: those of evaluation.ground_truth_sensor
  Reference,       ///< ground_truth.tum: the source's reference poses
  DeadReckoning,   ///< dead_reckoning.tum: the odometry alone (the summary's baseline)
};

/// The header text of a pose file: which body frame its poses are of (the
/// robot frame as output.robot_frame names it, or a sensor with its mount)
/// and which frame they are in (the map frame, fixed by the first pose; or
/// the reference's own frame), and how the summary compares them.
std::string pose_file_frame(const Slam& slam, PoseFile which);

/// trajectory.tum, dead_reckoning.tum (the baseline, when it was computed),
/// ground_truth.tum (when the source gave one) and, when the
/// evaluation compares a sensor's poses with it, trajectory_<sensor>.tum;
/// each written atomically with its frame header. Returns the files written.
std::vector<std::filesystem::path> write_pose_files(const std::filesystem::path& dir, const Slam& slam);
/// Every feature: id, type instance, plugin, layout, coordinates, M-space
/// dimension and its covariance block.
void write_map_yaml(const std::filesystem::path& file, const Slam& slam);
void write_summary_yaml(const std::filesystem::path& file, const RunSummary& summary, const Slam& slam);
/// The one-screen summary printed at the end of `mspace run`.
std::string format_summary(const RunSummary& summary, const Slam& slam);
/// Top view of the map, the estimated and the true trajectory (OpenCV).
void write_picture(const std::filesystem::path& file, const Slam& slam, int size_px);

/// What MapFrames wrote, for the line printed at the end of a run.
struct FramesReport {
  std::filesystem::path folder;  ///< <output.dir>/frames
  std::int64_t every = 0;        ///< steps between frames
  int written = 0;
  std::string first, last;   ///< file names of the first and the last frame written
  int view_changes = 0;      ///< times the view had to grow (0: one scale throughout)
  double seconds = 0.0;      ///< elapsed time of drawing and writing them
};

/// Pictures of the map as a run goes (output.frames, `--frames N`; drawn by
/// picture.cpp): the top view of map.png, without the side view, at a fixed
/// size, as <output.dir>/frames/frame_<step>.png after every step that is a
/// multiple of N and after the run's last step, each written atomically;
/// the loop closures so far are marked where the robot was when each closed.
/// One view for all frames, so that an animation does not jump: when the
/// source knows the world (true landmarks), their extent and the start with
/// a tenth of it added on each side; otherwise the extent of the first frame
/// with a quarter of it added on each side (at least 10 m across). When
/// something drawn leaves the view it grows to take it in, a quarter added
/// on each side again, never shrinking (view_changes counts how often). Frames of an earlier run with step numbers after this
/// run's start are removed first, so the folder holds one run's frames.
class MapFrames {
 public:
  /// Before `slam`'s first step (of this process: a resumed run's earlier
  /// loop closures are not known by pose, so they are not marked).
  MapFrames(const std::filesystem::path& output_dir, std::int64_t every, int size_px, const Slam& slam);
  ~MapFrames();
  MapFrames(const MapFrames&) = delete;
  MapFrames& operator=(const MapFrames&) = delete;
  /// After every step: notes a loop closure (RunStats::loop_closures grew)
  /// and writes the step's frame when the step is a multiple of N.
  void after_step(const Slam& slam);
  /// After the last step: its frame, unless after_step wrote it.
  void finish(const Slam& slam);
  const FramesReport& report() const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace mspace::kernel
