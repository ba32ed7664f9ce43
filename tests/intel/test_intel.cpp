// Walls from a 2-D laser through the kernel (T-RO §IV-F, §VI).
//  - LaserRoom: a simulated floor of walls with known truth; the filter must
//    be consistent (robot NEES) and accurate.
//  - Intel: config/intel_walls.yaml on the Intel Research Lab data, scored
//    with the relations metric of Kümmerle et al. 2009 on the 90 relations
//    that fall on the 910 scans.
#include <gtest/gtest.h>

#include <algorithm>
#include <cstdlib>
#include <filesystem>
#include <iostream>
#include <string>

#include "build_path.hpp"
#include "chi2.hpp"
#include "config.hpp"
#include "laser_sim.hpp"
#include "logging.hpp"
#include "plugin_registry.hpp"
#include "relations.hpp"
#include "runner.hpp"
#include "slam.hpp"

namespace {

using namespace mspace;
using namespace mspace::kernel;

const std::filesystem::path kSource = MSPACE_SOURCE_DIR;
const std::filesystem::path kIntelDir = kSource.parent_path() / "shared" / "datasets" / "intel_lab";

class WallRun : public ::testing::Test {
 protected:
  void SetUp() override {
    registry_.add_search_dir(MSPACE_PLUGIN_DIR);
    registry_.add_search_dir(MSPACE_INTEL_FIXTURE_DIR);
    set_log_level(LogLevel::Warn);
  }

  PluginRegistry registry_;

 public:
  /// A run of the configuration `text` with the --set style `sets` over it.
  RunResult run_text(const std::string& text, const std::vector<std::string>& sets) {
    return run(parse_config(text, "laser_room.yaml", registry_, sets));
  }

  RunResult run(const RunConfig& c) {
    Slam slam(c, registry_);
    RunOptions options;
    options.progress = false;
    options.write_outputs = false;
    return run_to_end(slam, options);
  }

  /// config/intel_walls.yaml (under `estimator` if given) scored on the
  /// Intel relations: at most `target` m mean translation error.
  void expect_intel_relations(const std::string& estimator, double target);
};

/// The laser_room simulation with the wall and laser_lines settings of
/// config/intel_walls.yaml; the motion model's noise is the simulated one.
std::string room_config(int seed, double join_distance = 0.0) {
  return R"(
run: {name: laser_room}
source:
  plugin: laser_room
  seed: )" + std::to_string(seed) + R"(
  laps: 2
  step: 0.3
  range_sigma: 0.01
  xy_noise_per_m: 0.05
  xy_noise_floor: 0.005
  theta_noise_per_rad: 0.05
  theta_noise_per_m: 2.0
  theta_noise_floor: 0.2
motion:
  plugin: odometry2d
  xy_noise_per_m: 0.05
  xy_noise_floor: 0.005
  theta_noise_per_rad: 0.05
  theta_noise_per_m: 2.0
  theta_noise_floor: 0.2
estimator: {plugin: ekf}
features:
  wall:
    plugin: wall
    min_observations: 3
    min_points: 30
    min_length: 1.0
    max_normal_std: 0.05
    min_end_observations: 3
    max_end_spread: 0.1
    max_path_distance: 15
    max_observations: 40
    match_margin: 0.5
sensors:
  laser:
    channel: laser
    mount: [0, 0, 0, 0, 0, 0]
    extractor:
      plugin: laser_lines
      range_sigma: 0.01
      max_range: 20
      split_distance: 0.06
      min_points: 10
      min_length: 0.6
      max_rms: 0.03
      depth_jump: 0.2
    feeds: [wall]
association:
  gate_probability: 0.99
  new_feature_probability: 0.9999
  tentative_max_age: 10
  join_distance: )" + std::to_string(join_distance) + R"(
)";
}

// Measured (3 seeds, 2 laps of a 14 m × 10 m floor, 1 cm range noise):
// ATE 0.013 / 0.021 / 0.025 m, mean robot NEES 9.1 / 5.0 / 5.4 (3 dof)
// (11.3 / 5.0 / 5.4 before real ends were unbiased in laser_lines).
// Open: with walls held at dim 2 only, the heading σ still falls from 1.09°
// (step 3, when the first walls enter, all relative to that pose) to 0.41°
// while the error stays ≈ 1.2°: information the model cannot have, so a
// structural cause, not a noise value.
// Before the wall's rotation was anchored (wall_B), sliding ends changed
// what the covariance meant and the NEES was 34 / 112 / 34 with the heading
// σ collapsing to 0.04° while the error was 0.3°. A consistent filter would
// give ≈ 3; the remaining factor 2–4 is still open, so this is a regression
// bound (NEES < 20), not a proof of consistency. ATE bound: 5 cm, about 2×
// the worst seed, far below what dead reckoning gives (metres).
TEST_F(WallRun, SimulatedFloorIsAccurateAndNotGrosslyOverconfident) {
  for (int seed = 1; seed <= 3; ++seed) {
    const RunResult r = run(parse_config(room_config(seed), "laser_room.yaml", registry_));
    ASSERT_TRUE(r.summary.errors.has_value());
    std::cout << "seed " << seed << ": ATE " << r.summary.errors->ate_rmse << " m, final "
              << r.summary.errors->final_translation << " m, mean NEES " << r.summary.mean_nees << " ("
              << r.summary.nees_dof << " dof); walls by dim:";
    for (const auto& [dim, n] : r.summary.features_by_dim.at("wall")) std::cout << " " << dim << ":" << n;
    std::cout << "\n";
    EXPECT_LT(r.summary.errors->ate_rmse, 0.05) << "seed " << seed;
    EXPECT_LT(r.summary.mean_nees, 20.0) << "seed " << seed;
  }
}

