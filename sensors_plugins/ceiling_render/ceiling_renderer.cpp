// ceiling_renderer.cpp — see ceiling_renderer.hpp.
#include "ceiling_renderer.hpp"

#include <algorithm>
#include <charconv>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>
#include <stdexcept>

#include "sim_world/route.hpp"
#include "sim_world/sim_random.hpp"

namespace mspace::ceiling_render {
namespace {

namespace fs = std::filesystem;
using planar_odometry::kDegree;
using sim_world::SimRandom;

constexpr std::uint64_t kOdometryStream = 21;
constexpr std::uint64_t kLaserStream = 22;
constexpr std::uint64_t kFirstNoiseStream = 1000;  ///< frame k uses stream 1000 + k

/// Shortest text that reads back as the same double.
std::string num(double x) {
  char buf[64];
  const auto result = std::to_chars(buf, buf + sizeof buf, x);
  return std::string(buf, result.ptr);
}

std::string list(std::initializer_list<double> values) {
  std::string s = "[";
  for (double v : values) {
    if (s.size() > 1) s += ", ";
    s += num(v);
  }
  return s + "]";
}

std::string point(const Eigen::Vector3d& p) { return list({p.x(), p.y(), p.z()}); }

std::ofstream open_for_writing(const fs::path& path) {
  std::ofstream out(path);
  if (!out) throw std::runtime_error(path.string() + ": cannot write");
  return out;
}

void write_camera_yaml(const camera::CameraModel& c, const fs::path& path) {
  std::ofstream out = open_for_writing(path);
  const Eigen::Vector3d rpy(c.mount[kPsi], c.mount[kPhi], c.mount[kTheta]);
  out << "# Rendered ceiling camera (mspace-render-ceiling). mount: camera pose in the robot\n"
      << "# frame [x, y, z (m), roll, pitch, yaw (deg)].\n"
      << "width: " << c.width << "\nheight: " << c.height << "\nfx: " << num(c.fx)
      << "\nfy: " << num(c.fy) << "\ncx: " << num(c.cx) << "\ncy: " << num(c.cy)
      << "\ndistortion: "
      << list({c.distortion[0], c.distortion[1], c.distortion[2], c.distortion[3],
               c.distortion[4]})
      << "\nmount: "
      << list({c.mount[kX], c.mount[kY], c.mount[kZ], rpy[0] / kDegree, rpy[1] / kDegree,
               rpy[2] / kDegree})
      << "\n";
}

void write_segments(std::ofstream& out, const char* key, const std::vector<Segment3>& segments) {
  out << key << ":\n";
  for (const Segment3& s : segments) out << "  - [" << point(s.a) << ", " << point(s.b) << "]\n";
}

/// The true world, for evaluation and pictures (not part of the sequence format).
void write_world_yaml(const CeilingWorld& world, const fs::path& path) {
  std::ofstream out = open_for_writing(path);
  out << "# True geometry of the rendered world (m, map frame = odometry frame at t = 0).\n"
      << "lamps:  # centre x, y, z and radius\n";
  for (const Lamp& lamp : world.lamps()) {
    out << "  - " << list({lamp.centre.x(), lamp.centre.y(), lamp.centre.z(), lamp.radius})
        << "\n";
  }
  write_segments(out, "joints", world.joints());
  write_segments(out, "fixture_edges", world.fixture_edges());
}

double beam_bearing(const LaserSettings& laser, int beam) {
  if (laser.beams == 1) return 0.0;
  const double fov = laser.fov_deg * kDegree;
  return -0.5 * fov + fov * beam / (laser.beams - 1);
}

void write_laser_yaml(const LaserSettings& laser, const fs::path& path) {
  std::ofstream out = open_for_writing(path);
  const double first = beam_bearing(laser, 0) / kDegree;
  const double step = laser.beams > 1 ? (beam_bearing(laser, 1) - beam_bearing(laser, 0)) / kDegree
                                      : 0.0;
  out << "# Planar laser of the rendered sequence. mount: laser pose in the robot frame\n"
      << "# [x, y, z (m), roll, pitch, yaw (deg)]; bearings in degrees.\n"
      << "beams: " << laser.beams << "\nfirst_bearing_deg: " << num(first)
      << "\nbearing_step_deg: " << num(step) << "\nmax_range: " << num(laser.max_range)
      << "\nmount: "
      << list({laser.mount[kX], laser.mount[kY], laser.mount[kZ], laser.mount[kPsi] / kDegree,
               laser.mount[kPhi] / kDegree, laser.mount[kTheta] / kDegree})
      << "\n";
}

/// One scan from the robot pose x_mr: "r_0,r_1,..." (m, 0 = no return).
std::string scan_row(const CeilingWorld& world, const LaserSettings& laser, const Pose6& x_mr,
                     SimRandom& rng) {
  const Pose6 x_ml = compound(x_mr, laser.mount);  // eq. 17
  std::string row;
  for (int i = 0; i < laser.beams; ++i) {
    const double angle = x_ml[kTheta] + beam_bearing(laser, i);
    double r = world.range(x_ml.head<2>(), {std::cos(angle), std::sin(angle)}, laser.max_range);
    if (r > 0.0) r = std::max(0.0, r + laser.range_sigma * rng.normal());
    r = std::round(r * 1e4) / 1e4;  // 0.1 mm
    if (i > 0) row += ',';
    row += num(r);
  }
  return row;
}

/// Dead-reckoned increments: truth + N(0, C_d) + heading drift per metre.
std::vector<planar_odometry::Increment> noisy_increments(
    const std::vector<planar_odometry::Increment>& truth, const SequenceSettings& s) {
  SimRandom rng(s.seed, kOdometryStream);
  std::vector<planar_odometry::Increment> out;
  out.reserve(truth.size());
  for (const planar_odometry::Increment& x_d : truth) {
    const Eigen::Vector3d sigma = s.odometry_noise.sigmas(x_d);
    planar_odometry::Increment noisy = x_d;
    for (int i = 0; i < 3; ++i) noisy[i] += sigma[i] * rng.normal();
    noisy[2] += s.heading_drift_deg_per_m * kDegree * x_d.head<2>().norm();
    out.push_back(noisy);
  }
  return out;
}

std::string frame_name(std::size_t k) {
  char buf[32];
  std::snprintf(buf, sizeof buf, "images/%06zu.png", k);
  return buf;
}

void write_png(const cv::Mat& image, const fs::path& path) {
  if (!cv::imwrite(path.string(), image)) throw std::runtime_error(path.string() + ": cannot write");
}

/// Frame k as the settings' PNG: 8-bit grey, or 16-bit with `bit_depth` bits used.
void write_frame(const CeilingRenderer& renderer, const Pose6& pose, std::size_t k, const fs::path& path) {
  const RenderSettings& s = renderer.settings();
  if (s.bit_depth == 8) {
    GreyImage image = renderer.render(pose, k);
    write_png(cv::Mat(image.height, image.width, CV_8UC1, image.pixels.data()), path);
    return;
  }
  std::vector<float> levels = renderer.render_levels(pose, k);
  cv::Mat deep;
  const double full_scale = std::ldexp(1.0, s.bit_depth) - 1.0;
  // convertTo rounds and saturates to 0–65535; values above full scale are clipped to it below.
  cv::Mat1f(s.camera.height, s.camera.width, levels.data()).convertTo(deep, CV_16U, full_scale / 255.0);
  cv::min(deep, full_scale, deep);
  write_png(deep, path);
}

}  // namespace

camera::CameraModel default_camera() {
  camera::CameraModel c;
  c.width = 320;
  c.height = 240;
  c.fx = c.fy = 260.0;
  c.cx = 159.5;
  c.cy = 119.5;
  c.distortion = {-0.15, 0.03, 0.0005, -0.0003, 0.0};
  c.mount = make_pose(0.1, 0.0, 0.4, 0.0, 0.0, 0.0);
  return c;
}

camera::CameraModel scaled_camera(const camera::CameraModel& c, double scale) {
  camera::CameraModel s = c;
  s.width = static_cast<int>(std::lround(c.width * scale));
  s.height = static_cast<int>(std::lround(c.height * scale));
  s.fx *= scale;
  s.fy *= scale;
  s.cx = (c.cx + 0.5) * scale - 0.5;
  s.cy = (c.cy + 0.5) * scale - 0.5;
  return s;
}

CeilingRenderer::CeilingRenderer(const CeilingWorld& world, const RenderSettings& settings,
                                 std::uint64_t seed)
    : world_(world), settings_(settings), seed_(seed) {
  if (settings_.bit_depth != 8 && (settings_.bit_depth < 10 || settings_.bit_depth > 16))
    throw std::invalid_argument("ceiling renderer: bit_depth must be 8 or 10-16");
  if (settings_.jpeg_quality < 0 || settings_.jpeg_quality > 100)
    throw std::invalid_argument("ceiling renderer: jpeg_quality must be 0-100");
  const camera::CameraModel& c = settings_.camera;
  const int n = settings_.supersampling;
  rays_.reserve(static_cast<std::size_t>(c.width * c.height * n * n));
  pixel_factor_.reserve(static_cast<std::size_t>(c.width * c.height));
  const double corner2 = std::max({c.cx * c.cx, (c.width - 1 - c.cx) * (c.width - 1 - c.cx)}) +
                         std::max({c.cy * c.cy, (c.height - 1 - c.cy) * (c.height - 1 - c.cy)});
  for (int v = 0; v < c.height; ++v) {
    for (int u = 0; u < c.width; ++u) {
      const double r2 = (u - c.cx) * (u - c.cx) + (v - c.cy) * (v - c.cy);
      pixel_factor_.push_back(settings_.gain * (1.0 - settings_.vignetting * r2 / corner2));
      for (int sy = 0; sy < n; ++sy) {
        for (int sx = 0; sx < n; ++sx) {
          // Sub-pixel sample of the distorted image; pixel centres are integers.
          const Eigen::Vector2d uv(u + (sx + 0.5) / n - 0.5, v + (sy + 0.5) / n - 0.5);
          const Eigen::Vector2d xy = c.normalised_from_pixel(uv);
          rays_.emplace_back(xy.x(), xy.y(), 1.0);
        }
      }
    }
  }
}

std::vector<float> CeilingRenderer::render_levels(const Pose6& robot_pose, std::uint64_t frame) const {
  const camera::CameraModel& c = settings_.camera;
  const Pose6 x_mc = compound(robot_pose, c.mount);  // eq. 17
  const Eigen::Matrix3d R = rotation(x_mc);
  const Eigen::Vector3d origin = x_mc.head<3>();
  const int n2 = settings_.supersampling * settings_.supersampling;

  std::vector<float> levels(static_cast<std::size_t>(c.width) * static_cast<std::size_t>(c.height));
  cv::Mat1f image(c.height, c.width, levels.data());
  auto ray = rays_.begin();
  for (int v = 0; v < c.height; ++v) {
    for (int u = 0; u < c.width; ++u) {
      double sum = 0.0;
      for (int s = 0; s < n2; ++s, ++ray) sum += world_.radiance(origin, R * *ray);
      const double factor = pixel_factor_[static_cast<std::size_t>(v) * static_cast<std::size_t>(c.width) +
                                          static_cast<std::size_t>(u)];
      image(v, u) = static_cast<float>(factor * (sum / n2) + settings_.offset);
    }
  }
  if (settings_.blur_sigma > 0.0) {
    cv::GaussianBlur(image, image, cv::Size(0, 0), settings_.blur_sigma);
  }
  if (settings_.noise_sigma > 0.0) {
    SimRandom rng(seed_, kFirstNoiseStream + frame);
    for (float& p : image) p += static_cast<float>(settings_.noise_sigma * rng.normal());
  }
  return levels;
}

GreyImage CeilingRenderer::render(const Pose6& robot_pose, std::uint64_t frame) const {
  const camera::CameraModel& c = settings_.camera;
  std::vector<float> levels = render_levels(robot_pose, frame);
  GreyImage out;
  out.width = c.width;
  out.height = c.height;
  out.pixels.resize(static_cast<std::size_t>(c.width * c.height));
  cv::Mat1b wrapped(c.height, c.width, out.pixels.data());
  cv::Mat1f(c.height, c.width, levels.data()).convertTo(wrapped, CV_8U);  // rounds and saturates to 0–255
  if (settings_.jpeg_quality > 0) {
    std::vector<std::uint8_t> jpeg;
    cv::imencode(".jpg", wrapped, jpeg, {cv::IMWRITE_JPEG_QUALITY, settings_.jpeg_quality});
    cv::imdecode(jpeg, cv::IMREAD_GRAYSCALE).copyTo(wrapped);
  }
  return out;
}

SequenceSummary write_sequence(const SequenceSettings& s, const std::string& folder) {
  const fs::path dir(folder);
  fs::create_directories(dir / "images");
  const CeilingWorld world(s.seed, s.appearance);
  const CeilingRenderer renderer(world, s.render, s.seed);
  const sim_world::Trajectory trajectory = sim_world::drive_route(
      CeilingWorld::route_waypoints(), {1, s.speed, s.dt, s.max_turn_rate});
  const std::vector<planar_odometry::Increment> increments =
      noisy_increments(trajectory.increments, s);

  std::size_t frames = trajectory.poses.size();
  if (s.max_frames > 0) frames = std::min(frames, s.max_frames);

  write_camera_yaml(s.render.camera, dir / "camera.yaml");
  write_world_yaml(world, dir / "world.yaml");
  std::ofstream frames_csv = open_for_writing(dir / "frames.csv");
  std::ofstream odometry_csv = open_for_writing(dir / "odometry.csv");
  std::ofstream truth_tum = open_for_writing(dir / "groundtruth.tum");
  frames_csv << "# rendered by mspace-render-ceiling, seed " << s.seed << "\nt_s,image\n";
  odometry_csv << "# dead-reckoned robot pose\nt_s,x_m,y_m,theta_rad\n";
  truth_tum << "# timestamp tx ty tz qx qy qz qw (true robot pose)\n";
  std::ofstream laser_csv;
  SimRandom laser_rng(s.seed, kLaserStream);
  if (s.laser.enabled) {
    write_laser_yaml(s.laser, dir / "laser.yaml");
    laser_csv = open_for_writing(dir / "laser.csv");
    laser_csv << "# t_s, then one range per beam (m, 0 = no return); bearings in laser.yaml\n";
  }

  SequenceSummary summary;
  Pose6 odometry = trajectory.poses.front();
  for (std::size_t k = 0; k < frames; ++k) {
    const Pose6& truth = trajectory.poses[k];
    if (k > 0) {
      odometry = planar_odometry::apply_increment(odometry, increments[k - 1]);
      summary.path_length += trajectory.increments[k - 1].head<2>().norm();
    }
    const std::string t = num(static_cast<double>(k) * s.dt);
    write_frame(renderer, truth, k, dir / frame_name(k));
    frames_csv << t << "," << frame_name(k) << "\n";
    odometry_csv << t << "," << num(odometry[kX]) << "," << num(odometry[kY]) << ","
                 << num(odometry[kTheta]) << "\n";
    const Eigen::Vector4d q = quaternion_xyzw(truth);
    truth_tum << t << " " << num(truth[kX]) << " " << num(truth[kY]) << " " << num(truth[kZ])
              << " " << num(q[0]) << " " << num(q[1]) << " " << num(q[2]) << " " << num(q[3])
              << "\n";
    if (s.laser.enabled) {
      laser_csv << t << "," << scan_row(world, s.laser, truth, laser_rng) << "\n";
    }
    summary.true_poses.push_back(truth);
    summary.odometry_poses.emplace_back(odometry[kX], odometry[kY], odometry[kTheta]);
  }
  summary.frames = frames;
  return summary;
}

}  // namespace mspace::ceiling_render
