// image_sequence.hpp — the `image_sequence` data source: a recorded (or
// rendered) ceiling-camera sequence in the folder format of issue 6.
//
//   <folder>/images/...       PNG or JPEG, grey or colour
//   <folder>/frames.csv       t_s,image            (image path relative to the folder)
//   <folder>/odometry.csv     t_s,x_m,y_m,theta_rad (dead-reckoned robot pose)
//   <folder>/camera.yaml      width, height, fx, fy, cx, cy,
//                             distortion: [k1, k2, p1, p2, k3]  (OpenCV model)
//                             mount: [x, y, z, roll, pitch, yaw] (m, DEGREES; camera pose
//                             in the robot frame; robot x forward, y left, z up; camera
//                             z = optical axis, x = image u, y = image v)
//   <folder>/groundtruth.tum  optional: t x y z qx qy qz qw (evaluation only)
//
// In the CSV files blank lines and lines starting with '#' are ignored, and a
// first line naming the columns (e.g. "t_s,image") is allowed.
//
// One DataStep per frame, at the frame's time stamp:
//   - odometry: the increment (dx, dy, dθ) of planar_odometry.hpp between the
//     dead-reckoned poses at the previous and this frame (odometry.csv is
//     interpolated linearly at the frame times; none on the first frame);
//   - one SensorReading on `channel`: `file` = the image's path, `values` =
//     the intrinsics row of camera_model.hpp;
//   - ground_truth: groundtruth.tum interpolated at the frame time, when present
//     and covering it.
// Optional planar laser (for fused laser + camera runs; an extension of the
// issue 6 format, written by the ceiling renderer), both files or neither:
//   <folder>/laser.yaml  beams, first_bearing_deg, bearing_step_deg, max_range,
//                        mount: [x, y, z, roll, pitch, yaw] (m, DEGREES)
//   <folder>/laser.csv   t_s,r_0,...,r_{beams-1}   (m; 0 = no return)
// A scan is delivered with the first frame at or after its stamp, as a
// reading on `laser_channel` with one row (range, bearing) per beam in beam
// order — what the `laser_lines` extractor reads. Its mount, like the
// camera's, must be repeated in the run configuration.
// Frames outside the time span of odometry.csv are skipped (with a warning).
// initial_pose() is the dead-reckoned pose at the first frame: the map frame
// is odometry's frame.
//
// Errors (std::runtime_error) name the file and, where it applies, the line:
// missing files, malformed lines, non-increasing time stamps, missing or
// unreadable images (checked when the source is built), a camera.yaml or
// laser.yaml without a required key or with a value that is not finite.
// With on_malformed: skip, malformed lines of frames.csv, odometry.csv and
// laser.csv are skipped and counted instead (groundtruth.tum stays strict).
//
// The mounts of camera.yaml and laser.yaml are reported as recorded_mounts():
// the run configuration's sensors.<name>.mount must repeat them, and the
// kernel refuses a run where it does not.
//
// The same steps from data read elsewhere (the `rosbag` source compiles this
// file in and builds a sequence from a bag's images and odometry): the
// SequenceContents constructor. Its frames' image paths are where the image
// will be when the step is delivered; this class does not open them.
#pragma once

#include <Eigen/Core>
#include <string>
#include <vector>

#include "camera_model.hpp"
#include "mspace/records.hpp"
#include "mspace/source.hpp"
#include "odometry2d/planar_odometry.hpp"

