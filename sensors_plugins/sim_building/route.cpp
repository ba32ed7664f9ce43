// route.cpp — see route.hpp.
#include "route.hpp"

#include <algorithm>
#include <cmath>
#include <limits>
#include <map>
#include <numbers>
#include <stdexcept>
#include <string>

#include "mspace/pose.hpp"
#include "sim_world/sim_random.hpp"

namespace mspace::sim_building {
namespace {

using sim_world::SimRandom;
constexpr double kPi = std::numbers::pi;

Pose6 to6(const Pose2& p) { return make_pose2d(p[0], p[1], p[2]); }
Pose2 to2(const Pose6& p) { return {p[kX], p[kY], p[kTheta]}; }

/// Shortest corridor path (node indices, from → to inclusive), Dijkstra.
std::vector<int> shortest_path(const FloorPlan& plan, int from, int to) {
  const std::size_t n = plan.nodes.size();
  std::vector<double> dist(n, std::numeric_limits<double>::infinity());
  std::vector<int> prev(n, -1);
  std::vector<bool> done(n, false);
  dist[static_cast<std::size_t>(from)] = 0.0;
  for (std::size_t round = 0; round < n; ++round) {
    int u = -1;
    for (std::size_t i = 0; i < n; ++i)
      if (!done[i] && (u < 0 || dist[i] < dist[static_cast<std::size_t>(u)])) u = static_cast<int>(i);
    if (u < 0 || !std::isfinite(dist[static_cast<std::size_t>(u)])) break;
    done[static_cast<std::size_t>(u)] = true;
    for (const auto& [a, b] : plan.edges) {
      if (a != u && b != u) continue;
      const int v = a == u ? b : a;
      const double d = dist[static_cast<std::size_t>(u)] +
                       (plan.nodes[static_cast<std::size_t>(a)] - plan.nodes[static_cast<std::size_t>(b)]).norm();
      if (d < dist[static_cast<std::size_t>(v)]) {
        dist[static_cast<std::size_t>(v)] = d;
        prev[static_cast<std::size_t>(v)] = u;
      }
    }
  }
  std::vector<int> path;
  for (int v = to; v >= 0; v = prev[static_cast<std::size_t>(v)]) {
    path.push_back(v);
    if (v == from) break;
  }
  if (path.back() != from) throw std::runtime_error("floor plan: corridor graph is not connected");
  std::reverse(path.begin(), path.end());
  return path;
}

int edge_index(const FloorPlan& plan, int u, int v) {
  for (std::size_t e = 0; e < plan.edges.size(); ++e)
    if ((plan.edges[e].first == u && plan.edges[e].second == v) ||
        (plan.edges[e].first == v && plan.edges[e].second == u))
      return static_cast<int>(e);
  throw std::runtime_error("floor plan: no corridor between nodes " + std::to_string(u) + " and " + std::to_string(v));
}

class WaypointPlanner {
 public:
  WaypointPlanner(const FloorPlan& plan, std::uint64_t seed, const RouteOptions& o)
      : plan_(plan), rng_(seed, 0x20u), options_(o) {}

  /// Drives the corridor from the current node to v, entering rooms on the way.
  void leg(int v) {
    const Vec2 a = plan_.nodes[static_cast<std::size_t>(current_)], b = plan_.nodes[static_cast<std::size_t>(v)];
    const int e = edge_index(plan_, current_, v);
    std::vector<const Room*> rooms;
    for (const Room& r : plan_.rooms)
      if (r.edge == e) rooms.push_back(&r);
    std::sort(rooms.begin(), rooms.end(), [&](const Room* p, const Room* q) {
      return (p->door_outside - a).norm() < (q->door_outside - a).norm();
    });
    for (const Room* r : rooms) {
      if (rng_.uniform() >= options_.room_visit_probability) continue;
      add(r->door_outside), add(r->door_inside);
      if ((r->centre - r->door_inside).norm() > 0.3) add(r->centre);
      add(r->door_inside), add(r->door_outside);
    }
    add(b);
    current_ = v;
  }

