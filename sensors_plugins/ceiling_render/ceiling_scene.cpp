// ceiling_scene.cpp — see ceiling_scene.hpp.
#include "ceiling_scene.hpp"

#include <unistd.h>  // close

#include <cerrno>
#include <cmath>
#include <cstdlib>  // mkstemps
#include <cstring>
#include <array>
#include <filesystem>
#include <numbers>
#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>
#include <stdexcept>
#include <system_error>

#include "ceiling_renderer.hpp"
#include "ceiling_world.hpp"
#include "sim_world/sim_random.hpp"

namespace mspace::ceiling_render {
namespace {

using sim_world::SimRandom;

constexpr std::uint64_t kSceneStream = 41;  ///< the scenes' own random stream of a seed
constexpr double kMargin = 8.0;             ///< px: objects stay this far inside the image
constexpr double kGap = 0.25;               ///< m between objects
constexpr int kAttempts = 500;              ///< placements tried per scene
constexpr double kStripHalfLength = 6.0;    ///< m: a light strip is longer than the view
constexpr double kMinVisible = 1.2;         ///< m of each strip edge well inside the image

/// The camera of a scene: the default camera on a robot at a pose drawn from
/// the seed, under a flat ceiling 1.9–2.5 m above it. The camera is level
/// (its mount has no roll or pitch), so its z axis is the map's.
struct SceneView {
  camera::CameraModel camera = default_camera();
  Pose6 robot = Pose6::Zero();
  Pose6 x_ms = Pose6::Zero();  ///< camera pose in the map, x_mr ⊕ mount (T-RO eq. 17)
  double ceiling_z = 0.0;      ///< m above the floor

  explicit SceneView(SimRandom& rng) {
    robot = make_pose(rng.uniform(-3.0, 3.0), rng.uniform(-3.0, 3.0), 0.0,
                      rng.uniform(-std::numbers::pi, std::numbers::pi), 0.0, 0.0);
    x_ms = compound(robot, camera.mount);
    ceiling_z = x_ms[kZ] + rng.uniform(1.9, 2.5);
  }

  /// The ceiling point seen at the undistorted normalised image coordinates
  /// (x, y): (d·x, d·y, d) in the camera frame, d the ceiling's height above
  /// the camera; its z set to ceiling_z exactly (the renderer draws a lamp or
  /// panel on the region whose ceiling_z equals its height).
  Eigen::Vector3d on_ceiling(double x, double y) const {
    const double d = ceiling_z - x_ms[kZ];
    Eigen::Vector3d p = rotation(x_ms) * Eigen::Vector3d(d * x, d * y, d) + x_ms.head<3>();
    p.z() = ceiling_z;
    return p;
  }

  /// Whether the map point p is seen at least kMargin px inside the image.
  bool well_inside(const Eigen::Vector3d& p) const {
    Eigen::Vector2d uv;
    if (!camera.project(rotation(x_ms).transpose() * (p - x_ms.head<3>()), uv)) return false;
    return uv.x() >= kMargin && uv.y() >= kMargin && uv.x() <= camera.width - 1.0 - kMargin &&
           uv.y() <= camera.height - 1.0 - kMargin;
  }

  /// The noise-free image of `world` (the renderer's default blur, the lens;
  /// no pixel noise), written to `files`, as an image_sequence reading.
  SensorReading render(const CeilingWorld& world, std::uint64_t seed, SceneImageFiles& files) const {
    RenderSettings settings{camera};
    settings.noise_sigma = 0.0;
    const CeilingRenderer renderer(world, settings, seed);
    SensorReading reading;
    reading.channel = "camera";
    reading.values = camera::reading_row(camera);
    reading.file = files.write(renderer.render(robot, 0));
    return reading;
  }

