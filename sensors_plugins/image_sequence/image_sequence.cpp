// image_sequence.cpp — see image_sequence.hpp.
#include "image_sequence.hpp"

#include <yaml-cpp/yaml.h>

#include <Eigen/Geometry>
#include <algorithm>
#include <filesystem>
#include <fstream>
#include <functional>
#include <opencv2/imgcodecs.hpp>
#include <stdexcept>
#include <string_view>
#include <type_traits>

namespace mspace::image_sequence {
namespace {

namespace fs = std::filesystem;
using planar_odometry::kDegree;

using records::at;

/// A problem with one record; for_each_row adds "file:line: " and reports it
/// to the file's MalformedRecords (an error, or a counted skip).
struct RecordError : std::runtime_error {
  using std::runtime_error::runtime_error;
};

using Fields = std::vector<std::string_view>;

/// Calls `row(fields, line)` for every data line of a text file; skips blank
/// and '#' lines and a first line that does not start with a number (a
/// header). A line of another width, or one for which `row` throws a
/// RecordError, goes to `malformed`.
void for_each_row(const std::string& path, char separator, std::size_t columns, records::MalformedRecords& malformed,
                  const std::function<void(const Fields&, int)>& row) {
  std::ifstream in(path);
  if (!in) throw std::runtime_error(path + ": cannot open file");
  std::string text;
  bool first_data_line = true;
  for (int line = 1; std::getline(in, text); ++line) {
    const Fields fields = records::split(text, separator);
    const bool blank = fields.empty() || (fields.size() == 1 && fields[0].empty());
    if (blank || fields[0].front() == '#') continue;
    double ignored = 0.0;
    const bool header = first_data_line && !records::parse_finite(fields[0], ignored);
    first_data_line = false;
    if (header) continue;
    try {
      if (fields.size() != columns)
        throw RecordError("expected " + std::to_string(columns) + " columns, found " + std::to_string(fields.size()));
      row(fields, line);
    } catch (const RecordError& e) {
      malformed.report(path, line, e.what());
    }
  }
}

double number(std::string_view field, const char* what) {
  double value = 0.0;
  if (!records::parse_finite(field, value))
    throw RecordError("'" + std::string(field) + "' is not a finite number (" + what + ")");
  return value;
}

/// Throws a RecordError unless t is larger than the previous stamp of the same file.
void check_increasing(double t, double previous, bool has_previous) {
  if (has_previous && !(t > previous)) {
    throw RecordError("time stamp " + std::to_string(t) + " s is not after the previous one (" +
                      std::to_string(previous) + " s); stamps must increase");
  }
}

void require_file(const std::string& path, const char* what) {
  if (!fs::is_regular_file(path)) {
    throw std::runtime_error(path + ": missing " + std::string(what));
  }
}

template <class T>
T yaml_value(const YAML::Node& root, const char* key, const std::string& path) {
  const YAML::Node node = root[key];
  if (!node) throw std::runtime_error(path + ": missing key '" + key + "'");
  T value;
  try {
    value = node.as<T>();
  } catch (const YAML::Exception&) {
    throw std::runtime_error(at(path, node.Mark().line + 1) + "key '" + key +
                             "' has the wrong type");
  }
  if constexpr (std::is_floating_point_v<T>) {
    if (!std::isfinite(value))
      throw std::runtime_error(at(path, node.Mark().line + 1) + "key '" + key + "' is not a finite number");
  }
  return value;
}

std::vector<double> yaml_list(const YAML::Node& root, const char* key, std::size_t size,
                              const std::string& path) {
  const auto values = yaml_value<std::vector<double>>(root, key, path);
  for (double v : values)
    if (!std::isfinite(v))
      throw std::runtime_error(at(path, root[key].Mark().line + 1) + "'" + key + "' holds a value that is not finite");
  if (values.size() != size) {
    throw std::runtime_error(at(path, root[key].Mark().line + 1) + "'" + key + "' needs " +
                             std::to_string(size) + " numbers, has " +
                             std::to_string(values.size()));
  }
  return values;
}

Pose6 slerp_pose(const Pose6& a, const Pose6& b, double s) {
  const Eigen::Quaterniond qa(rotation(a));
  const Eigen::Quaterniond qb(rotation(b));
  const Eigen::Matrix3d R = qa.slerp(s, qb).toRotationMatrix();
  Pose6 p;
  p.head<3>() = (1.0 - s) * a.head<3>() + s * b.head<3>();
  p.tail<3>() = euler_from_rotation(R);
  return p;
}

/// Index i with stamps[i].t <= t <= stamps[i + 1].t (stamps sorted, t inside).
template <class Stamped>
std::size_t bracket(const std::vector<Stamped>& stamps, double t) {
  const auto upper = std::upper_bound(stamps.begin(), stamps.end(), t,
                                      [](double x, const Stamped& s) { return x < s.t; });
  const auto i = static_cast<std::size_t>(upper - stamps.begin());
  return std::min(i == 0 ? 0 : i - 1, stamps.size() - 2);
}

template <class Stamped>
bool covers(const std::vector<Stamped>& stamps, double t) {
  return stamps.size() >= 2 && t >= stamps.front().t && t <= stamps.back().t;
}

std::optional<Pose6> ground_truth_at(const std::vector<StampedPose6>& truth, double t) {
  if (truth.size() == 1 && truth.front().t == t) return truth.front().pose;
  if (!covers(truth, t)) return std::nullopt;
  const std::size_t i = bracket(truth, t);
  const double s = (t - truth[i].t) / (truth[i + 1].t - truth[i].t);
  return slerp_pose(truth[i].pose, truth[i + 1].pose, s);
}

void check_images(const std::vector<Frame>& frames, const std::string& frames_csv) {
  for (const Frame& frame : frames) {
    if (!fs::is_regular_file(frame.image)) {
      throw std::runtime_error(at(frames_csv, frame.line) + "image '" + frame.image +
                               "' does not exist");
    }
    if (!cv::haveImageReader(frame.image)) {
      throw std::runtime_error(at(frames_csv, frame.line) + "image '" + frame.image +
                               "' is not a readable image (PNG or JPEG expected)");
    }
  }
}

}  // namespace

camera::CameraModel read_camera_yaml(const std::string& path) {
  require_file(path, "camera description (camera.yaml)");
  YAML::Node root;
  try {
    root = YAML::LoadFile(path);
  } catch (const YAML::Exception& e) {
    throw std::runtime_error(at(path, e.mark.line + 1) + e.msg);
  }
  camera::CameraModel c;
  c.width = yaml_value<int>(root, "width", path);
  c.height = yaml_value<int>(root, "height", path);
  c.fx = yaml_value<double>(root, "fx", path);
  c.fy = yaml_value<double>(root, "fy", path);
  c.cx = yaml_value<double>(root, "cx", path);
  c.cy = yaml_value<double>(root, "cy", path);
  if (c.width < 1 || c.height < 1 || !(c.fx > 0.0) || !(c.fy > 0.0)) {
    throw std::runtime_error(path + ": width, height, fx and fy must be positive");
  }
  const std::vector<double> k = yaml_list(root, "distortion", 5, path);
  std::copy(k.begin(), k.end(), c.distortion.begin());
  const std::vector<double> m = yaml_list(root, "mount", 6, path);
  // camera.yaml gives [x, y, z, roll, pitch, yaw]; Pose6 is (x, y, z, yaw, pitch, roll).
  c.mount = make_pose(m[0], m[1], m[2], m[5] * kDegree, m[4] * kDegree, m[3] * kDegree);
  return c;
}

std::vector<Frame> read_frames_csv(const std::string& path, const std::string& folder,
                                   records::MalformedRecords& malformed) {
  require_file(path, "frame list (frames.csv)");
  std::vector<Frame> frames;
  for_each_row(path, ',', 2, malformed, [&](const Fields& f, int line) {
    const double t = number(f[0], "t_s");
    check_increasing(t, frames.empty() ? 0.0 : frames.back().t, !frames.empty());
    if (f[1].empty()) throw RecordError("empty image path");
    frames.push_back({t, (fs::path(folder) / f[1]).string(), line});
  });
  if (frames.empty()) throw std::runtime_error(path + ": no frames");
  return frames;
}

std::vector<StampedPose2> read_odometry_csv(const std::string& path, records::MalformedRecords& malformed) {
  require_file(path, "odometry (odometry.csv)");
  std::vector<StampedPose2> poses;
  static const char* const names[] = {"t_s", "x_m", "y_m", "theta_rad"};
  for_each_row(path, ',', 4, malformed, [&](const Fields& f, int) {
    StampedPose2 p;
    p.t = number(f[0], names[0]);
    for (int i = 0; i < 3; ++i) p.pose[i] = number(f[i + 1], names[i + 1]);
    check_increasing(p.t, poses.empty() ? 0.0 : poses.back().t, !poses.empty());
    poses.push_back(p);
  });
  if (poses.size() < 2) throw std::runtime_error(path + ": needs at least two poses");
  return poses;
}

std::vector<StampedPose6> read_tum(const std::string& path) {
  require_file(path, "TUM trajectory");
  records::MalformedRecords strict;  // ground truth: never skipped (mspace/records.hpp)
  std::vector<StampedPose6> poses;
  for_each_row(path, ' ', 8, strict, [&](const Fields& f, int) {
    double v[8];
    for (int i = 0; i < 8; ++i) v[i] = number(f[static_cast<std::size_t>(i)], "TUM");
    check_increasing(v[0], poses.empty() ? 0.0 : poses.back().t, !poses.empty());
    const Eigen::Quaterniond q(v[7], v[4], v[5], v[6]);  // (w, x, y, z)
    if (std::abs(q.norm() - 1.0) > 1e-3) throw RecordError("quaternion is not of unit length");
    StampedPose6 p;
    p.t = v[0];
    p.pose.head<3>() = Eigen::Vector3d(v[1], v[2], v[3]);
    p.pose.tail<3>() = euler_from_rotation(q.normalized().toRotationMatrix());
    poses.push_back(p);
  });
  return poses;
}

LaserScans read_laser(const std::string& yaml_path, const std::string& csv_path,
                      records::MalformedRecords& malformed) {
  require_file(yaml_path, "laser description (laser.yaml)");
  require_file(csv_path, "laser scans (laser.csv)");
  YAML::Node root;
  try {
    root = YAML::LoadFile(yaml_path);
  } catch (const YAML::Exception& e) {
    throw std::runtime_error(at(yaml_path, e.mark.line + 1) + e.msg);
  }
  LaserScans scans;
  const int beams = yaml_value<int>(root, "beams", yaml_path);
  if (beams < 1) throw std::runtime_error(yaml_path + ": 'beams' must be positive");
  const double first = yaml_value<double>(root, "first_bearing_deg", yaml_path) * kDegree;
  const double step = yaml_value<double>(root, "bearing_step_deg", yaml_path) * kDegree;
  for (int i = 0; i < beams; ++i) scans.bearings.push_back(first + i * step);
  scans.max_range = yaml_value<double>(root, "max_range", yaml_path);
  const std::vector<double> m = yaml_list(root, "mount", 6, yaml_path);
  scans.mount = make_pose(m[0], m[1], m[2], m[5] * kDegree, m[4] * kDegree, m[3] * kDegree);

  for_each_row(csv_path, ',', static_cast<std::size_t>(beams) + 1, malformed,
               [&](const Fields& f, int) {
                 const double t = number(f[0], "t_s");
                 check_increasing(t, scans.t.empty() ? 0.0 : scans.t.back(), !scans.t.empty());
                 Eigen::VectorXd r(beams);
                 for (int i = 0; i < beams; ++i) {
                   r[i] = number(f[static_cast<std::size_t>(i) + 1], "range");
                   if (r[i] < 0.0) throw RecordError("negative range");
                 }
                 scans.t.push_back(t);
                 scans.ranges.push_back(std::move(r));
               });
  return scans;
}

planar_odometry::Increment increment_between(const Eigen::Vector3d& from,
                                             const Eigen::Vector3d& to) {
  // Inverse of f (eq. 25): rotate the displacement back into `from`'s frame.
  const double c = std::cos(from[2]);
  const double s = std::sin(from[2]);
  const double dx = to[0] - from[0];
  const double dy = to[1] - from[1];
  return {c * dx + s * dy, -s * dx + c * dy, wrap_angle(to[2] - from[2])};
}

Eigen::Vector3d interpolate(const std::vector<StampedPose2>& poses, double t) {
  const std::size_t i = bracket(poses, t);
  const double s = (t - poses[i].t) / (poses[i + 1].t - poses[i].t);
  const Eigen::Vector3d& a = poses[i].pose;
  const Eigen::Vector3d& b = poses[i + 1].pose;
  Eigen::Vector3d p = a + s * (b - a);
  p[2] = wrap_angle(a[2] + s * wrap_angle(b[2] - a[2]));
  return p;
}

std::vector<ParamSpec> ImageSequence::param_specs() {
  return {
      required(param_string("folder", "",
                            "sequence folder (images/, frames.csv, odometry.csv, camera.yaml, "
                            "optional groundtruth.tum)")),
      param_string("channel", "camera", "channel name of the image readings"),
      param_string("laser_channel", "laser",
                   "channel name of the laser scans (laser.yaml + laser.csv, when present)"),
      records::on_malformed_param(),
  };
}

ImageSequence::ImageSequence(const std::string& folder, const std::string& channel, Logger& log,
                             const std::string& laser_channel, const std::string& on_malformed)
    : channel_(channel), laser_channel_(laser_channel), malformed_(on_malformed) {
  const fs::path dir(folder);
  if (!fs::is_directory(dir)) throw std::runtime_error(folder + ": not a folder");
  camera_origin_ = (dir / "camera.yaml").string();
  camera_ = read_camera_yaml(camera_origin_);
  camera_row_ = camera::reading_row(camera_);
  const std::string frames_csv = (dir / "frames.csv").string();
  std::vector<Frame> frames = read_frames_csv(frames_csv, folder, malformed_);
  check_images(frames, frames_csv);
  const std::string odometry_csv = (dir / "odometry.csv").string();
  odometry_ = read_odometry_csv(odometry_csv, malformed_);
  const std::string tum = (dir / "groundtruth.tum").string();
  if (fs::exists(tum)) ground_truth_ = read_tum(tum);
  const fs::path laser_yaml = dir / "laser.yaml", laser_csv = dir / "laser.csv";
  if (fs::exists(laser_yaml) || fs::exists(laser_csv)) {
    laser_ = read_laser(laser_yaml.string(), laser_csv.string(), malformed_);
    laser_origin_ = laser_yaml.string();
  }
  if (malformed_.skipped() > 0)
    log.warn("image sequence ", folder, ": skipped ", malformed_.skipped(), " malformed record(s); the first: ",
             malformed_.first_problem());
  select_frames(std::move(frames), frames_csv, odometry_csv, log);
  log.info("image sequence ", folder, ": ", frames_.size(), " frames ", camera_.width, "x",
           camera_.height, ", f = ", camera_.focal(), " px",
           ground_truth_.empty() ? ", no ground truth" : ", with ground truth", ", ",
           laser_.t.size(), " laser scans");
}

ImageSequence::ImageSequence(SequenceContents contents, const std::string& channel, Logger& log)
    : channel_(channel),
      camera_origin_(std::move(contents.camera_origin)),
      camera_(contents.camera),
      camera_row_(camera::reading_row(contents.camera)),
      odometry_(std::move(contents.odometry)),
      ground_truth_(std::move(contents.ground_truth)),
      malformed_("error") {
  if (odometry_.size() < 2)
    throw std::runtime_error(contents.odometry_origin + ": " + std::to_string(odometry_.size()) +
                             " odometry pose(s); at least two are needed to interpolate at the frames");
  select_frames(std::move(contents.frames), contents.frames_origin, contents.odometry_origin, log);
}

void ImageSequence::select_frames(std::vector<Frame> frames, const std::string& frames_origin,
                                  const std::string& odometry_origin, Logger& log) {
  for (Frame& frame : frames) {
    if (covers(odometry_, frame.t)) frames_.push_back(std::move(frame));
  }
  if (frames_.empty()) {
    throw std::runtime_error(frames_origin + ": no frame lies within the time span of " + odometry_origin);
  }
  if (frames_.size() < frames.size()) {
    log.warn(frames.size() - frames_.size(), " frames of ", frames_origin, " lie outside the time span of ",
             odometry_origin, " and are skipped");
  }
}

ImageSequence::ImageSequence(const PluginArgs& args)
    : ImageSequence(args.params.get_string("folder"), args.params.get_string("channel"),
                    args.log(), args.params.get_string("laser_channel"),
                    args.params.get_string("on_malformed")) {}

Pose6 ImageSequence::initial_pose() const {
  const Eigen::Vector3d p = interpolate(odometry_, frames_.front().t);
  return make_pose2d(p[0], p[1], p[2]);
}

std::vector<RecordedMount> ImageSequence::recorded_mounts() const {
  std::vector<RecordedMount> mounts{{channel_, camera_.mount, camera_origin_}};
  if (!laser_.t.empty()) mounts.push_back({laser_channel_, laser_.mount, laser_origin_});
  return mounts;
}

bool ImageSequence::next(DataStep& step) {
  if (next_frame_ >= frames_.size()) return false;
  const Frame& frame = frames_[next_frame_];
  step = DataStep{};
  step.t = frame.t;
  const Eigen::Vector3d odometry = interpolate(odometry_, frame.t);
  if (next_frame_ > 0) step.odometry = increment_between(previous_odometry_, odometry);
  previous_odometry_ = odometry;
  step.ground_truth = ground_truth_at(ground_truth_, frame.t);

  SensorReading reading;
  reading.channel = channel_;
  reading.t = frame.t;
  reading.values = camera_row_;
  reading.file = frame.image;
  step.readings.push_back(std::move(reading));
  add_scans_until(frame.t, step);
  ++next_frame_;
  return true;
}

}  // namespace mspace::image_sequence

namespace mspace::image_sequence {

void ImageSequence::add_scans_until(double t, DataStep& step) {
  const auto beams = static_cast<Eigen::Index>(laser_.bearings.size());
  for (; next_scan_ < laser_.t.size() && laser_.t[next_scan_] <= t; ++next_scan_) {
    SensorReading scan;
    scan.channel = laser_channel_;
    scan.t = laser_.t[next_scan_];
    scan.values.resize(beams, 2);
    scan.values.col(0) = laser_.ranges[next_scan_];
    scan.values.col(1) = Eigen::Map<const Eigen::VectorXd>(laser_.bearings.data(), beams);
    step.readings.push_back(std::move(scan));
  }
}

}  // namespace mspace::image_sequence