  void go_to(int node) {
    const std::vector<int> path = shortest_path(plan_, current_, node);
    for (std::size_t k = 1; k < path.size(); ++k) leg(path[k]);
  }

  /// Drives loop i once around from the loop node nearest (along corridors)
  /// to the current node, in direction dir (±1).
  void loop(std::size_t i, int dir) {
    const std::vector<int>& nodes = plan_.loops[i];
    std::size_t entry = 0;
    double best = std::numeric_limits<double>::infinity();
    for (std::size_t k = 0; k < nodes.size(); ++k) {
      const std::vector<int> p = shortest_path(plan_, current_, nodes[k]);
      double d = 0.0;
      for (std::size_t m = 1; m < p.size(); ++m)
        d += (plan_.nodes[static_cast<std::size_t>(p[m])] - plan_.nodes[static_cast<std::size_t>(p[m - 1])]).norm();
      if (d < best) best = d, entry = k;
    }
    go_to(nodes[entry]);
    const std::size_t n = nodes.size();
    for (std::size_t k = 1; k <= n; ++k) {
      const std::size_t idx = dir > 0 ? (entry + k) % n : (entry + n * k - k) % n;
      leg(nodes[idx]);
    }
  }

  std::vector<Vec2> run() {
    current_ = plan_.loops.at(0).at(0);
    add(plan_.nodes[static_cast<std::size_t>(current_)]);
    loop(0, +1);
    std::vector<std::size_t> order(plan_.loops.size());
    for (std::size_t i = 0; i < order.size(); ++i) order[i] = i;
    std::size_t next = 1;  // loop 0 was first; go on with the others, then reshuffle
    while (length_ < options_.length_m) {
      if (next >= order.size()) {
        for (std::size_t i = order.size(); i > 1; --i) std::swap(order[i - 1], order[rng_.index(i)]);
        next = 0;
      }
      loop(order[next++], rng_.uniform() < 0.5 ? +1 : -1);
    }
    go_to(plan_.loops[0][0]);
    loop(0, +1);
    return waypoints_;
  }

 private:
  void add(const Vec2& p) {
    if (!waypoints_.empty()) {
      const double d = (p - waypoints_.back()).norm();
      if (d < 1e-9) return;
      length_ += d;
    }
    waypoints_.push_back(p);
  }

  const FloorPlan& plan_;
  SimRandom rng_;
  RouteOptions options_;
  int current_ = 0;
  std::vector<Vec2> waypoints_;
  double length_ = 0.0;
};

/// Speed along a line of length L at distance s: accelerate from v_in, cruise
/// at v_max, brake to v_out, with acceleration a (v² = v₀² + 2·a·s); at least
/// a creep speed so that a line starting or ending at rest is still driven.
double line_speed(double s, double length, double v_in, double v_max, double v_out, double a) {
  const double v = std::min(
      {v_max, std::sqrt(v_in * v_in + 2.0 * a * s), std::sqrt(v_out * v_out + 2.0 * a * std::max(0.0, length - s))});
  return std::max(v, 0.03);
}

class Driver {
 public:
  Driver(const RouteOptions& o, Route& route) : o_(o), route_(route) {}

  void start(const Vec2& p, double heading) {
    pose_ = {p.x(), p.y(), heading};
    route_.samples.push_back({0.0, pose_, 0.0, 0.0});
  }

  void line(const Vec2& to, double v_in, double v_max, double v_out) {
    const Vec2 from(pose_[0], pose_[1]);
    const double length = (to - from).norm();
    if (length < 1e-9) return;
    const Vec2 dir = (to - from) / length;
    const double heading = std::atan2(dir.y(), dir.x());
    double s = 0.0;
    while (s < length) {
      const double v = line_speed(s, length, v_in, v_max, v_out, o_.accel);
      const double s_next = std::min(length, s + v * o_.dt);
      const Vec2 p = from + s_next * dir;
      emit({p.x(), p.y(), heading}, (s_next - s) / o_.dt, 0.0);
      s = s_next;
    }
  }

