// image_sequence.cpp — see image_sequence.hpp.
#include "image_sequence.hpp"

#include <yaml-cpp/yaml.h>

#include <Eigen/Geometry>
#include <algorithm>
#include <charconv>
#include <filesystem>
#include <fstream>
#include <functional>
#include <opencv2/imgcodecs.hpp>
#include <stdexcept>

namespace mspace::image_sequence {
namespace {

namespace fs = std::filesystem;
using planar_odometry::kDegree;

/// "file:line: " — the prefix of every error about a line of a file.
std::string at(const std::string& path, int line) {
  return path + ":" + std::to_string(line) + ": ";
}

std::string trim(std::string_view s) {
  const auto first = s.find_first_not_of(" \t\r");
  if (first == std::string_view::npos) return {};
  const auto last = s.find_last_not_of(" \t\r");
  return std::string(s.substr(first, last - first + 1));
}

/// Splits on `separator` (',' or any run of blanks when separator is ' ').
std::vector<std::string> split(const std::string& line, char separator) {
  std::vector<std::string> fields;
  std::string field;
  for (char ch : line) {
    const bool cut = separator == ' ' ? (ch == ' ' || ch == '\t') : ch == separator;
    if (!cut) {
      field += ch;
    } else if (separator != ' ' || !field.empty()) {
      fields.push_back(trim(field));
      field.clear();
    }
  }
  if (separator != ' ' || !field.empty()) fields.push_back(trim(field));
  return fields;
}

bool parse_double(const std::string& text, double& value) {
  const char* end = text.data() + text.size();
  const auto result = std::from_chars(text.data(), end, value);
  return result.ec == std::errc() && result.ptr == end && std::isfinite(value);
}

/// Calls `row(fields, line)` for every data line of a text file; skips blank
/// and '#' lines and a first line that does not start with a number (a header).
void for_each_row(const std::string& path, char separator, std::size_t columns,
                  const std::function<void(const std::vector<std::string>&, int)>& row) {
  std::ifstream in(path);
  if (!in) throw std::runtime_error(path + ": cannot open file");
  std::string text;
  bool first_data_line = true;
  for (int line = 1; std::getline(in, text); ++line) {
    const std::string content = trim(text);
    if (content.empty() || content[0] == '#') continue;
    const std::vector<std::string> fields = split(content, separator);
    double ignored = 0.0;
    const bool header = first_data_line && !parse_double(fields[0], ignored);
    first_data_line = false;
    if (header) continue;
    if (fields.size() != columns) {
      throw std::runtime_error(at(path, line) + "expected " + std::to_string(columns) +
                               " columns, found " + std::to_string(fields.size()));
    }
    row(fields, line);
  }
}

double number(const std::string& field, const std::string& path, int line, const char* what) {
  double value = 0.0;
  if (!parse_double(field, value)) {
    throw std::runtime_error(at(path, line) + "'" + field + "' is not a finite number (" + what +
                             ")");
  }
  return value;
}

/// Throws unless t is larger than the previous stamp of the same file.
void check_increasing(double t, double previous, bool has_previous, const std::string& path,
                      int line) {
  if (has_previous && !(t > previous)) {
    throw std::runtime_error(at(path, line) + "time stamp " + std::to_string(t) +
                             " s is not after the previous one (" + std::to_string(previous) +
                             " s); stamps must increase");
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
  try {
    return node.as<T>();
  } catch (const YAML::Exception&) {
    throw std::runtime_error(at(path, node.Mark().line + 1) + "key '" + key +
                             "' has the wrong type");
  }
}

std::vector<double> yaml_list(const YAML::Node& root, const char* key, std::size_t size,
                              const std::string& path) {
  const auto values = yaml_value<std::vector<double>>(root, key, path);
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

std::vector<Frame> read_frames_csv(const std::string& path, const std::string& folder) {
  require_file(path, "frame list (frames.csv)");
  std::vector<Frame> frames;
  for_each_row(path, ',', 2, [&](const std::vector<std::string>& f, int line) {
    const double t = number(f[0], path, line, "t_s");
    check_increasing(t, frames.empty() ? 0.0 : frames.back().t, !frames.empty(), path, line);
    if (f[1].empty()) throw std::runtime_error(at(path, line) + "empty image path");
    frames.push_back({t, (fs::path(folder) / f[1]).string(), line});
  });
  if (frames.empty()) throw std::runtime_error(path + ": no frames");
  return frames;
}

std::vector<StampedPose2> read_odometry_csv(const std::string& path) {
  require_file(path, "odometry (odometry.csv)");
  std::vector<StampedPose2> poses;
  static const char* const names[] = {"t_s", "x_m", "y_m", "theta_rad"};
  for_each_row(path, ',', 4, [&](const std::vector<std::string>& f, int line) {
    StampedPose2 p;
    p.t = number(f[0], path, line, names[0]);
    for (int i = 0; i < 3; ++i) p.pose[i] = number(f[i + 1], path, line, names[i + 1]);
    check_increasing(p.t, poses.empty() ? 0.0 : poses.back().t, !poses.empty(), path, line);
    poses.push_back(p);
  });
  if (poses.size() < 2) throw std::runtime_error(path + ": needs at least two poses");
  return poses;
}

std::vector<StampedPose6> read_tum(const std::string& path) {
  require_file(path, "TUM trajectory");
  std::vector<StampedPose6> poses;
  for_each_row(path, ' ', 8, [&](const std::vector<std::string>& f, int line) {
    double v[8];
    for (int i = 0; i < 8; ++i) v[i] = number(f[static_cast<std::size_t>(i)], path, line, "TUM");
    check_increasing(v[0], poses.empty() ? 0.0 : poses.back().t, !poses.empty(), path, line);
    const Eigen::Quaterniond q(v[7], v[4], v[5], v[6]);  // (w, x, y, z)
    if (std::abs(q.norm() - 1.0) > 1e-3) {
      throw std::runtime_error(at(path, line) + "quaternion is not of unit length");
    }
    StampedPose6 p;
    p.t = v[0];
    p.pose.head<3>() = Eigen::Vector3d(v[1], v[2], v[3]);
    p.pose.tail<3>() = euler_from_rotation(q.normalized().toRotationMatrix());
    poses.push_back(p);
  });
  return poses;
}

LaserScans read_laser(const std::string& yaml_path, const std::string& csv_path) {
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

  for_each_row(csv_path, ',', static_cast<std::size_t>(beams) + 1,
               [&](const std::vector<std::string>& f, int line) {
                 const double t = number(f[0], csv_path, line, "t_s");
                 check_increasing(t, scans.t.empty() ? 0.0 : scans.t.back(), !scans.t.empty(),
                                  csv_path, line);
                 Eigen::VectorXd r(beams);
                 for (int i = 0; i < beams; ++i) {
                   r[i] = number(f[static_cast<std::size_t>(i) + 1], csv_path, line, "range");
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
  };
}

ImageSequence::ImageSequence(const std::string& folder, const std::string& channel, Logger& log,
                             const std::string& laser_channel)
    : folder_(folder), channel_(channel), laser_channel_(laser_channel) {
  const fs::path dir(folder);
  if (!fs::is_directory(dir)) throw std::runtime_error(folder + ": not a folder");
  camera_ = read_camera_yaml((dir / "camera.yaml").string());
  camera_row_ = camera::reading_row(camera_);
  const std::string frames_csv = (dir / "frames.csv").string();
  std::vector<Frame> frames = read_frames_csv(frames_csv, folder);
  check_images(frames, frames_csv);
  odometry_ = read_odometry_csv((dir / "odometry.csv").string());
  const std::string tum = (dir / "groundtruth.tum").string();
  if (fs::exists(tum)) ground_truth_ = read_tum(tum);
  const fs::path laser_yaml = dir / "laser.yaml", laser_csv = dir / "laser.csv";
  if (fs::exists(laser_yaml) || fs::exists(laser_csv)) {
    laser_ = read_laser(laser_yaml.string(), laser_csv.string());
  }

  for (Frame& frame : frames) {
    if (covers(odometry_, frame.t)) frames_.push_back(std::move(frame));
  }
  if (frames_.empty()) {
    throw std::runtime_error(frames_csv + ": no frame lies within the time span of odometry.csv");
  }
  if (frames_.size() < frames.size()) {
    log.warn(frames.size() - frames_.size(), " frames of ", frames_csv,
             " lie outside the odometry time span and are skipped");
  }
  log.info("image sequence ", folder, ": ", frames_.size(), " frames ", camera_.width, "x",
           camera_.height, ", f = ", camera_.focal(), " px",
           ground_truth_.empty() ? ", no ground truth" : ", with ground truth", ", ",
           laser_.t.size(), " laser scans");
}

ImageSequence::ImageSequence(const PluginArgs& args)
    : ImageSequence(args.params.get_string("folder"), args.params.get_string("channel"),
                    args.log(), args.params.get_string("laser_channel")) {}

Pose6 ImageSequence::initial_pose() const {
  const Eigen::Vector3d p = interpolate(odometry_, frames_.front().t);
  return make_pose2d(p[0], p[1], p[2]);
}

std::vector<RecordedMount> ImageSequence::recorded_mounts() const {
  std::vector<RecordedMount> mounts{{channel_, camera_.mount, (fs::path(folder_) / "camera.yaml").string()}};
  if (!laser_.t.empty()) mounts.push_back({laser_channel_, laser_.mount, (fs::path(folder_) / "laser.yaml").string()});
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
