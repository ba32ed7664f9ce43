// route.hpp — the simulated robot's route and how it drives it.
//
// The route is a "four-leaf clover" of rectangles around the origin, with
// a = half width and b = half height of the area it covers:
//
//   (-a, b) ─────── (0, b) ─────── (a, b)
//      │  leaf II     │  leaf I      │
//   (-a, 0) ─────── (0, 0) ─────── (a, 0)
//      │  leaf III    │  leaf IV     │
//   (-a,-b) ─────── (0,-b) ─────── (a,-b)
//
// Starting at the origin heading east (θ = 0), one lap drives the four
// rectangles (leaves) I → IV → III → II, each counter-clockwise:
//   I:   (a,0) (a,b) (0,b) (0,0)      — arrives heading south, goes straight on into
//   IV:  (0,-b) (a,-b) (a,0) (0,0)    — arrives heading west, straight on into
//   III: (-a,0) (-a,-b) (0,-b) (0,0)  — arrives heading north, straight on into
//   II:  (0,b) (-a,b) (-a,0) (0,0)    — arrives heading east, as at the start.
// So the robot crosses the origin four times a lap, drives every inner
// half-axis once in each direction and the outer rim once: length 8(a + b) per
// lap, with loop closures inside every lap and again on every further lap.
#pragma once

#include <Eigen/Core>
#include <vector>

#include "mspace/pose.hpp"
#include "odometry2d/planar_odometry.hpp"

namespace mspace::sim_world {

/// The waypoints of one lap (see above); the last one is the origin.
std::vector<Eigen::Vector2d> clover_waypoints(double a, double b);

/// Length of one lap of the polyline from the origin through `waypoints`.
double route_length(const std::vector<Eigen::Vector2d>& waypoints);

struct DriveSettings {
  int laps = 1;
  double speed = 1.0;          ///< m/s
  double dt = 0.1;             ///< s per step
  double max_turn_rate = 1.0;  ///< rad/s
};

/// The driven trajectory: poses[0] is the origin (heading 0), and
/// increments[k] moves poses[k] to poses[k + 1] through planar_odometry's f.
struct Trajectory {
  std::vector<Pose6> poses;
  std::vector<planar_odometry::Increment> increments;
};

/// Drives `laps` laps of the waypoints at constant speed, one circular arc per
/// step, with a turn rate bounded by max_turn_rate. It steers at a point one
/// turning radius (speed / max_turn_rate) ahead on the current leg, so it
/// settles onto the leg's line. A waypoint counts as reached within one
/// turning radius (so 90° corners are rounded with about that radius); the run
/// ends at the last waypoint of the last lap. Throws std::runtime_error if it
/// never gets there.
Trajectory drive_route(const std::vector<Eigen::Vector2d>& waypoints,
                       const DriveSettings& settings);

}  // namespace mspace::sim_world