  /// Arc of radius r turning by `sweep` (signed, rad) at constant speed.
  void arc(double r, double sweep) {
    const double sign = sweep > 0 ? 1.0 : -1.0;
    // Centre: r to the left (sweep > 0) or right of the current heading.
    const Vec2 centre(pose_[0] - sign * r * std::sin(pose_[2]), pose_[1] + sign * r * std::cos(pose_[2]));
    const double phi0 = std::atan2(pose_[1] - centre.y(), pose_[0] - centre.x());
    const double heading0 = pose_[2];
    const double rate = o_.arc_speed / r;  // rad/s
    double done = 0.0;
    while (done < std::abs(sweep)) {
      const double next = std::min(std::abs(sweep), done + rate * o_.dt);
      const double phi = phi0 + sign * next;
      emit({centre.x() + r * std::cos(phi), centre.y() + r * std::sin(phi), heading0 + sign * next},
           r * (next - done) / o_.dt, sign * (next - done) / o_.dt);
      done = next;
    }
  }

  /// Turn in place by `angle` (signed, rad), trapezoidal angular speed.
  void rotate(double angle) {
    const double total = std::abs(angle), sign = angle > 0 ? 1.0 : -1.0;
    const double heading0 = pose_[2];
    double done = 0.0;
    while (done < total) {
      const double w = line_speed(done, total, 0.0, o_.turn_rate, 0.0, o_.turn_accel);
      const double next = std::min(total, done + w * o_.dt);
      emit({pose_[0], pose_[1], heading0 + sign * next}, 0.0, sign * (next - done) / o_.dt);
      done = next;
    }
  }

  double heading() const { return pose_[2]; }

 private:
  void emit(const Pose2& p, double v, double w) {
    const double step = std::hypot(p[0] - pose_[0], p[1] - pose_[1]);
    route_.length += step;
    pose_ = p;
    Pose2 wrapped = p;
    wrapped[2] = std::remainder(p[2], 2.0 * kPi);
    route_.samples.push_back({route_.samples.back().t + o_.dt, wrapped, v, w});
  }

