// line_truth.cpp — see line_truth.hpp.
#include "line_truth.hpp"

#include <algorithm>
#include <cmath>
#include <limits>
#include <numbers>
#include <optional>
#include <stdexcept>
#include <vector>

#include <yaml-cpp/yaml.h>

#include "ray_caster.hpp"
#include "route.hpp"

namespace mspace::sim_building {
namespace {

constexpr double kPi = std::numbers::pi;
constexpr double kInf = std::numeric_limits<double>::infinity();

/// A static segment as a line: origin, unit direction, length.
struct WallLine {
  Vec2 a, d;
  double length = 0.0;
  double along(const Vec2& p) const { return d.dot(p - a); }
  double across(const Vec2& p) const { return std::abs(d.x() * (p.y() - a.y()) - d.y() * (p.x() - a.x())); }
};

/// What the noise-free beam meets: the static segment's index (−1: a pillar,
/// a person or nothing within max_range) and the range.
struct Hit {
  int wall = -1;
  double range = kInf;
};

Hit first_hit(const std::vector<Segment>& walls, const std::vector<Disc>& occluders, const Vec2& o, double angle,
              double max_range) {
  const Vec2 d(std::cos(angle), std::sin(angle));
  Hit h;
  for (std::size_t j = 0; j < walls.size(); ++j) {
    const double s = ray_segment(o, d, walls[j]);
    if (s < h.range) h = {static_cast<int>(j), s};
  }
  for (const Disc& disc : occluders)
    if (const double s = ray_disc(o, d, disc); s < h.range) h = {-1, s};
  if (!(h.range <= max_range)) h.wall = -1;
  return h;
}

/// A visible piece of static segment `wall`: its extent along the wall.
struct Piece {
  int wall = -1;
  double from = 0.0, to = 0.0;
};

/// An extracted segment in the plan: its ends, the wall it lies on (−1: none)
/// and the ends' extents along that wall.
struct Placed {
  Vec2 a, b;
  int wall = -1;
  double along_a = 0.0, along_b = 0.0;
  bool real_a = false, real_b = false;
};

}  // namespace

LineScore& LineScore::operator+=(const LineScore& o) {
  scans += o.scans;
  extracted += o.extracted;
  right += o.right;
  visible += o.visible;
  found += o.found;
  real_ends += o.real_ends;
  right_real_ends += o.right_real_ends;
  offered_ends += o.offered_ends;
  found_ends += o.found_ends;
  return *this;
}

LineScore score_lines(const Simulation& sim, const laser_lines::LineConfig& configured, std::size_t stride,
                      bool sigma_from_data) {
  laser_lines::LineConfig c = configured;
  laser_lines::RangeNoiseTracker noise;
  const LaserSpec& l = sim.settings.laser;
  const std::vector<Segment> walls = sim.plan.static_segments();
  std::vector<WallLine> lines;
  for (const Segment& w : walls) {
    const Vec2 d = w.b - w.a;
    lines.push_back({w.a, d.normalized(), d.norm()});
  }
  LineScore score;
  Eigen::VectorXd ranges(l.beams), bearings(l.beams);
  for (std::size_t k = 0; k < sim.scans.size(); k += std::max<std::size_t>(1, stride)) {
    const ScanRecord& scan = sim.scans[k];
    const RouteSample& sample = sim.route.samples[scan.sample];
    const Pose2 laser = compose2(sample.pose, Pose2(l.mount_x, l.mount_y, l.mount_theta_deg * kPi / 180.0));
    const Vec2 origin = laser.head<2>();
    for (int i = 0; i < l.beams; ++i) {
      // As carmen_log reads the log: the no-return value and the error codes
      // just below it (no_return − 0.01 … 0.03) become 0, no return.
      const double r = scan.ranges[static_cast<std::size_t>(i)];
      ranges[i] = r >= l.no_return - 0.035 ? 0.0 : r;
      bearings[i] = l.bearing(i, scan.index);
    }
    ++score.scans;

    // Visible pieces: runs of beams on one wall (noise-free rays).
    std::vector<Disc> occluders = sim.plan.pillars;
    for (const Person& p : sim.plan.people) occluders.push_back(p.at(sample.t));
    std::vector<Piece> pieces;
    int run_wall = -1, run_beams = 0;
    double run_from = 0.0, run_to = 0.0;
    const auto close_run = [&] {
      if (run_wall >= 0 && run_beams >= c.min_points && std::abs(run_to - run_from) >= c.min_length)
        pieces.push_back({run_wall, std::min(run_from, run_to), std::max(run_from, run_to)});
      run_wall = -1;
      run_beams = 0;
    };
    for (int i = 0; i < l.beams; ++i) {
      const double angle = laser[2] + bearings[i];
      const Hit h = first_hit(walls, occluders, origin, angle, c.max_range);
      if (h.wall != run_wall) close_run();
      if (h.wall < 0) continue;
      const double along = lines[static_cast<std::size_t>(h.wall)].along(origin + h.range * Vec2(std::cos(angle), std::sin(angle)));
      if (run_wall < 0) {
        run_wall = h.wall;
        run_from = along;
      }
      run_to = along;
      ++run_beams;
    }
    close_run();
    score.visible += pieces.size();

    // The extracted segments, placed with the true laser pose.
    if (sigma_from_data) c.breakpoint_sigma = noise.sigma(configured.range_sigma);
    const std::vector<laser_lines::Segment> segs = laser_lines::extract_segments(ranges, bearings, c);
    if (sigma_from_data) noise.add(segs, configured.max_incidence);
    std::vector<Placed> placed;
    const double cs = std::cos(laser[2]), sn = std::sin(laser[2]);
    const auto to_plan = [&](const Vec2& p) { return Vec2(origin.x() + cs * p.x() - sn * p.y(), origin.y() + sn * p.x() + cs * p.y()); };
    for (const laser_lines::Segment& s : segs) {
      const Vec2 u(std::cos(s.alpha), std::sin(s.alpha)), t(std::sin(s.alpha), -std::cos(s.alpha));
      Placed p;
      p.a = to_plan(s.rho * u + s.s_a * t);
      p.b = to_plan(s.rho * u + s.s_b * t);
      p.real_a = line_segment::is_real(s.end_a);
      p.real_b = line_segment::is_real(s.end_b);
      const Vec2 dir = (p.b - p.a).normalized();
      double best = kLineDistance;
      for (std::size_t j = 0; j < lines.size(); ++j) {
        const WallLine& w = lines[j];
        const double off = std::max(w.across(p.a), w.across(p.b));
        if (off > best || std::abs(dir.dot(w.d)) < std::cos(kLineAngle)) continue;
        const double lo = std::min(w.along(p.a), w.along(p.b)), hi = std::max(w.along(p.a), w.along(p.b));
        // On this piece of the line, not across an opening to the next piece.
        if (lo < -kEndDistance || hi > w.length + kEndDistance) continue;
        best = off;
        p.wall = static_cast<int>(j);
        p.along_a = w.along(p.a);
        p.along_b = w.along(p.b);
      }
      ++score.extracted;
      if (p.wall >= 0) ++score.right;
      const auto end_right = [&](double along) {
        const double length = p.wall >= 0 ? lines[static_cast<std::size_t>(p.wall)].length : 0.0;
        return p.wall >= 0 && (std::abs(along) <= kEndDistance || std::abs(along - length) <= kEndDistance);
      };
      if (p.real_a) {
        ++score.real_ends;
        if (end_right(p.along_a)) ++score.right_real_ends;
      }
      if (p.real_b) {
        ++score.real_ends;
        if (end_right(p.along_b)) ++score.right_real_ends;
      }
      placed.push_back(p);
    }

    // Recall, and the wall ends the found pieces offer.
    for (const Piece& piece : pieces) {
      const WallLine& w = lines[static_cast<std::size_t>(piece.wall)];
      const Placed* cover = nullptr;
      for (const Placed& p : placed) {
        if (p.wall != piece.wall) continue;
        const double lo = std::min(p.along_a, p.along_b), hi = std::max(p.along_a, p.along_b);
        const double overlap = std::min(hi, piece.to) - std::max(lo, piece.from);
        if (overlap >= 0.5 * (piece.to - piece.from)) {
          cover = &p;
          break;
        }
      }
      if (!cover) continue;
      ++score.found;
      for (const double wall_end : {0.0, w.length}) {
        const double piece_end = std::abs(piece.from - wall_end) < std::abs(piece.to - wall_end) ? piece.from : piece.to;
        if (std::abs(piece_end - wall_end) > kEndDistance) continue;  // the view stops before the wall does
        ++score.offered_ends;
        const bool a_nearer = std::abs(cover->along_a - wall_end) < std::abs(cover->along_b - wall_end);
        const bool real = a_nearer ? cover->real_a : cover->real_b;
        const double along = a_nearer ? cover->along_a : cover->along_b;
        if (real && std::abs(along - wall_end) <= kEndDistance) ++score.found_ends;
      }
    }
  }
  return score;
}

laser_lines::LineConfig intel_walls_line_config() {
  const std::string file = std::string(MSPACE_SOURCE_DIR) + "/config/intel_walls.yaml";
  const YAML::Node e = YAML::LoadFile(file)["sensors"]["laser"]["extractor"];
  if (!e) throw std::runtime_error(file + ": no sensors.laser.extractor");
  laser_lines::LineConfig c;
  const auto set = [&](const char* key, double& value, double scale = 1.0) {
    if (e[key]) value = e[key].as<double>() * scale;
  };
  const double deg = kPi / 180.0;
  set("range_sigma", c.range_sigma);
  set("min_range", c.min_range);
  set("max_range", c.max_range);
  set("breakpoint_lambda_deg", c.breakpoint_lambda, deg);
  set("split_distance", c.split_distance);
  set("min_length", c.min_length);
  set("max_rms", c.max_rms);
  set("depth_jump", c.depth_jump);
  set("min_corner_angle_deg", c.min_corner_angle, deg);
  set("corner_distance", c.corner_distance);
  set("max_incidence_deg", c.max_incidence, deg);
  set("distance_sigma_floor", c.distance_sigma_floor);
  set("angle_sigma_floor_deg", c.angle_sigma_floor, deg);
  if (e["min_points"]) c.min_points = e["min_points"].as<int>();
  if (e["bridge_no_returns"]) c.bridge_no_returns = e["bridge_no_returns"].as<int>();
  return c;
}

}  // namespace mspace::sim_building
