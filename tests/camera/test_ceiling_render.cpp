// Tests of the ceiling renderer: determinism for a seed, and that lamps and
// wall/ceiling joints appear where the camera model puts them.
#include <gtest/gtest.h>

#include <fstream>
#include <numbers>
#include <sstream>

#include "camera_test_support.hpp"

namespace mspace {
namespace {

using ceiling_render::CeilingRenderer;
using ceiling_render::CeilingWorld;
using ceiling_render::GreyImage;
using ceiling_render::RenderSettings;

/// Blurred but noise-free images: the geometry tests look at exact greys.
RenderSettings noise_free() {
  RenderSettings s{ceiling_render::default_camera()};
  s.noise_sigma = 0.0;
  return s;
}

std::string file_text(const std::filesystem::path& path) {
  std::ifstream in(path, std::ios::binary);
  std::stringstream text;
  text << in.rdbuf();
  return text.str();
}

/// Pixel where `p_world` projects, if it is at least 2 px inside the image.
std::optional<Eigen::Vector2d> pixel_of(const Eigen::Vector3d& p_world, const Pose6& x_mr,
                                        const camera::CameraModel& camera) {
  Eigen::Vector2d uv;
  if (!camera.project(camera_test::in_camera(p_world, x_mr, camera), uv)) return std::nullopt;
  if (uv.x() < 2 || uv.y() < 2 || uv.x() > camera.width - 3 || uv.y() > camera.height - 3) {
    return std::nullopt;
  }
  return uv;
}

int grey_at(const GreyImage& image, const Eigen::Vector2d& uv) {
  return image.at(static_cast<int>(std::lround(uv.x())), static_cast<int>(std::lround(uv.y())));
}

/// Grey at the pixel where `p_world` projects, or -1 when it is outside the image.
int grey_at(const GreyImage& image, const Eigen::Vector3d& p_world, const Pose6& x_mr,
            const camera::CameraModel& camera) {
  const auto uv = pixel_of(p_world, x_mr, camera);
  return uv ? grey_at(image, *uv) : -1;
}

TEST(CeilingRender, SameSeedSameImagesOtherSeedOtherImages) {
  const CeilingWorld world1(1), world1b(1), world2(2);
  const RenderSettings settings{ceiling_render::default_camera()};
  const Pose6 pose = make_pose2d(1.0, 0.2, 0.3);
  const GreyImage a = CeilingRenderer(world1, settings, 1).render(pose, 7);
  const GreyImage b = CeilingRenderer(world1b, settings, 1).render(pose, 7);
  const GreyImage c = CeilingRenderer(world2, settings, 2).render(pose, 7);
  const GreyImage d = CeilingRenderer(world1, settings, 1).render(pose, 8);
  EXPECT_EQ(a.pixels, b.pixels);
  EXPECT_NE(a.pixels, c.pixels);
  EXPECT_NE(a.pixels, d.pixels);  // another frame, other noise
}

TEST(CeilingRender, WrittenSequencesAreIdenticalForASeed) {
  ceiling_render::SequenceSettings s;
  s.max_frames = 3;
  const auto dir1 = camera_test::scratch_dir("determinism1");
  const auto dir2 = camera_test::scratch_dir("determinism2");
  ceiling_render::write_sequence(s, dir1.string());
  ceiling_render::write_sequence(s, dir2.string());
  for (const char* name : {"frames.csv", "odometry.csv", "groundtruth.tum", "camera.yaml",
                           "world.yaml", "images/000002.png"}) {
    EXPECT_EQ(file_text(dir1 / name), file_text(dir2 / name)) << name;
  }
}

TEST(CeilingRender, LaserRangesFollowTheFloorPlan) {
  const CeilingWorld world(1);
  EXPECT_NEAR(world.range({0.0, 0.0}, {0.0, 1.0}, 8.0), 1.0, 1e-12);   // corridor wall
  EXPECT_NEAR(world.range({0.0, 0.5}, {-1.0, 0.0}, 10.0), 8.0, 1e-12);  // corridor end x = -8
  EXPECT_EQ(world.range({0.0, 0.5}, {1.0, 0.0}, 8.0), 0.0);             // x = 10: too far
  EXPECT_NEAR(world.range({6.0, 0.0}, {0.0, 1.0}, 8.0), 7.2, 1e-12);   // through door B
  EXPECT_NEAR(world.range({5.0, 0.0}, {0.0, 1.0}, 8.0), 1.0, 1e-12);   // beside the door
  const Eigen::Vector2d diagonal = Eigen::Vector2d(1.0, 1.0).normalized();
  EXPECT_NEAR(world.range({0.0, 0.0}, diagonal, 8.0), std::sqrt(2.0), 1e-12);
}

TEST(CeilingRender, TheRouteStaysInFreeSpaceAwayFromWalls) {
  const CeilingWorld world(1);
  const camera::CameraModel camera = ceiling_render::default_camera();
  for (const Pose6& x_mr : camera_test::route_poses(1)) {
    const Pose6 x_mc = compound(x_mr, camera.mount);
    for (const Eigen::Vector2d& offset : {Eigen::Vector2d(0.25, 0), Eigen::Vector2d(-0.25, 0),
                                         Eigen::Vector2d(0, 0.25), Eigen::Vector2d(0, -0.25)}) {
      ASSERT_GE(world.region_at(x_mc.head<2>() + offset), 0) << x_mc.transpose();
    }
  }
}

/// Checks lamp centres and their surroundings along the route; returns how many were in view.
int check_lamps(const RenderSettings& settings) {
  const CeilingWorld world(1);
  const CeilingRenderer renderer(world, settings, 1);
  int checked = 0;
  for (const Pose6& x_mr : camera_test::route_poses(10)) {
    const GreyImage image = renderer.render(x_mr, 0);
    for (const ceiling_render::Lamp& lamp : world.lamps()) {
      const int centre = grey_at(image, lamp.centre, x_mr, settings.camera);
      // 2.5 radii off the centre is plain ceiling (no panel is that close to a lamp).
      const Eigen::Vector3d off = lamp.centre + Eigen::Vector3d(2.5 * lamp.radius, 0, 0);
      const int outside = grey_at(image, off, x_mr, settings.camera);
      if (centre < 0 || outside < 0) continue;
      ++checked;
      EXPECT_GE(centre, 254) << "lamp at " << lamp.centre.transpose();
      EXPECT_LE(outside, 215) << "beside lamp at " << lamp.centre.transpose();
    }
  }
  return checked;
}

TEST(CeilingRender, LampsAppearWhereTheCameraModelProjectsThem) {
  EXPECT_GE(check_lamps(noise_free()), 60);
}

TEST(CeilingRender, LampsAppearWhereTheCameraModelProjectsThemWithATiltedTurnedMount) {
  RenderSettings settings = noise_free();
  const double deg = std::numbers::pi / 180.0;
  // Camera turned 90° about the optical axis, pitched 8° and rolled 5°.
  settings.camera.mount = make_pose(0.05, -0.1, 0.45, 90 * deg, 8 * deg, 5 * deg);
  EXPECT_GE(check_lamps(settings), 60);
}

TEST(CeilingRender, JointsSeparateCeilingFromWallWhereTheCameraModelSaysSo) {
  const CeilingWorld world(1);
  const RenderSettings settings = noise_free();
  const CeilingRenderer renderer(world, settings, 1);
  const double wall_top = world.appearance().wall_grey_high;
  int checked = 0;
  for (const Pose6& x_mr : camera_test::route_poses(10)) {
    const GreyImage image = renderer.render(x_mr, 0);
    const Pose6 x_mc = compound(x_mr, settings.camera.mount);
    const int region = world.region_at(x_mc.head<2>());
    for (const ceiling_render::Segment3& joint : world.joints()) {
      if (std::abs(joint.a.z() - world.regions()[static_cast<std::size_t>(region)].ceiling_z) >
          1e-9) {
        continue;  // another room's joint
      }
      // Unit normal of the joint pointing into the camera's room (horizontal).
      const Eigen::Vector3d t = (joint.b - joint.a).normalized();
      Eigen::Vector3d n(-t.y(), t.x(), 0.0);
      if (n.dot(x_mc.head<3>() - joint.a) < 0) n = -n;
      for (double s = 0.05; s < 1.0; s += 0.05) {
        const Eigen::Vector3d p = joint.a + s * (joint.b - joint.a);
        const auto on_joint = pixel_of(p, x_mr, settings.camera);
        const auto ceiling_side = pixel_of(p + 0.06 * n, x_mr, settings.camera);
        const auto wall_side = pixel_of(p - Eigen::Vector3d(0, 0, 0.06), x_mr, settings.camera);
        if (!on_joint || !ceiling_side || !wall_side) continue;
        // Seen from nearly below, a wall is edge-on: skip sides blurred into the joint.
        if ((*ceiling_side - *on_joint).norm() < 3 || (*wall_side - *on_joint).norm() < 3) continue;
        const int ceiling = grey_at(image, *ceiling_side);
        const int wall = grey_at(image, *wall_side);
        ++checked;
        EXPECT_GE(ceiling, 140) << "ceiling side of joint at " << p.transpose();
        EXPECT_LE(wall, wall_top + 1) << "wall side of joint at " << p.transpose();
      }
    }
  }
  EXPECT_GE(checked, 200);
}

}  // namespace
}  // namespace mspace