  /// One flat ceiling of grey `grey`, wider than the view (no wall in sight).
  Region ceiling(double grey) const {
    constexpr double kHalf = 30.0;  // m; the view is about 3 m × 2.3 m
    const Box2 box{x_ms[kX] - kHalf, x_ms[kY] - kHalf, x_ms[kX] + kHalf, x_ms[kY] + kHalf};
    return {box, ceiling_z, grey, false, false};
  }
};

bool boxes_apart(const Box2& a, const Box2& b, double gap) {
  return a.x1 + gap < b.x0 || b.x1 + gap < a.x0 || a.y1 + gap < b.y0 || b.y1 + gap < a.y0;
}

}  // namespace

SceneImageFiles::~SceneImageFiles() {
  for (const std::string& path : paths_) {
    std::error_code ignored;  // a file already gone is fine
    std::filesystem::remove(path, ignored);
  }
}

std::string SceneImageFiles::write(const GreyImage& image) {
  std::string path = (std::filesystem::temp_directory_path() / "mspace-scene-XXXXXX.png").string();
  const int fd = ::mkstemps(path.data(), 4);  // creates the file under a name no one else has
  if (fd < 0) {
    throw std::runtime_error(path + ": cannot create a temporary file for a sample scene's image: " +
                             std::strerror(errno));
  }
  ::close(fd);
  {
    const std::lock_guard lock(mutex_);
    paths_.push_back(path);  // registered before writing: deleted even if writing fails
  }
  const cv::Mat wrapped(image.height, image.width, CV_8UC1, const_cast<std::uint8_t*>(image.pixels.data()));
  if (!cv::imwrite(path, wrapped)) throw std::runtime_error(path + ": cannot write a sample scene's image");
  return path;
}

SampleScene lamp_scene(std::uint64_t seed, SceneImageFiles& files) {
  SimRandom rng(seed, kSceneStream);
  const SceneView view(rng);
  const std::size_t wanted = 2 + static_cast<std::size_t>(rng.uniform(0.0, 3.0));
  std::vector<Lamp> lamps;
  for (int attempt = 0; attempt < kAttempts && lamps.size() < wanted; ++attempt) {
    Lamp lamp;
    lamp.radius = rng.uniform(0.08, 0.12);
    lamp.centre = view.on_ceiling(rng.uniform(-0.6, 0.6), rng.uniform(-0.45, 0.45));
    bool ok = true;
    // Whole and inside: a ring a little wider than the lamp (the blur) in view.
    constexpr int kRim = 32;
    for (int k = 0; k < kRim && ok; ++k) {
      const double a = 2.0 * std::numbers::pi * k / kRim;
      ok = view.well_inside(lamp.centre + (lamp.radius + 0.02) * Eigen::Vector3d(std::cos(a), std::sin(a), 0.0));
    }
    for (const Lamp& other : lamps)
      ok = ok && (other.centre - lamp.centre).norm() > other.radius + lamp.radius + kGap;
    if (ok) lamps.push_back(lamp);
  }
  if (lamps.size() < 2) throw std::logic_error("lamp_scene: fewer than two lamps placed (seed " + std::to_string(seed) + ")");

  SampleScene scene;
  scene.x_ms = view.x_ms;
  for (const Lamp& lamp : lamps) {
    TrueShape point;
    point.kind = TrueShape::Kind::Point;
    point.a = lamp.centre;
    scene.truth.push_back(point);
  }
  const CeilingWorld world({view.ceiling(rng.uniform(150.0, 210.0))}, {}, std::move(lamps));
  scene.reading = view.render(world, seed, files);
  return scene;
}

SampleScene panel_scene(std::uint64_t seed, SceneImageFiles& files) {
  SimRandom rng(seed, kSceneStream);
  const SceneView view(rng);
  // Long light strips along the map's x or y axis (all the same way, so none
  // crosses another), each passing near the middle of the view; only their
  // two long edges show, across much of the image.
  const bool along_x = rng.uniform() < 0.5;
  const std::size_t wanted = 1 + static_cast<std::size_t>(rng.uniform(0.0, 2.0));
  std::vector<Fixture> strips;
  std::vector<Segment3> edges;
  for (int attempt = 0; attempt < kAttempts && strips.size() < wanted; ++attempt) {
    const double half_width = rng.uniform(0.15, 0.3);
    const Eigen::Vector3d c = view.on_ceiling(rng.uniform(-0.3, 0.3), rng.uniform(-0.2, 0.2));
    const Box2 box = along_x ? Box2{c.x() - kStripHalfLength, c.y() - half_width, c.x() + kStripHalfLength, c.y() + half_width}
                             : Box2{c.x() - half_width, c.y() - kStripHalfLength, c.x() + half_width, c.y() + kStripHalfLength};
    const double z = view.ceiling_z;
    const std::array<Segment3, 2> long_edges =
        along_x ? std::array<Segment3, 2>{Segment3{{box.x0, box.y0, z}, {box.x1, box.y0, z}},
                                          Segment3{{box.x0, box.y1, z}, {box.x1, box.y1, z}}}
                : std::array<Segment3, 2>{Segment3{{box.x0, box.y0, z}, {box.x0, box.y1, z}},
                                          Segment3{{box.x1, box.y0, z}, {box.x1, box.y1, z}}};
    // Each edge well inside the image over at least kMinVisible (m, on the
    // ceiling): points every 2 cm along it.
    bool ok = true;
    for (const Segment3& e : long_edges) {
      const int n = static_cast<int>((e.b - e.a).norm() / 0.02);
      int inside = 0;
      for (int k = 0; k <= n; ++k) inside += view.well_inside(e.a + (e.b - e.a) * k / n) ? 1 : 0;
      ok = ok && inside * 0.02 >= kMinVisible;
    }
    for (const Fixture& other : strips) ok = ok && boxes_apart(other.box, box, kGap);
    if (!ok) continue;
    strips.push_back({box, z});
    edges.insert(edges.end(), long_edges.begin(), long_edges.end());
  }
  if (strips.empty()) throw std::logic_error("panel_scene: no light strip placed (seed " + std::to_string(seed) + ")");

  const CeilingWorld world({view.ceiling(rng.uniform(150.0, 200.0))}, std::move(strips), {});
  SampleScene scene;
  scene.x_ms = view.x_ms;
  for (const Segment3& edge : edges) {
    TrueShape line;
    line.kind = TrueShape::Kind::Segment;
    line.a = edge.a;
    line.b = edge.b;
    scene.truth.push_back(line);
  }
  scene.reading = view.render(world, seed, files);
  return scene;
}

}  // namespace mspace::ceiling_render