  const RouteOptions& o_;
  Route& route_;
  Pose2 pose_ = Pose2::Zero();
};

void check(bool ok, const std::string& what) {
  if (!ok) throw std::invalid_argument("route: " + what);
}

}  // namespace

Pose2 relative2(const Pose2& a, const Pose2& b) { return to2(relative(to6(a), to6(b))); }
Pose2 compose2(const Pose2& a, const Pose2& d) { return to2(compound(to6(a), to6(d))); }

std::vector<Vec2> plan_waypoints(const FloorPlan& plan, std::uint64_t seed, const RouteOptions& options) {
  if (plan.loops.empty()) throw std::invalid_argument("floor plan '" + plan.name + "' has no loop to drive");
  return WaypointPlanner(plan, seed, options).run();
}

Route drive(const std::vector<Vec2>& waypoints, std::uint64_t seed, const RouteOptions& o) {
  check(waypoints.size() >= 2, "at least two waypoints are needed");
  check(o.min_speed > 0.0 && o.min_speed <= o.max_speed, "need 0 < min_speed <= max_speed");
  check(o.accel > 0.0 && o.turn_rate > 0.0 && o.turn_accel > 0.0, "accelerations and turn rate must be > 0");
  check(o.arc_radius > 0.0 && o.arc_speed > 0.0, "arc radius and speed must be > 0");
  check(o.dt > 0.0 && o.dt <= 0.1, "dt must be in (0, 0.1] s");
  SimRandom rng(seed, 0x21u);
  Route route;
  route.waypoints = waypoints;
  const std::size_t n = waypoints.size();
  std::vector<Vec2> dir(n - 1);
  std::vector<double> len(n - 1);
  for (std::size_t k = 0; k + 1 < n; ++k) {
    len[k] = (waypoints[k + 1] - waypoints[k]).norm();
    dir[k] = (waypoints[k + 1] - waypoints[k]) / len[k];
  }
  // Corner k (at waypoint k, 1 ≤ k ≤ n−2): turn angle, and how it is driven.
  enum class Corner { Straight, Arc, InPlace };
  std::vector<Corner> kind(n, Corner::InPlace);
  std::vector<double> turn(n, 0.0), cut(n, 0.0);
  for (std::size_t k = 1; k + 1 < n; ++k) {
    const Vec2& a = dir[k - 1];
    const Vec2& b = dir[k];
    turn[k] = std::atan2(a.x() * b.y() - a.y() * b.x(), a.dot(b));
    // An arc of radius r tangent to both legs starts r·tan(|α|/2) before the corner.
    const double c = o.arc_radius * std::tan(std::abs(turn[k]) / 2.0);
    if (std::abs(turn[k]) < 1e-6) {
      kind[k] = Corner::Straight;
    } else if (std::abs(turn[k]) <= 100.0 * kPi / 180.0 && c <= 0.45 * std::min(len[k - 1], len[k])) {
      kind[k] = Corner::Arc;
      cut[k] = c;
    }
  }
  std::vector<double> cruise(n - 1);
  for (double& v : cruise) v = rng.uniform(o.min_speed, o.max_speed);
  auto corner_speed = [&](std::size_t k) {  // speed when passing corner k
    if (k == 0 || k + 1 >= n) return 0.0;
    if (kind[k] == Corner::Arc) return std::min(o.arc_speed, std::min(cruise[k - 1], cruise[k]));
    if (kind[k] == Corner::Straight) return std::min(cruise[k - 1], cruise[k]);
    return 0.0;
  };
  Driver driver(o, route);
  driver.start(waypoints[0], std::atan2(dir[0].y(), dir[0].x()));
  for (std::size_t k = 0; k + 1 < n; ++k) {
    const Vec2 end = waypoints[k + 1] - cut[k + 1] * dir[k];
    driver.line(end, corner_speed(k), cruise[k], corner_speed(k + 1));
    const std::size_t c = k + 1;
    if (c + 1 >= n) break;
    if (kind[c] == Corner::Arc) {
      driver.arc(o.arc_radius, turn[c]);
    } else if (kind[c] == Corner::InPlace) {
      driver.rotate(turn[c]);
    }
  }
  return route;
}

std::vector<Pose2> wheel_odometry(const std::vector<RouteSample>& samples, const OdometryErrors& e,
                                  std::uint64_t seed) {
  SimRandom rng(seed, 0x22u);
  std::vector<Pose2> out(samples.size(), Pose2::Zero());
  const double bias = e.heading_bias_deg_per_m * kPi / 180.0;
  const double sigma_theta = e.heading_noise_deg * kPi / 180.0;
  for (std::size_t k = 1; k < samples.size(); ++k) {
    const Pose2 inc = relative2(samples[k - 1].pose, samples[k].pose);
    const double d = std::hypot(inc[0], inc[1]);
    const double sd = std::sqrt(d);
    Pose2 odo;
    odo[0] = (1.0 + e.scale_error) * inc[0] + e.xy_noise * sd * rng.normal();
    odo[1] = (1.0 + e.scale_error) * inc[1] + e.xy_noise * sd * rng.normal();
    odo[2] = (1.0 + e.turn_scale_error) * inc[2] + bias * d + sigma_theta * sd * rng.normal() +
             e.turn_noise * std::sqrt(std::abs(inc[2])) * rng.normal();
    out[k] = compose2(out[k - 1], odo);
  }
  return out;
}

}  // namespace mspace::sim_building
