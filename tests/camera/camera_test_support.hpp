// Shared helpers of the camera tests: scratch folders, the route's poses,
// camera-frame geometry of the rendered world.
#pragma once

#include <unistd.h>

#include <filesystem>
#include <string>
#include <vector>

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

}  // namespace mspace::camera_test
