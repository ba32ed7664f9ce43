// Shared helpers of the camera tests: scratch folders, the route's poses,
// camera-frame geometry of the rendered world.
#pragma once

#include <unistd.h>

#include <filesystem>
#include <string>
#include <vector>

#include "build_path.hpp"
#include "ceiling_render/ceiling_renderer.hpp"
#include "mspace/coords.hpp"
#include "mspace/pose.hpp"
#include "mspace/transform.hpp"
#include "sim_world/route.hpp"

namespace mspace::camera_test {

/// An empty scratch folder under the build tree, private to this process:
/// CTest runs the test cases of one executable as separate processes in
/// parallel, and they must not clear each other's folders.
inline std::filesystem::path scratch_dir(const std::string& name) {
  const std::filesystem::path dir = std::filesystem::path(MSPACE_BINARY_DIR) / "test_tmp" / "camera" /
                                    (name + "-" + std::to_string(::getpid()));
  std::filesystem::remove_all(dir);
  std::filesystem::create_directories(dir);
  return dir;
}

/// Every `stride`-th true robot pose of the renderer's route.
inline std::vector<Pose6> route_poses(std::size_t stride) {
  const ceiling_render::SequenceSettings s;
  const sim_world::Trajectory trajectory = sim_world::drive_route(
      ceiling_render::CeilingWorld::route_waypoints(), {1, s.speed, s.dt, s.max_turn_rate});
  std::vector<Pose6> poses;
  for (std::size_t k = 0; k < trajectory.poses.size(); k += stride)
    poses.push_back(trajectory.poses[k]);
  return poses;
}

/// A world point in the frame of the camera on a robot at x_mr, with the
/// SDK's transforms (x_ms = x_mr ⊕ x_rs, eq. 17; map → sensor frame, eq. 7).
inline Eigen::Vector3d in_camera(const Eigen::Vector3d& p_world, const Pose6& x_mr,
                                 const camera::CameraModel& camera) {
  const Pose6 x_mc = compound(x_mr, camera.mount);
  return to_sensor_frame(CoordLayout{BlockKind::Point3D}, p_world, x_mc);
}

/// One rendering variant: what another camera, exposure or building does to
/// the images (defaults: the first renderer's), for the extractors' sweeps.
struct RenderVariant {
  const char* name;
  double gain = 1.0, offset = 0.0, vignetting = 0.0, noise = 2.0, blur = 0.7;
  double lamp_grey = 255.0, lamp_radius = 0.10, tile_darkening = 30.0, distortion_scale = 1.0;
  // Other lamps and other cameras (ceiling_world.hpp, ceiling_renderer.hpp).
  ceiling_render::LampShape lamp_shape = ceiling_render::LampShape::Disc;
  double lamp_aspect = 1.0, lamp_grey_spread = 0.0, lamp_falloff = 0.0;
  double ring_width = 0.0, ring_grey = 70.0, halo_grey = 0.0, halo_width = 0.1;
  double panel_grey = 238.0;
  bool lamps = true;
  double scale = 1.0;  ///< resolution: times 320×240
  int supersampling = 2, jpeg_quality = 0;

  ceiling_render::RenderSettings settings() const {
    ceiling_render::RenderSettings s{ceiling_render::scaled_camera(ceiling_render::default_camera(), scale)};
    for (double& k : s.camera.distortion) k *= distortion_scale;
    s.gain = gain;
    s.offset = offset;
    s.vignetting = vignetting;
    s.noise_sigma = noise;
    s.blur_sigma = blur;
    s.supersampling = supersampling;
    s.jpeg_quality = jpeg_quality;
    return s;
  }
  ceiling_render::Appearance appearance() const {
    ceiling_render::Appearance a;
    a.lamp_grey = lamp_grey;
    a.lamp_radius = lamp_radius;
    a.tile_line_darkening = tile_darkening;
    a.lamps = lamps;
    a.lamp_shape = lamp_shape;
    a.lamp_aspect = lamp_aspect;
    a.lamp_grey_spread = lamp_grey_spread;
    a.lamp_falloff = lamp_falloff;
    a.ring_width = ring_width;
    a.ring_grey = ring_grey;
    a.halo_grey = halo_grey;
    a.halo_width = halo_width;
    a.fixture_grey = panel_grey;
    return a;
  }
};

/// The sweep: exposure, noise, vignetting, blur, smaller/dimmer lamps,
/// texture and distortion, and all of what the issue reports of another
/// renderer at once (lamps 0.12–0.15 m across a little below full white,
/// pixel noise σ 6, plus auto exposure and vignetting).
inline std::vector<RenderVariant> render_variants() {
  std::vector<RenderVariant> v;
  auto add = [&](const char* name, auto&& change) {
    RenderVariant r{name};
    change(r);
    v.push_back(r);
  };
  add("default", [](RenderVariant&) {});
  add("dark exposure (gain 0.6)", [](RenderVariant& r) { r.gain = 0.6; });
  // Brighter still and the brightest room's ceiling saturates around its
  // lamps: nothing can see them there (measured: 80 % recall at gain 1.15).
  add("bright exposure (gain 1.1)", [](RenderVariant& r) { r.gain = 1.1; });
  add("noisy sensor (sigma 6)", [](RenderVariant& r) { r.noise = 6.0; });
  add("vignetting 0.4", [](RenderVariant& r) { r.vignetting = 0.4; });
  add("blurred (sigma 1.5 px)", [](RenderVariant& r) { r.blur = 1.5; });
  // Both at once: every gradient about half the default's (ceiling_lines'
  // relative thresholds are for this; the absolute ones lose room B's lines).
  add("dark and blurred (gain 0.6, blur 1.2)", [](RenderVariant& r) {
    r.gain = 0.6;
    r.blur = 1.2;
  });
  add("dim small lamps (235, r 0.065 m)", [](RenderVariant& r) {
    r.lamp_grey = 235.0;
    r.lamp_radius = 0.065;
  });
  add("strong texture, 2x distortion", [](RenderVariant& r) {
    r.tile_darkening = 60.0;
    r.distortion_scale = 2.0;
  });
  add("other renderer (all of it, gain 0.85)", [](RenderVariant& r) {
    r.gain = 0.85;
    r.noise = 6.0;
    r.lamp_grey = 240.0;
    r.lamp_radius = 0.065;
    r.vignetting = 0.2;
  });
  return v;
}

}  // namespace mspace::camera_test