namespace mspace::image_sequence {

struct Frame {
  double t = 0.0;
  std::string image;  ///< path: the folder joined with the CSV's relative path
  int line = 0;       ///< line in frames.csv (for messages)
};

struct StampedPose2 {
  double t = 0.0;
  Eigen::Vector3d pose = Eigen::Vector3d::Zero();  ///< x, y, θ
};

struct StampedPose6 {
  double t = 0.0;
  Pose6 pose = Pose6::Zero();
};

/// camera.yaml → camera model (mount converted to a Pose6 in radians).
camera::CameraModel read_camera_yaml(const std::string& path);
/// frames.csv; image paths are joined to `folder`. Malformed lines (another
/// width, a field that is not a finite number, a stamp not after the previous
/// one) go to `malformed`: an error "file:line: problem" or a counted skip.
std::vector<Frame> read_frames_csv(const std::string& path, const std::string& folder,
                                   records::MalformedRecords& malformed);
/// odometry.csv (malformed lines as read_frames_csv).
std::vector<StampedPose2> read_odometry_csv(const std::string& path, records::MalformedRecords& malformed);
/// A TUM trajectory file (t x y z qx qy qz qw); ground truth, so always strict.
std::vector<StampedPose6> read_tum(const std::string& path);

struct LaserScans {
  std::vector<double> bearings;  ///< rad, one per beam
  double max_range = 0.0;
  Pose6 mount = Pose6::Zero();
  std::vector<double> t;
  std::vector<Eigen::VectorXd> ranges;  ///< one per scan
};

/// laser.yaml + laser.csv (malformed lines of laser.csv as read_frames_csv;
/// a negative range is malformed too).
LaserScans read_laser(const std::string& yaml_path, const std::string& csv_path,
                      records::MalformedRecords& malformed);

/// The increment x_d that planar_odometry::apply_increment turns `from` into
/// `to` (both (x, y, θ)): the inverse of eq. 25's f.
planar_odometry::Increment increment_between(const Eigen::Vector3d& from,
                                             const Eigen::Vector3d& to);

/// Pose at time t by linear interpolation (angle along the short way);
/// t must lie within [front().t, back().t].
Eigen::Vector3d interpolate(const std::vector<StampedPose2>& poses, double t);

/// A sequence read from somewhere other than a folder; the `origin` strings
/// name where each part came from in messages (and the camera's as the
/// recorded mount's origin).
struct SequenceContents {
  camera::CameraModel camera;
  std::string camera_origin;
  std::vector<Frame> frames;  ///< stamps increasing; `line` is the frame's index in its origin, for messages
  std::string frames_origin;
  std::vector<StampedPose2> odometry;  ///< stamps increasing
  std::string odometry_origin;
  std::vector<StampedPose6> ground_truth;  ///< may be empty
};

class ImageSequence final : public DataSource {
 public:
  static std::vector<ParamSpec> param_specs();

  /// Reads and checks the whole folder (not the image pixels).
  ImageSequence(const std::string& folder, const std::string& channel,
                Logger& log = null_logger(), const std::string& laser_channel = "laser",
                const std::string& on_malformed = "error");
  explicit ImageSequence(const PluginArgs& args);
  /// The steps of `contents` (no laser); frames outside the odometry's time
  /// span are left out as in a folder, with a warning.
  ImageSequence(SequenceContents contents, const std::string& channel, Logger& log = null_logger());

  bool next(DataStep& step) override;
  std::size_t size_hint() const override { return frames_.size(); }
  std::size_t skipped_records() const override { return malformed_.skipped(); }
  Pose6 initial_pose() const override;
  /// The camera's mount (camera.yaml) on `channel`, the laser's (laser.yaml) on `laser_channel`.
  std::vector<RecordedMount> recorded_mounts() const override;

  const camera::CameraModel& camera() const { return camera_; }
  const std::vector<Frame>& frames() const { return frames_; }
  /// The laser scans (empty when the folder has none).
  const LaserScans& laser() const { return laser_; }

 private:
  /// Appends the not yet delivered scans stamped at or before t.
  void add_scans_until(double t, DataStep& step);
  /// Keeps the frames within the odometry's time span (an error when none is).
  void select_frames(std::vector<Frame> frames, const std::string& frames_origin,
                     const std::string& odometry_origin, Logger& log);

  std::string channel_;
  std::string camera_origin_;  ///< camera.yaml's path, or where the contents' camera came from
  camera::CameraModel camera_;
  Eigen::RowVectorXd camera_row_;
  std::vector<Frame> frames_;
  std::vector<StampedPose2> odometry_;
  std::vector<StampedPose6> ground_truth_;
  std::string laser_channel_;
  LaserScans laser_;
  std::string laser_origin_;  ///< laser.yaml's path
  records::MalformedRecords malformed_;
  std::size_t next_frame_ = 0;
  std::size_t next_scan_ = 0;
  Eigen::Vector3d previous_odometry_ = Eigen::Vector3d::Zero();
};

}  // namespace mspace::image_sequence
