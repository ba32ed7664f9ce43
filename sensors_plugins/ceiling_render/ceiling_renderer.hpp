// ceiling_renderer.hpp — renders what an upward-looking camera on the robot
// sees of a CeilingWorld, and writes whole sequences in the `image_sequence`
// folder format (images/, frames.csv, odometry.csv, camera.yaml,
// groundtruth.tum; plus world.yaml with the true lamps and lines).
//
// Image formation, per pixel: supersampling² rays through sub-pixel positions
// of the *distorted* image (each undistorted with the camera model, so the
// lens distortion is exact), averaged; times the vignetting falloff and the
// exposure gain, plus the offset; then a Gaussian blur (the lens) and Gaussian
// noise (the sensor), rounded and saturated to 8-bit grey (or written with
// more bits, optionally through JPEG compression). The defaults
// (gain 1, offset 0, no vignetting) give the images of the first renderer
// bit for bit; the other settings give the variety other cameras show
// (auto exposure, dark corners, noisier sensors) for the extractors' tests. The noise of frame k
// comes from its own random stream, so a frame does not depend on which
// frames were rendered before it. Everything is deterministic for a seed.
//
// Sequence: the robot drives CeilingWorld::route_waypoints() (sim_world's
// route driver) at `speed`, one frame every dt. Odometry is the true increment
// plus N(0, C_d) noise of planar_odometry.hpp plus a systematic heading drift
// of `heading_drift_deg_per_m` degrees per metre (an uncalibrated wheel base);
// odometry.csv holds the dead-reckoned poses integrated from those increments.
// With the laser enabled, laser.yaml and laser.csv hold planar scans of the
// same rooms (see image_sequence.hpp for their format).
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include "ceiling_world.hpp"
#include "image_sequence/camera_model.hpp"
#include "mspace/pose.hpp"
#include "odometry2d/planar_odometry.hpp"

namespace mspace::ceiling_render {

/// An 8-bit grey image, row-major.
struct GreyImage {
  int width = 0;
  int height = 0;
  std::vector<std::uint8_t> pixels;
  std::uint8_t at(int u, int v) const {
    return pixels[static_cast<std::size_t>(v) * static_cast<std::size_t>(width) +
                  static_cast<std::size_t>(u)];
  }
  camera::GreyView view() const {
    return {width, height, pixels.data(), static_cast<std::size_t>(width)};
  }
};

struct RenderSettings {
  camera::CameraModel camera;  ///< intrinsics, distortion and mount
  int supersampling = 2;       ///< rays per pixel along each axis
  double blur_sigma = 0.7;     ///< Gaussian blur, pixels (0: none)
  double noise_sigma = 2.0;    ///< Gaussian pixel noise, grey levels (0: none)
  double gain = 1.0;           ///< exposure: radiance × gain …
  double offset = 0.0;         ///< … + offset (grey levels), before noise and saturation
  /// Vignetting: radiance × (1 − vignetting · (r / r_corner)²), r the pixel's
  /// distance from the principal point (0: none; 0.4: corners 40 % darker).
  double vignetting = 0.0;
  /// 1–100: every image goes through JPEG compression at this quality (its
  /// block artefacts and ringing), in render() and so in written sequences
  /// (0: none).
  int jpeg_quality = 0;
  /// Bits per pixel of the written PNGs: 8, or 10–16 for 16-bit PNGs whose
  /// values use the low `bit_depth` bits (a 12-bit sensor stores 0–4095):
  /// grey g (0–255) is written as g · (2^bit_depth − 1) / 255, from the
  /// unquantised image.
  int bit_depth = 8;
};

/// The default camera: 320×240, f = 260 px, mild barrel distortion, mounted
/// 0.1 m ahead of the robot centre and 0.4 m above the floor looking straight
/// up (camera x = robot x, camera y = robot y, optical axis = robot z).
camera::CameraModel default_camera();

/// The camera `c` with `scale` times as many pixels along each axis (same
/// field of view and distortion): focal lengths and principal point scaled
/// (pixel centres are integers, so c' = (c + ½)·scale − ½).
camera::CameraModel scaled_camera(const camera::CameraModel& c, double scale);

class CeilingRenderer {
 public:
  CeilingRenderer(const CeilingWorld& world, const RenderSettings& settings, std::uint64_t seed);

  /// The image seen from the robot pose x_mr (camera at x_mr ⊕ mount, T-RO eq. 17);
  /// `frame` selects the noise stream.
  GreyImage render(const Pose6& robot_pose, std::uint64_t frame) const;

  /// The same image before rounding, saturation and JPEG: grey levels as
  /// floats (row-major), for deeper bit depths.
  std::vector<float> render_levels(const Pose6& robot_pose, std::uint64_t frame) const;

  const RenderSettings& settings() const { return settings_; }

 private:
  const CeilingWorld& world_;
  RenderSettings settings_;
  std::uint64_t seed_;
  std::vector<Eigen::Vector3d> rays_;  ///< camera-frame ray of every sub-pixel sample
  std::vector<double> pixel_factor_;   ///< gain × vignetting falloff of every pixel
};

/// The optional planar laser scanner (for a fused laser + camera run): one
/// scan per frame, at the frame's time, beams evenly spread over the field of
/// view centred on the laser's x axis, Gaussian range noise, 0 = no return.
struct LaserSettings {
  bool enabled = true;
  int beams = 181;
  double fov_deg = 180.0;
  double max_range = 8.0;     ///< m
  double range_sigma = 0.01;  ///< m
  Pose6 mount = make_pose(0.0, 0.0, 0.3, 0.0, 0.0, 0.0);  ///< laser pose in the robot frame
};

struct SequenceSettings {
  std::uint64_t seed = 1;
  RenderSettings render{default_camera()};
  Appearance appearance;        ///< grey levels and lamp size of the world
  double speed = 0.4;           ///< m/s
  double dt = 0.1;              ///< s between frames (10 Hz)
  double max_turn_rate = 1.0;   ///< rad/s
  planar_odometry::NoiseModel odometry_noise{0.01, 0.0005, 0.01, 0.005, 0.0002};
  double heading_drift_deg_per_m = 0.5;
  std::size_t max_frames = 0;   ///< 0: the whole route
  LaserSettings laser;
};

struct SequenceSummary {
  std::size_t frames = 0;
  double path_length = 0.0;  ///< m
  std::vector<Pose6> true_poses;
  std::vector<Eigen::Vector3d> odometry_poses;  ///< dead-reckoned (x, y, θ)
};

/// Renders the sequence into `folder` (created; existing files overwritten).
SequenceSummary write_sequence(const SequenceSettings& settings, const std::string& folder);

}  // namespace mspace::ceiling_render
