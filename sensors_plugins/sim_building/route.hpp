// route.hpp — where the simulated robot drives in a floor plan, how it moves,
// and what its wheel odometry says.
//
// Route (plan_waypoints): along corridor centre lines, starting at the first
// node of loop 0. It drives loop 0, then visits the plan's loops in a seeded
// order (reaching each by the shortest corridor path, driving it in a seeded
// direction), until `length_m` is driven, and ends by driving loop 0 again:
// loops close after long excursions and places are revisited in both
// directions. On a corridor leg it enters a room off that leg with
// probability `room_visit_probability` (door → 1 m inside → room centre, turn
// in place, back out).
//
// Motion (drive): lines at a cruise speed drawn per leg in [min_speed,
// max_speed] with acceleration `accel`; a corner of up to 100° is an arc of
// radius `arc_radius` driven at `arc_speed`; sharper corners, U-turns and the
// turn in a room are turns in place (angular speed ≤ turn_rate, angular
// acceleration turn_accel). The robot state is sampled every `dt` seconds.
//
// Wheel odometry (wheel_odometry): for each true increment (dx, dy, dθ) between
// two samples, with d = |(dx, dy)|,
//   dx' = (1 + scale_error)·dx + σ_xy·√d·n₁,   dy' = (1 + scale_error)·dy + σ_xy·√d·n₂,
//   dθ' = (1 + turn_scale_error)·dθ + heading_bias·d + σ_θ·√d·n₃ + σ_turn·√|dθ|·n₄,
// n_i ~ N(0, 1). The √ makes the white noise independent of dt (variance
// grows with distance / angle, as a random walk). heading_bias (a wheel-radius
// difference) makes the heading drift linearly with distance driven; it and
// scale_error are the drift that carries the odometry outside any association
// gate over a loop.
#pragma once

#include <Eigen/Core>
#include <cstdint>
#include <vector>

#include "floor_plan.hpp"

namespace mspace::sim_building {

/// Planar pose (x, y, θ).
using Pose2 = Eigen::Vector3d;

struct RouteOptions {
  double length_m = 400.0;               ///< drive at least this far before the final lap of loop 0
  double room_visit_probability = 0.25;  ///< per room on a driven corridor leg
  double min_speed = 0.3;                ///< m/s, cruise speeds are drawn in [min, max]
  double max_speed = 1.0;                ///< m/s
  double accel = 0.4;                    ///< m/s²
  double arc_radius = 0.7;               ///< m
  double arc_speed = 0.35;               ///< m/s
  double turn_rate = 0.6;                ///< rad/s
  double turn_accel = 0.8;               ///< rad/s²
  double dt = 0.01;                      ///< s between samples
};

struct RouteSample {
  double t = 0.0;              ///< s since the start
  Pose2 pose = Pose2::Zero();  ///< true robot pose in the plan's frame
  double v = 0.0;              ///< forward speed (m/s)
  double w = 0.0;              ///< turn rate (rad/s)
};

struct Route {
  std::vector<Vec2> waypoints;
  std::vector<RouteSample> samples;
  double length = 0.0;  ///< m actually driven
};

/// The waypoints (see above). Deterministic for (plan, seed).
std::vector<Vec2> plan_waypoints(const FloorPlan& plan, std::uint64_t seed, const RouteOptions& options);

/// Drives the waypoints (see above); the first sample is at waypoints[0],
/// heading towards waypoints[1]. Throws std::invalid_argument for bad options.
Route drive(const std::vector<Vec2>& waypoints, std::uint64_t seed, const RouteOptions& options);

struct OdometryErrors {
  double scale_error = 0.01;             ///< relative error of the distance
  double turn_scale_error = 0.01;        ///< relative error of the turn
  double heading_bias_deg_per_m = 0.05;  ///< heading drift per metre driven
  double xy_noise = 0.005;               ///< σ_xy, m per √m
  double heading_noise_deg = 0.1;        ///< σ_θ, deg per √m
  double turn_noise = 0.01;              ///< σ_turn, rad per √rad turned
};

/// Dead-reckoned odometry pose at every sample, starting at (0, 0, 0).
std::vector<Pose2> wheel_odometry(const std::vector<RouteSample>& samples, const OdometryErrors& errors,
                                  std::uint64_t seed);

/// The pose b seen from pose a (⊖a ⊕ b, mspace::relative in the plane).
Pose2 relative2(const Pose2& a, const Pose2& b);
/// a ⊕ d: the pose reached from a by the increment d given in a's frame (mspace::compound).
Pose2 compose2(const Pose2& a, const Pose2& d);

}  // namespace mspace::sim_building
