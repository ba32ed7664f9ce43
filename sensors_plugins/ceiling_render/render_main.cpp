// mspace-render-ceiling — writes a rendered ceiling-camera sequence in the
// `image_sequence` folder format (see ceiling_renderer.hpp).
//
//   mspace-render-ceiling --out data/ceiling --seed 1 [--frames 300]
#include <CLI/CLI.hpp>
#include <cstdio>
#include <exception>

#include "ceiling_renderer.hpp"

int main(int argc, char** argv) {
  using mspace::ceiling_render::SequenceSettings;
  SequenceSettings settings;
  std::string out;
  CLI::App app{"Render a ceiling-camera image sequence (images/, frames.csv, odometry.csv, "
               "camera.yaml, groundtruth.tum, world.yaml)"};
  app.add_option("--out", out, "output folder")->required();
  app.add_option("--seed", settings.seed, "random seed (world jitter, odometry and pixel noise)");
  app.add_option("--frames", settings.max_frames, "stop after this many frames (0: whole route)");
  app.add_option("--speed", settings.speed, "robot speed (m/s)")->check(CLI::PositiveNumber);
  bool no_laser = false;
  app.add_flag("--no-laser", no_laser, "no planar laser scans (laser.yaml, laser.csv): camera-only runs");
  app.add_option("--heading-drift", settings.heading_drift_deg_per_m,
                 "systematic odometry heading drift (deg per m)");
  app.add_option("--noise", settings.render.noise_sigma, "pixel noise std (grey levels)")
      ->check(CLI::NonNegativeNumber);
  app.add_option("--blur", settings.render.blur_sigma, "Gaussian blur std (pixels)")
      ->check(CLI::NonNegativeNumber);
  app.add_option("--gain", settings.render.gain, "exposure gain (grey = gain * radiance + offset)")
      ->check(CLI::PositiveNumber);
  app.add_option("--offset", settings.render.offset, "exposure offset (grey levels)");
  app.add_option("--vignetting", settings.render.vignetting,
                 "corner darkening: 1 - v * (r / r_corner)^2 (0: none)")
      ->check(CLI::Range(0.0, 1.0));
  app.add_option("--lamp-grey", settings.appearance.lamp_grey, "lamp radiance (grey levels)")
      ->check(CLI::PositiveNumber);
  app.add_option("--lamp-radius", settings.appearance.lamp_radius, "lamp disc radius (m)")
      ->check(CLI::PositiveNumber);
  app.add_option("--tile-darkening", settings.appearance.tile_line_darkening,
                 "ceiling texture: grey-level drop of the tile grid lines")
      ->check(CLI::NonNegativeNumber);
  auto& a = settings.appearance;
  std::string shape = "disc";
  app.add_option("--lamp-shape", shape, "lamp outline: disc, square or rounded (a square with rounded corners)")
      ->check(CLI::IsMember({"disc", "square", "rounded"}));
  app.add_option("--lamp-aspect", a.lamp_aspect, "square/rounded lamps: length / width (1: square)")
      ->check(CLI::Range(1.0, 10.0));
  app.add_option("--lamp-grey-spread", a.lamp_grey_spread,
                 "each lamp's grey is lamp-grey * (1 - spread * U(0,1)) (lamps of different brightness)")
      ->check(CLI::Range(0.0, 1.0));
  app.add_option("--lamp-falloff", a.lamp_falloff, "lamps dimmer towards the rim: * (1 - falloff * s^2)")
      ->check(CLI::Range(0.0, 1.0));
  app.add_option("--ring-width", a.ring_width, "fixture ring around each lamp (m, 0: none)")
      ->check(CLI::NonNegativeNumber);
  app.add_option("--ring-grey", a.ring_grey, "fixture ring grey level")->check(CLI::NonNegativeNumber);
  app.add_option("--halo-grey", a.halo_grey, "glow around each lamp: grey levels added at its rim (0: none)")
      ->check(CLI::NonNegativeNumber);
  app.add_option("--halo-width", a.halo_width, "glow fall-off distance (m)")->check(CLI::PositiveNumber);
  app.add_option("--panel-grey", a.fixture_grey, "light panel grey level (brighter than lamps: a bright non-lamp)")
      ->check(CLI::NonNegativeNumber);
  bool no_lamps = false;
  app.add_flag("--no-lamps", no_lamps, "a ceiling without lamps (panels and lines only)");
  double scale = 1.0;
  app.add_option("--scale", scale, "image resolution: times the default 320x240 (same field of view)")
      ->check(CLI::Range(0.25, 8.0));
  app.add_option("--supersampling", settings.render.supersampling, "rays per pixel along each axis")
      ->check(CLI::Range(1, 8));
  app.add_option("--jpeg-quality", settings.render.jpeg_quality,
                 "pass every image through JPEG compression at this quality (1-100, 0: none)")
      ->check(CLI::Range(0, 100));
  app.add_option("--bit-depth", settings.render.bit_depth,
                 "8, or 10-16: 16-bit PNGs whose values use that many bits (12: 0-4095)")
      ->check(CLI::Range(8, 16));
  double distortion_scale = 1.0;
  app.add_option("--distortion-scale", distortion_scale,
                 "multiplies the default lens distortion coefficients (0: a pinhole camera)")
      ->check(CLI::NonNegativeNumber);
  CLI11_PARSE(app, argc, argv);
  settings.laser.enabled = !no_laser;
  a.lamps = !no_lamps;
  a.lamp_shape = shape == "square"    ? mspace::ceiling_render::LampShape::Square
                 : shape == "rounded" ? mspace::ceiling_render::LampShape::RoundedSquare
                                      : mspace::ceiling_render::LampShape::Disc;
  settings.render.camera = mspace::ceiling_render::scaled_camera(settings.render.camera, scale);
  for (double& k : settings.render.camera.distortion) k *= distortion_scale;
  try {
    const auto summary = mspace::ceiling_render::write_sequence(settings, out);
    std::printf("%zu frames, %.1f m of path, written to %s\n", summary.frames,
                summary.path_length, out.c_str());
  } catch (const std::exception& e) {
    std::fprintf(stderr, "mspace-render-ceiling: %s\n", e.what());
    return 1;
  }
  return 0;
}