// Shared corners (T-RO §VI, eq. 33) in the same floor: walls whose end
// points come within 0.3 m and that cross at 30° or more share the corner.
// Every shared coordinate must stay identical in all its walls, and the run
// must stay as accurate as without sharing. Measured (seeds 1–3): 12 corners
// each, ATE 0.014 / 0.018 / 0.016 m; mean NEES 19 / 72 / 29 with the plain
// ekf — the linearisation inconsistency of tests/wall_consistency, which the
// observability-constrained prototype removes there (20 seeds: 3.4).
TEST_F(WallRun, SimulatedFloorWithSharedCorners) {
  for (int seed = 1; seed <= 3; ++seed) {
    Slam slam(parse_config(room_config(seed, 0.3), "laser_room.yaml", registry_), registry_);
    RunOptions options;
    options.progress = false;
    options.write_outputs = false;
    const RunResult r = run_to_end(slam, options);
    ASSERT_TRUE(r.summary.errors.has_value());
    std::cout << "seed " << seed << " with corners: " << slam.shared_coordinates().size() << " corners, ATE "
              << r.summary.errors->ate_rmse << " m, mean NEES " << r.summary.mean_nees << "\n";
    EXPECT_GE(slam.shared_coordinates().size(), 4u) << "seed " << seed;
    EXPECT_LT(r.summary.errors->ate_rmse, 0.05) << "seed " << seed;
    for (const SharedCoordinate& c : slam.shared_coordinates()) {
      const Eigen::VectorXd value = slam.shared_value(c);
      for (const auto& [id, block] : c.members)
        for (const MapFeature& f : slam.features()) {
          if (f.id == id) {
            EXPECT_EQ(f.feature->coords().segment<2>(2 * block), value) << "corner " << c.id;
          }
        }
    }
  }
}

/// Mean robot NEES (3 dof) over seeds 1–`seeds` of the floor with shared
/// corners under the smoother with `sets`, and the 95 % band of an average of
/// that many χ²(3) samples.
struct FloorNees {
  double mean = 0.0, lo = 0.0, hi = 0.0;
};
FloorNees smoother_nees_on_the_floor(WallRun& run, const std::vector<std::string>& sets, int seeds) {
  FloorNees out;
  out.lo = chi2_quantile(0.025, 3 * seeds) / seeds;
  out.hi = chi2_quantile(0.975, 3 * seeds) / seeds;
  for (int seed = 1; seed <= seeds; ++seed) {
    const RunResult r = run.run_text(room_config(seed, 0.3), sets);
    EXPECT_TRUE(r.summary.errors.has_value());
    if (!r.summary.errors) continue;
    std::cout << "seed " << seed << ": ATE " << r.summary.errors->ate_rmse << " m, mean NEES " << r.summary.mean_nees
              << "\n";
    EXPECT_LT(r.summary.errors->ate_rmse, 0.05) << "seed " << seed;
    out.mean += r.summary.mean_nees / seeds;
  }
  std::cout << "mean robot NEES over " << seeds << " seeds " << out.mean << " (95 % band [" << out.lo << ", "
            << out.hi << "])\n";
  return out;
}

// The smoother's own marginals on the same floor with shared corners:
// optimising at every step (period 1), so that the covariance the run gates
// with and the NEES is computed from is always the optimised one, never the
// running filter's. With the frozen factors kept in their sensor's frame
// (problem.freeze_in_sensor_frame) the robot NEES of 3 dof, averaged over
// seeds 1–10, lies in the 95 % band of an average of 10 χ²(3) samples.
// Measured 2026-12-08 (10 seeds; mean over each run's steps, then over the
// seeds): 3.48 (without corners 3.52). With the default world-frame freezing
// the same runs give 33.8 (69.0 without corners): a factor frozen when its
// wall extends keeps its world-frame Jacobian, which a rigid turn of pose and
// wall no longer leaves unchanged, so it informs the global rotation that
// nothing observes (problem.hpp); walls that never extend give 4.9.
TEST_F(WallRun, SmootherMarginalsOnTheFloorAreConsistentWithFactorsFrozenInTheSensorFrame) {
  const FloorNees n = smoother_nees_on_the_floor(
      *this, {"estimator={plugin: smoother, running_filter: ekf, period: 1, growth: 0}", "problem.freeze_in_sensor_frame=true"},
      10);
  EXPECT_GE(n.mean, n.lo);
  EXPECT_LE(n.mean, n.hi);
}

