#include "route.hpp"

#include <algorithm>
#include <cmath>
#include <limits>
#include <stdexcept>
#include <string>

namespace mspace::sim_world {

using planar_odometry::Increment;

std::vector<Eigen::Vector2d> clover_waypoints(double a, double b) {
  return {
      {a, 0.0},  {a, b},   {0.0, b},  {0.0, 0.0},  // leaf I
      {0.0, -b}, {a, -b},  {a, 0.0},  {0.0, 0.0},  // leaf IV
      {-a, 0.0}, {-a, -b}, {0.0, -b}, {0.0, 0.0},  // leaf III
      {0.0, b},  {-a, b},  {-a, 0.0}, {0.0, 0.0},  // leaf II
  };
}

double route_length(const std::vector<Eigen::Vector2d>& waypoints) {
  double length = 0.0;
  Eigen::Vector2d from = Eigen::Vector2d::Zero();
  for (const Eigen::Vector2d& to : waypoints) {
    length += (to - from).norm();
    from = to;
  }
  return length;
}

namespace {

/// The increment of driving an arc of length `length` while turning by dθ:
/// chord (sin dθ / dθ, (1 − cos dθ) / dθ)·length in the starting frame.
Increment arc_increment(double length, double dtheta) {
  if (std::abs(dtheta) < 1e-9) return {length, 0.5 * length * dtheta, dtheta};
  const double radius = length / dtheta;
  return {radius * std::sin(dtheta), radius * (1.0 - std::cos(dtheta)), dtheta};
}

/// The point `lookahead` metres ahead of p's projection onto the segment
/// from → to, but not beyond `to`: steering at it brings the robot onto the
/// segment's line instead of merely towards its end.
Eigen::Vector2d carrot(const Eigen::Vector2d& p, const Eigen::Vector2d& from,
                       const Eigen::Vector2d& to, double lookahead) {
  const Eigen::Vector2d along = to - from;
  const double length = along.norm();
  const Eigen::Vector2d direction = along / length;
  const double s = std::clamp((p - from).dot(direction) + lookahead, 0.0, length);
  return from + s * direction;
}

/// The turn of one step: towards `target`, at most max_turn per step.
double steer(const Pose6& pose, const Eigen::Vector2d& target, double max_turn) {
  const double bearing = std::atan2(target.y() - pose[kY], target.x() - pose[kX]);
  return std::clamp(wrap_angle(bearing - pose[kTheta]), -max_turn, max_turn);
}

double distance(const Pose6& pose, const Eigen::Vector2d& point) {
  return std::hypot(point.x() - pose[kX], point.y() - pose[kY]);
}

}  // namespace

Trajectory drive_route(const std::vector<Eigen::Vector2d>& waypoints, const DriveSettings& s) {
  const double step = s.speed * s.dt;
  const double max_turn = s.max_turn_rate * s.dt;
  const double reach_distance = std::max(s.speed / s.max_turn_rate, step);
  const std::size_t num_targets = waypoints.size() * static_cast<std::size_t>(s.laps);
  // Generous bound: the route is shorter than this many steps by far.
  const auto max_steps =
      static_cast<std::size_t>(3.0 * s.laps * route_length(waypoints) / step) + 1000;

  Trajectory trajectory;
  trajectory.poses.push_back(Pose6::Zero());
  double previous_final_distance = std::numeric_limits<double>::infinity();
  for (std::size_t target = 0; target < num_targets;) {
    const Pose6& pose = trajectory.poses.back();
    const Eigen::Vector2d& waypoint = waypoints[target % waypoints.size()];
    const Eigen::Vector2d previous =
        target == 0 ? Eigen::Vector2d::Zero() : waypoints[(target - 1) % waypoints.size()];
    const double remaining = distance(pose, waypoint);
    if (target + 1 < num_targets) {
      if (remaining < reach_distance) {
        ++target;
        continue;
      }
    } else if (remaining < 0.5 * step || remaining > previous_final_distance) {
      break;  // at the end of the route (or just past it)
    } else {
      previous_final_distance = remaining;
    }
    if (trajectory.increments.size() >= max_steps) {
      throw std::runtime_error("sim_world: the robot did not complete the route in " +
                               std::to_string(max_steps) +
                               " steps (turn rate too low for the route?)");
    }
    const Eigen::Vector2d aim = carrot(pose.head<2>(), previous, waypoint, reach_distance);
    const Increment increment = arc_increment(step, steer(pose, aim, max_turn));
    trajectory.increments.push_back(increment);
    trajectory.poses.push_back(planar_odometry::apply_increment(pose, increment));
  }
  return trajectory;
}

}  // namespace mspace::sim_world
