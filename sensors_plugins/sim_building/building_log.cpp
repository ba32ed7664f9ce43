// building_log.cpp — see building_log.hpp.
#include "building_log.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <limits>
#include <numbers>
#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>
#include <sstream>
#include <stdexcept>

#include "mspace/pose.hpp"
#include "ray_caster.hpp"
#include "sim_world/sim_random.hpp"

namespace mspace::sim_building {
namespace {

using sim_world::SimRandom;
constexpr double kPi = std::numbers::pi;
constexpr double kDeg = kPi / 180.0;

/// Scan times: every interval (± jitter), with occasional gaps; as sample indices.
std::vector<std::size_t> scan_samples(const Simulation& sim, SimRandom& rng, std::size_t& gaps) {
  const LaserSpec& l = sim.settings.laser;
  const double dt = sim.settings.route.dt;
  const double end = sim.route.samples.back().t;
  std::vector<std::size_t> out;
  for (double t = 0.0; t <= end + 1e-9;) {
    const auto k = static_cast<std::size_t>(std::llround(t / dt));
    if (k >= sim.route.samples.size()) break;
    if (out.empty() || k > out.back()) out.push_back(k);
    t += l.interval * (1.0 + l.interval_jitter * rng.uniform(-1.0, 1.0));
    if (rng.uniform() < l.gap_probability) {
      t += rng.uniform(l.gap_min, l.gap_max);
      ++gaps;
    }
  }
  return out;
}

std::vector<double> simulate_scan(const Simulation& sim, const RayCaster& caster, std::size_t sample, long index,
                                  SimRandom& rng) {
  const LaserSpec& l = sim.settings.laser;
  const RouteSample& s = sim.route.samples[sample];
  // The laser pose x_ms = x_mr ⊕ x_rs (T-RO eq. 17) in the plane.
  const Pose2 laser = compose2(s.pose, Pose2(l.mount_x, l.mount_y, l.mount_theta_deg * kDeg));
  std::vector<Disc> people;
  for (const Person& p : sim.plan.people) people.push_back(p.at(s.t));
  std::vector<double> ranges(static_cast<std::size_t>(l.beams));
  for (int i = 0; i < l.beams; ++i) {
    const double r = caster.cast(laser.head<2>(), laser[2] + l.bearing(i, index), l.max_range, people);
    double value = l.no_return;
    if (std::isfinite(r)) {
      value = std::max(0.0, r + l.range_sigma * rng.normal());
      if (value >= l.max_range) value = l.no_return;  // noise carried it out of range
      if (l.dropout_probability > 0.0 && rng.uniform() < l.dropout_probability) value = l.no_return;
    }
    if (l.error_code_probability > 0.0 && rng.uniform() < l.error_code_probability)
      value = l.no_return - 0.01 * static_cast<double>(1 + rng.index(3));  // a SICK error code
    ranges[static_cast<std::size_t>(i)] = value;
  }
  return ranges;
}

/// Relations (see building_log.hpp).
void make_relations(Simulation& sim, SimRandom& rng) {
  const auto& samples = sim.route.samples;
  std::vector<double> path(samples.size(), 0.0);  // distance driven up to each sample
  for (std::size_t k = 1; k < samples.size(); ++k)
    path[k] = path[k - 1] + (samples[k].pose.head<2>() - samples[k - 1].pose.head<2>()).norm();
  auto add = [&](std::size_t a, std::size_t b) {
    sim.relations.push_back({sim.time(a), sim.time(b), relative2(samples[a].pose, samples[b].pose)});
  };
  // Short: a chain of pairs 1–4 s apart over the whole route (where the robot moved).
  const auto& scans = sim.scans;
  for (std::size_t i = 0; i < scans.size();) {
    const double target = samples[scans[i].sample].t + rng.uniform(1.0, 4.0);
    std::size_t j = i + 1;
    while (j < scans.size() && samples[scans[j].sample].t < target) ++j;
    if (j >= scans.size()) break;
    const Pose2 d = relative2(samples[scans[i].sample].pose, samples[scans[j].sample].pose);
    if (std::hypot(d[0], d[1]) > 0.05 || std::abs(d[2]) > kDeg) {
      add(scans[i].sample, scans[j].sample);
      ++sim.short_relations;
    }
    i = j;
  }
  // Long: a scan ≥ long_relation_dt after an earlier one at the same place
  // (≤ 1.5 m, ≤ 45° apart, so that the two scans overlap), one per 3 m driven.
  double last = -1e18;
  for (std::size_t i = 0; i < scans.size(); ++i) {
    const RouteSample& si = samples[scans[i].sample];
    if (path[scans[i].sample] - last < 3.0) continue;
    std::size_t best = scans.size();
    double best_d = 1.5;
    for (std::size_t j = 0; j < i; ++j) {
      const RouteSample& sj = samples[scans[j].sample];
      if (si.t - sj.t < sim.settings.long_relation_dt) {
        break;  // scans are in time order: all later ones are closer in time
      }
      const double d = (si.pose.head<2>() - sj.pose.head<2>()).norm();
      if (d <= best_d && std::abs(std::remainder(si.pose[2] - sj.pose[2], 2 * kPi)) <= 45.0 * kDeg) {
        best_d = d;
        best = j;
      }
    }
    if (best < scans.size()) {
      add(scans[best].sample, scans[i].sample);
      ++sim.long_relations;
      last = path[scans[i].sample];
    }
  }
}

std::ofstream open_out(const std::filesystem::path& file) {
  std::ofstream out(file);
  if (!out) throw std::runtime_error(file.string() + ": cannot write this file");
  return out;
}

void close_checked(std::ofstream& out, const std::filesystem::path& file) {
  out.close();
  if (!out) throw std::runtime_error(file.string() + ": writing failed");
}

std::string fmt(const char* format, double v) {
  char buf[64];
  std::snprintf(buf, sizeof buf, format, v);
  return buf;
}

void write_tum_line(std::ostream& out, double t, const Pose2& p) {
  const Eigen::Vector4d q = quaternion_xyzw(make_pose2d(p[0], p[1], p[2]));
  char buf[256];
  std::snprintf(buf, sizeof buf, "%.6f %.6f %.6f 0 %.9f %.9f %.9f %.9f\n", t, p[0], p[1], q[0], q[1], q[2], q[3]);
  out << buf;
}

void write_clf(const Simulation& sim, const std::filesystem::path& file) {
  std::ofstream out = open_out(file);
  const LaserSpec& l = sim.settings.laser;
  const double t0 = sim.settings.t0;
  out << "# CARMEN log written by mspace-sim-building: plan " << sim.plan.name << ", world seed "
      << sim.settings.world_seed << ", seed " << sim.settings.seed << ", laser " << l.preset << "\n";
  out << "# ODOM x y theta tv rv accel timestamp hostname logger_timestamp\n";
  if (l.format == "flaser")
    out << "# FLASER num_readings [range_readings] x y theta odom_x odom_y odom_theta timestamp hostname "
           "logger_timestamp\n";
  else
    out << "# ROBOTLASER1 laser_type start_angle field_of_view angular_resolution maximum_range accuracy "
           "remission_mode num_readings [range_readings] num_remissions [remission_values] laser_pose_x "
           "laser_pose_y laser_pose_theta robot_pose_x robot_pose_y robot_pose_theta laser_tv laser_rv "
           "forward_safety_dist side_safty_dist turn_axis timestamp hostname logger_timestamp\n";
  auto param = [&](const std::string& name, const std::string& value) {
    out << "PARAM " << name << " " << value << " " << fmt("%.6f", t0) << " mspace-sim " << fmt("%.6f", t0) << "\n";
  };
  param("robot_front_laser_max", fmt("%g", l.max_range));
  param("robot_frontlaser_offset", fmt("%g", l.mount_x));
  param("robot_frontlaser_side_offset", fmt("%g", l.mount_y));
  param("robot_frontlaser_angular_offset", fmt("%g", l.mount_theta_deg * kDeg));
  param("laser_front_laser_resolution", fmt("%g", l.resolution_deg));
  param("laser_front_laser_fov", fmt("%g", (l.beams - 1) * l.resolution_deg));
  param("laser_front_laser_no_return", fmt("%g", l.no_return));
  param("laser_front_laser_interleave", fmt("%g", l.interleave));

  const Pose2 mount(l.mount_x, l.mount_y, l.mount_theta_deg * kDeg);
  std::size_t next_odom = 0, next_scan = 0;
  char buf[256];
  while (next_odom < sim.odom_samples.size() || next_scan < sim.scans.size()) {
    const bool odom_first =
        next_scan >= sim.scans.size() ||
        (next_odom < sim.odom_samples.size() && sim.odom_samples[next_odom] <= sim.scans[next_scan].sample);
    if (odom_first) {
      const std::size_t k = sim.odom_samples[next_odom++];
      const Pose2& p = sim.odometry[k];
      const double t = sim.time(k);
      std::snprintf(buf, sizeof buf, "ODOM %.6f %.6f %.6f %.3f %.3f 0 %.6f mspace-sim %.6f\n", p[0], p[1], p[2],
                    sim.route.samples[k].v, sim.route.samples[k].w, t, t);
      out << buf;
      continue;
    }
    const ScanRecord& scan = sim.scans[next_scan++];
    const Pose2& odo = sim.odometry[scan.sample];
    const Pose2 laser = compose2(odo, mount);
    const double t = sim.time(scan.sample);
    if (l.format == "flaser") {
      out << "FLASER " << scan.ranges.size();
      for (double r : scan.ranges) out << fmt(" %.3f", r);
      std::snprintf(buf, sizeof buf, " %.6f %.6f %.6f %.6f %.6f %.6f %.6f mspace-sim %.6f\n", laser[0], laser[1],
                    laser[2], odo[0], odo[1], odo[2], t, t);
      out << buf;
    } else {
      const double start = l.bearing(0, scan.index);
      std::snprintf(buf, sizeof buf, "ROBOTLASER1 0 %.12f %.12f %.12f %g 0.01 0 %zu", start,
                    (l.beams - 1) * l.resolution_deg * kDeg, l.resolution_deg * kDeg, l.max_range, scan.ranges.size());
      out << buf;
      for (double r : scan.ranges) out << fmt(" %.3f", r);
      const RouteSample& s = sim.route.samples[scan.sample];
      std::snprintf(buf, sizeof buf, " 0 %.6f %.6f %.6f %.6f %.6f %.6f %.3f %.3f 0.5 0.5 0 %.6f mspace-sim %.6f\n",
                    laser[0], laser[1], laser[2], odo[0], odo[1], odo[2], s.v, s.w, t, t);
      out << buf;
    }
  }
  close_checked(out, file);
}

void write_poses(const Simulation& sim, const std::filesystem::path& file, bool truth) {
  std::ofstream out = open_out(file);
  out << "# " << (truth ? "true robot pose" : "wheel odometry") << " (robot frame), TUM: t x y z qx qy qz qw\n";
  std::vector<std::size_t> samples;
  for (const ScanRecord& s : sim.scans) samples.push_back(s.sample);
  if (truth) {
    samples.insert(samples.end(), sim.odom_samples.begin(), sim.odom_samples.end());
    std::sort(samples.begin(), samples.end());
    samples.erase(std::unique(samples.begin(), samples.end()), samples.end());
  }
  for (std::size_t k : samples) write_tum_line(out, sim.time(k), truth ? sim.route.samples[k].pose : sim.odometry[k]);
  close_checked(out, file);
}

void write_relations(const Simulation& sim, const std::filesystem::path& file) {
  std::ofstream out = open_out(file);
  char buf[256];
  for (const RelationRecord& r : sim.relations) {
    std::snprintf(buf, sizeof buf, "%.6f %.6f %.6f %.6f 0.000000 0.000000 0.000000 %.6f\n", r.t1, r.t2, r.delta[0],
                  r.delta[1], r.delta[2]);
    out << buf;
  }
  close_checked(out, file);
}

std::string point(const Vec2& p) {
  char buf[96];
  std::snprintf(buf, sizeof buf, "[%.3f, %.3f]", p.x(), p.y());
  return buf;
}
std::string rect(const Rect& r) {
  char buf[128];
  std::snprintf(buf, sizeof buf, "[%.2f, %.2f, %.2f, %.2f]", r.x0, r.y0, r.x1, r.y1);
  return buf;
}

void write_plan_yaml(const Simulation& sim, const std::filesystem::path& file) {
  const FloorPlan& p = sim.plan;
  std::ofstream out = open_out(file);
  out << "# Floor plan written by mspace-sim-building (m, rad). `segments` holds every static segment\n"
      << "# [x1, y1, x2, y2]: the walls, then the box sides; pillars are circles [x, y, r].\n";
  out << "plan: " << p.name << "\nworld_seed: " << p.world_seed << "\nsymmetric: " << (p.symmetric ? "true" : "false")
      << "\ncorridor_width: " << p.corridor_width << "\nwall_thickness: " << p.wall_thickness << "\nnodes:\n";
  for (const Vec2& n : p.nodes) out << "  - " << point(n) << "\n";
  out << "edges:\n";
  for (const auto& [a, b] : p.edges) out << "  - [" << a << ", " << b << "]\n";
  out << "loops:\n";
  for (std::size_t i = 0; i < p.loops.size(); ++i) {
    out << "  - {nodes: [";
    for (std::size_t k = 0; k < p.loops[i].size(); ++k) out << (k ? ", " : "") << p.loops[i][k];
    out << "], length_m: " << fmt("%.2f", p.loop_length(i)) << "}\n";
  }
  out << "rooms:\n";
  for (const Room& r : p.rooms)
    out << "  - {area: " << rect(r.area) << ", door: " << rect(r.door) << ", edge: " << r.edge << "}\n";
  out << "pillars:\n";
  for (const Disc& d : p.pillars)
    out << "  - [" << fmt("%.3f", d.centre.x()) << ", " << fmt("%.3f", d.centre.y()) << ", " << fmt("%.3f", d.radius)
        << "]\n";
  out << "people:\n";
  for (const Person& m : p.people)
    out << "  - {from: " << point(m.a) << ", to: " << point(m.b) << ", speed: " << fmt("%.3f", m.speed)
        << ", radius: " << fmt("%.3f", m.radius) << ", phase_s: " << fmt("%.3f", m.phase) << "}\n";
  out << "wall_count: " << p.walls.size() << "\nsegments:\n";
  for (const Segment& s : p.static_segments())
    out << "  - [" << fmt("%.3f", s.a.x()) << ", " << fmt("%.3f", s.a.y()) << ", " << fmt("%.3f", s.b.x()) << ", "
        << fmt("%.3f", s.b.y()) << "]\n";
  close_checked(out, file);
}

void write_png(const Simulation& sim, const std::filesystem::path& file) {
  const Rect b = sim.plan.bounds();
  const double margin = 1.0, size = 1200.0;
  const double scale = size / std::max(b.x1 - b.x0 + 2 * margin, b.y1 - b.y0 + 2 * margin);
  const int w = static_cast<int>(std::ceil((b.x1 - b.x0 + 2 * margin) * scale));
  const int h = static_cast<int>(std::ceil((b.y1 - b.y0 + 2 * margin) * scale));
  cv::Mat img(h, w, CV_8UC3, cv::Scalar(255, 255, 255));
  auto px = [&](const Vec2& p) {  // y up in the picture
    return cv::Point(static_cast<int>(std::lround((p.x() - b.x0 + margin) * scale)),
                     static_cast<int>(std::lround((b.y1 + margin - p.y()) * scale)));
  };
  for (const Person& m : sim.plan.people) cv::line(img, px(m.a), px(m.b), cv::Scalar(180, 180, 255), 3);
  std::vector<cv::Point> route;
  for (std::size_t k = 0; k < sim.route.samples.size(); k += 10)
    route.push_back(px(sim.route.samples[k].pose.head<2>()));
  cv::polylines(img, route, false, cv::Scalar(230, 150, 60), 1, cv::LINE_AA);
  for (const Segment& s : sim.plan.walls) cv::line(img, px(s.a), px(s.b), cv::Scalar(0, 0, 0), 2);
  for (const Box& box : sim.plan.boxes)
    for (const Segment& s : box.sides()) cv::line(img, px(s.a), px(s.b), cv::Scalar(90, 90, 90), 1, cv::LINE_AA);
  for (const Disc& d : sim.plan.pillars)
    cv::circle(img, px(d.centre), std::max(1, static_cast<int>(d.radius * scale)), cv::Scalar(90, 90, 90), -1);
  cv::circle(img, px(sim.route.samples.front().pose.head<2>()), 6, cv::Scalar(0, 160, 0), -1);
  cv::putText(img,
              sim.plan.name + " world " + std::to_string(sim.settings.world_seed) + " seed " +
                  std::to_string(sim.settings.seed) + ", route " + fmt("%.0f", sim.route.length) + " m",
              cv::Point(8, 20), cv::FONT_HERSHEY_SIMPLEX, 0.55, cv::Scalar(0, 0, 0), 1, cv::LINE_AA);
  if (!cv::imwrite(file.string(), img)) throw std::runtime_error(file.string() + ": cannot write the picture");
}

void write_readme(const Simulation& sim, const std::filesystem::path& file) {
  const GeneratorSettings& s = sim.settings;
  const FloorPlan& p = sim.plan;
  std::ofstream out = open_out(file);
  const double duration = sim.route.samples.back().t;
  const Pose2 err = relative2(sim.route.samples.back().pose, sim.odometry.back());
  out << "Simulated office building for 2-D laser SLAM, written by mspace-sim-building.\n\n";
  if (!s.command_line.empty()) out << "Command: " << s.command_line << "\n\n";
  out << "Plan: " << p.name << " (world seed " << s.world_seed << (p.symmetric ? ", deliberately symmetric" : "")
      << "), corridor width " << p.corridor_width << " m, walls " << p.wall_thickness << " m thick\n";
  for (std::size_t i = 0; i < p.loops.size(); ++i)
    out << "  corridor loop " << i << ": " << fmt("%.1f", p.loop_length(i)) << " m\n";
  out << "  " << p.rooms.size() << " rooms, " << p.boxes.size() << " boxes, " << p.pillars.size() << " pillars, "
      << p.people.size() << " moving people, " << p.walls.size() << " wall segments\n\n";
  out << "Route (seed " << s.seed << "): " << fmt("%.1f", sim.route.length) << " m in " << fmt("%.1f", duration)
      << " s, " << sim.route.waypoints.size() << " waypoints; target length " << s.route.length_m
      << " m, room visit probability " << s.route.room_visit_probability << ", speed " << s.route.min_speed << "–"
      << s.route.max_speed << " m/s, arcs r " << s.route.arc_radius << " m at " << s.route.arc_speed
      << " m/s, turns in place ≤ " << s.route.turn_rate << " rad/s\n\n";
  out << "Wheel odometry: scale error " << s.odometry.scale_error << ", turn scale error "
      << s.odometry.turn_scale_error << ", heading bias " << s.odometry.heading_bias_deg_per_m << " deg/m, noise "
      << s.odometry.xy_noise << " m/sqrt(m), " << s.odometry.heading_noise_deg << " deg/sqrt(m), "
      << s.odometry.turn_noise
      << " rad/sqrt(rad)\n  error at the end of the route: " << fmt("%.2f", std::hypot(err[0], err[1])) << " m, "
      << fmt("%.1f", std::abs(err[2]) / kDeg) << " deg\n\n";
  out << "Laser:\n" << s.laser.describe() << "\n";
  out << "Log: " << sim.scans.size() << " scans, " << sim.odom_samples.size() << " ODOM lines, " << sim.gaps
      << " logging gaps, time stamps from " << fmt("%.3f", s.t0) << " s\n";
  out << "Relations: " << sim.short_relations << " between scans 1–4 s apart, " << sim.long_relations
      << " between scans >= " << s.long_relation_dt << " s apart at the same place\n\n";
  out << "Files: building.clf (CARMEN: PARAM, ODOM, " << (s.laser.format == "flaser" ? "FLASER" : "ROBOTLASER1")
      << "), ground_truth.tum, odometry.tum, building.relations, floor_plan.yaml, floor_plan.png, README.txt\n\n";
  out << "Run the wall SLAM on it:\n  MSPACE_SIM_BUILDING=<this folder> build/bin/mspace run config/sim_building.yaml\n"
      << "config/sim_building.yaml expects the laser at [" << 0.22 << ", 0, 0] (the sick181 preset); for this log set\n"
      << "  sensors.laser.mount: [" << s.laser.mount_x << ", " << s.laser.mount_y << ", 0, " << s.laser.mount_theta_deg
      << ", 0, 0]\n";
  if (s.laser.format == "flaser")
    out << "  source.flaser_fov_deg: " << s.laser.beams * s.laser.resolution_deg << " (FLASER lines carry no angles)\n";
  out << "(carmen_log reads the laser's offset and the no-return code " << s.laser.no_return
      << " from the log itself and refuses a mount that differs.)\n";
  close_checked(out, file);
}

}  // namespace

Simulation simulate(const GeneratorSettings& settings) {
  validate(settings.laser);
  if (settings.route.length_m < 0.0 || settings.route.length_m > 20000.0)
    throw std::invalid_argument("route length must be in [0, 20000] m");
  if (settings.laser.odom_interval < settings.route.dt)
    throw std::invalid_argument("odom_interval must be at least the sample time " + std::to_string(settings.route.dt));
  Simulation sim;
  sim.settings = settings;
  sim.plan = generate_plan(plan_index(settings.plan), settings.world_seed, settings.plan_options);
  sim.route = drive(plan_waypoints(sim.plan, settings.seed, settings.route), settings.seed, settings.route);
  sim.odometry = wheel_odometry(sim.route.samples, settings.odometry, settings.seed);

  const auto odom_every =
      static_cast<std::size_t>(std::max(1L, std::lround(settings.laser.odom_interval / settings.route.dt)));
  for (std::size_t k = 0; k < sim.route.samples.size(); k += odom_every) sim.odom_samples.push_back(k);

  SimRandom schedule(settings.seed, 0x31u), noise(settings.seed, 0x30u), relations(settings.seed, 0x32u);
  const RayCaster caster(sim.plan.static_segments(), sim.plan.pillars);
  long index = 0;
  for (std::size_t k : scan_samples(sim, schedule, sim.gaps)) {
    ScanRecord scan;
    scan.sample = k;
    scan.index = index++;
    scan.ranges = simulate_scan(sim, caster, k, scan.index, noise);
    sim.scans.push_back(std::move(scan));
  }
  make_relations(sim, relations);
  return sim;
}

void write_data_set(const Simulation& sim, const std::filesystem::path& dir) {
  std::error_code ec;
  std::filesystem::create_directories(dir, ec);
  if (ec || !std::filesystem::is_directory(dir))
    throw std::runtime_error(dir.string() + ": cannot create the output folder (" + ec.message() + ")");
  write_clf(sim, dir / "building.clf");
  write_poses(sim, dir / "ground_truth.tum", true);
  write_poses(sim, dir / "odometry.tum", false);
  write_relations(sim, dir / "building.relations");
  write_plan_yaml(sim, dir / "floor_plan.yaml");
  write_png(sim, dir / "floor_plan.png");
  write_readme(sim, dir / "README.txt");
}

}  // namespace mspace::sim_building