// The same consistency at the smoother's default schedule (an optimisation
// every max(100, N/2) nodes): the running filter between optimisations
// observability-constrained, its unobservable directions taken at the
// optimised values after each optimisation (Slam::refresh_unobservable).
// Measured 2026-12-08 (10 seeds): 3.49; without the constraint 9.08; with it
// but the directions carried from the first estimates through the
// optimisations (before refresh_unobservable) 474.
TEST_F(WallRun, SmootherOnTheFloorIsConsistentWithTheConstrainedRunningFilter) {
  const FloorNees n = smoother_nees_on_the_floor(
      *this,
      {"estimator={plugin: smoother, running_filter: ekf, observability_constrained: true}",
       "problem.freeze_in_sensor_frame=true"},
      10);
  EXPECT_GE(n.mean, n.lo);
  EXPECT_LE(n.mean, n.hi);
}

// config/intel_walls.yaml as `mspace run` runs it, scored on the 90
// relations that fall on the 910 scans (max_dt 1e-4 s; raw odometry scores
// 3.31 m there, GMapping 0.036 m). Measured with laser odometry, the motion
// noise set from its measured errors, shared corners and joint
// compatibility: the smoother 0.018 ± 0.022 m, 0.29° (issue 10's target:
// at most 0.05 m); the ekf on the same file 0.077 ± 0.143 m (the first
// issue's target: at most 0.10 m).
TEST_F(WallRun, IntelLabRelationsWithinTarget) { expect_intel_relations("", 0.05); }
TEST_F(WallRun, IntelLabRelationsWithinTargetUnderTheEkf) { expect_intel_relations("ekf", 0.10); }

void WallRun::expect_intel_relations(const std::string& estimator, double target) {
  if (!std::filesystem::is_regular_file(kIntelDir / "intel_910_scans.txt") ||
      !std::filesystem::is_regular_file(kIntelDir / "intel.relations"))
    GTEST_SKIP() << "Intel Research Lab data not found in " << kIntelDir << " (see config/intel_walls.yaml)";
  const std::string data = (kSource.parent_path() / "shared" / "datasets").string();
  setenv("MSPACE_DATA", data.c_str(), /*overwrite=*/0);
  RunConfig c = load_config(kSource / "config" / "intel_walls.yaml", registry_);
  if (!estimator.empty()) override_estimator(c, estimator, registry_);
  c.evaluation.relations = (kIntelDir / "intel.relations").string();
  c.evaluation.relations_max_dt = 1e-4;
  Slam slam(c, registry_);
  while (slam.step()) {
  }
  const RelationErrors e =
      evaluate_relations(slam.trajectory(), read_relations(kIntelDir / "intel.relations"), 1e-4);
  std::cout << "Intel (" << c.estimator.plugin << "): " << e.matched << " relations, translation " << e.translation.mean << " ± "
            << e.translation.std << " m (squared " << e.translation_sq.mean << " m²), rotation " << e.rotation_deg.mean
            << " ± " << e.rotation_deg.std << " deg (squared " << e.rotation_sq_deg.mean << " deg²)\n";
  EXPECT_EQ(e.matched, 90u);
  EXPECT_LE(e.translation.mean, target) << c.estimator.plugin;
}

// Issue 18: a log that records its laser 0.22 m ahead of the robot (the
// ROBOTLASER1 laser poses) refuses a configuration whose sensor mount says
// otherwise, naming the log's file and line; with the recorded mount the run
// goes through on laser odometry for the robot.
TEST_F(WallRun, RecordedLaserOffsetMustMatchTheSensorMount) {
  const std::filesystem::path file = std::filesystem::temp_directory_path() / "mspace_issue18_kernel.clf";
  test_laser::robotlaser_log::Options o;
  o.scans = 40;
  test_laser::robotlaser_log::write(file, o);
  auto config = [&](const std::string& mount) {
    return "run: {name: issue18}\nsource: {plugin: carmen_log, file: " + file.string() +
           ", odometry: scan_matched}\nmotion: {plugin: odometry2d}\nestimator: {plugin: ekf}\n"
           "features: {wall: {plugin: wall}}\nsensors:\n  laser:\n    channel: laser\n    mount: [" +
           mount + ", 0, 0, 0, 0, 0]\n    extractor: {plugin: laser_lines}\n    feeds: [wall]\n";
  };
  try {
    run(parse_config(config("0"), "issue18.yaml", registry_));
    FAIL() << "expected the configured mount to be refused";
  } catch (const std::exception& e) {
    EXPECT_NE(std::string(e.what()).find("mspace_issue18_kernel.clf:4"), std::string::npos) << e.what();
  }
  const RunResult r = run(parse_config(config("0.22"), "issue18.yaml", registry_));
  EXPECT_EQ(r.summary.steps, 40);
}

}  // namespace
