// building_log.hpp — a whole simulated data set: floor plan, route, wheel
// odometry, laser scans and reference relations, and the files that hold it.
//
// simulate() computes everything in memory (deterministic for the settings);
// write_data_set() writes it to a folder:
//   building.clf        CARMEN log: PARAM lines, ODOM (wheel odometry, every
//                       odom_interval s) and one ROBOTLASER1 or FLASER line
//                       per scan (robot pose = the wheel odometry)
//   ground_truth.tum    true robot pose at every ODOM and scan time, TUM
//                       `t x y z qx qy qz qw` (robot frame, plan coordinates)
//   odometry.tum        the wheel odometry at the scan times (same format)
//   building.relations  Kümmerle et al. relations `t1 t2 x y z roll pitch yaw`
//                       (m, rad; the true pose at t2 seen from the pose at t1)
//                       between scans 1–4 s apart along the whole route and
//                       between scans ≥ 60 s apart taken at the same place
//                       (≤ 1.5 m, ≤ 45°): the loop closures
//   floor_plan.yaml     corridor graph and loops, rooms, walls, clutter, people,
//                       and `segments`: every static segment [x1, y1, x2, y2]
//   floor_plan.png      the plan with the route
//   README.txt          what was generated, with every parameter
#pragma once

#include <cstddef>
#include <cstdint>
#include <filesystem>
#include <string>
#include <vector>

#include "floor_plan.hpp"
#include "laser.hpp"
#include "route.hpp"

namespace mspace::sim_building {

struct GeneratorSettings {
  std::string plan = "ring";  ///< family name or index
  std::uint64_t world_seed = 1;
  std::uint64_t seed = 1;  ///< route, odometry and laser noise
  PlanOptions plan_options;
  RouteOptions route;
  OdometryErrors odometry;
  LaserSpec laser = laser_preset("sick181");
  double t0 = 1000.0;              ///< time stamp of the start (s)
  double long_relation_dt = 60.0;  ///< s: relations at least this far apart in time are "long"
  std::string command_line;        ///< for README.txt
};

struct ScanRecord {
  std::size_t sample = 0;      ///< index into route.samples
  long index = 0;              ///< scan number (selects the interleave offset)
  std::vector<double> ranges;  ///< as written (no-return and error codes included)
};

struct RelationRecord {
  double t1 = 0.0, t2 = 0.0;
  Pose2 delta = Pose2::Zero();  ///< true pose at t2 in the frame of the true pose at t1
};

struct Simulation {
  GeneratorSettings settings;
  FloorPlan plan;
  Route route;
  std::vector<Pose2> odometry;            ///< wheel odometry at every sample
  std::vector<std::size_t> odom_samples;  ///< samples with an ODOM line
  std::vector<ScanRecord> scans;
  std::vector<RelationRecord> relations;
  std::size_t short_relations = 0, long_relations = 0;
  std::size_t gaps = 0;  ///< logging gaps drawn

  double time(std::size_t sample) const { return settings.t0 + route.samples[sample].t; }
};

/// Everything for the settings (std::invalid_argument for bad settings).
Simulation simulate(const GeneratorSettings& settings);

/// Writes the files listed above into dir (created if needed); throws
/// std::runtime_error naming the file that cannot be written.
void write_data_set(const Simulation& sim, const std::filesystem::path& dir);

}  // namespace mspace::sim_building
