// Loop closing by map matching (kernel/src/loop_closing.cpp,
// slam_loop_closure.cpp) through the whole kernel on generated buildings
// whose laser log has minute-long gaps (0.3 % chance per scan of 40–80 s
// without scans): the robot drives on with its drifting wheel odometry and
// comes back to mapped corridors metres off, beyond the association gate.
// The motion noise is config/sim_building.yaml's laser-odometry one, far
// smaller than the wheels' real drift — the overconfident filter of a real
// log. Every accepted closure is checked against the ground truth (the
// robot's pose relative to where it first saw the paired features, against
// the true relative pose; > 1 m or 5° is a false closure), so a false
// closure shows as plainly as a missed one.
//
// Measured when these tests were written (smoother, before the confirmation
// step): ring 1: 1 closure (8 features merged), 0 false, ATE 0.371 → 0.343 m;
// symmetric 1 (the deliberately symmetric plan): 1 closure, 0 false, 4
// refused as ambiguous, ATE 1.298 → 1.408 m. Re-measured 2026-11-25 with the
// confirmation step: symmetric 1: 0 closures, 6 refused as ambiguous, ATE
// 1.298 m either way; long_loop 2: 0 closures, 56 refused, ATE 5.242 m. Re-measured 2026-11-28 after
// the pairing, warp and anchor changes (README, "Why right closures made maps worse"): ring 1: 1
// closure, ATE 0.371 → 0.336 m; symmetric 1: 0 closures, 1.298 m; long_loop 2: 1 closure, 0 false,
// ATE 5.242 → 1.827 m; l_ring 2: 2 closures, 0 false, 1.613 → 1.610 m. The assertions are the
// property (no false closure, at least one closure where the loop exists, no
// run worse than without loop closing by more than 10 %), not those figures.
#include <gtest/gtest.h>

#include <png.h>

#include <algorithm>
#include <cmath>
#include <numbers>
#include <cstdint>
#include <cstdlib>
#include <filesystem>
#include <functional>
#include <iostream>
#include <string>
#include <tuple>
#include <utility>
#include <vector>

#include "build_path.hpp"
#include "building_log.hpp"
#include "config.hpp"
#include "logging.hpp"
#include "plugin_registry.hpp"
#include "runner.hpp"
#include "relations.hpp"
#include "slam.hpp"
#include "test_paths.hpp"

namespace {

using namespace mspace;
using namespace mspace::kernel;
namespace fs = std::filesystem;

struct Outcome {
  RunStats stats;
  double ate = 0.0;
};

fs::path building_with_gaps(const std::string& plan, std::uint64_t seed) {
  sim_building::GeneratorSettings settings;
  settings.plan = plan;
  settings.world_seed = settings.seed = seed;
  settings.laser.gap_probability = 0.003;
  settings.laser.gap_min = 40.0;
  settings.laser.gap_max = 80.0;
  const sim_building::Simulation sim = sim_building::simulate(settings);
  // Each test writes its own copy: ctest runs tests in parallel.
  const fs::path dir = test::scratch_dir("loop_closing_run", plan + "_" + std::to_string(seed) + "_gaps");
  sim_building::write_data_set(sim, dir);
  return dir;
}

Outcome run(const fs::path& dir, bool loop_closing) {
  set_log_level(LogLevel::Warn);
  setenv("MSPACE_SIM_BUILDING", dir.c_str(), 1);
  PluginRegistry registry;
  registry.add_search_dir(MSPACE_PLUGIN_DIR);
  RunConfig config = load_config(fs::path(MSPACE_SOURCE_DIR) / "config" / "sim_building.yaml", registry);
  config.source.params.set("odometry", std::string("wheel"));
  config.association.loop_closing = loop_closing;
  override_estimator(config, "smoother", registry);
  Slam slam(config, registry);
  RunOptions options;
  options.progress = false;
  options.write_outputs = false;
  const RunResult r = run_to_end(slam, options);
  Outcome out;
  out.stats = slam.stats();
  if (r.summary.errors) out.ate = r.summary.errors->ate_rmse;
  return out;
}

/// Every accepted closure must also pair only the same objects
/// (RunStats::loop_wrong_pairs, the ground truth's pairs check).
void check(const std::string& plan, std::uint64_t seed, bool loop_expected) {
  const fs::path dir = building_with_gaps(plan, seed);
  const Outcome without = run(dir, false);
  const Outcome with = run(dir, true);
  std::cout << plan << ": " << with.stats.loop_closures << " closures (" << with.stats.loop_merged
            << " features merged) in " << with.stats.loop_attempts << " searches, " << with.stats.loop_ambiguous
            << " refused as ambiguous, " << with.stats.loop_false << " of " << with.stats.loop_checked
            << " false, " << with.stats.loop_wrong_pairs << " pairing a wrong object; ATE " << without.ate
            << " m without, " << with.ate << " m with\n";
  EXPECT_EQ(with.stats.loop_false, 0);
  EXPECT_EQ(with.stats.loop_wrong_pairs, 0);
  EXPECT_EQ(with.stats.loop_checked, with.stats.loop_closures);  // every closure was checked
  if (loop_expected) {
    EXPECT_GE(with.stats.loop_closures, 1);
  }
  EXPECT_LT(with.ate, without.ate * 1.1);
}

/// A generated building (world seed = noise seed = `seed`) logged with the
/// laser preset `preset`, written to this test's own directory; and the laser.
std::pair<fs::path, sim_building::LaserSpec> logged_building(const std::string& plan, std::uint64_t seed,
                                                             const std::string& preset) {
  sim_building::GeneratorSettings settings;
  settings.plan = plan;
  settings.world_seed = settings.seed = seed;
  settings.laser = sim_building::laser_preset(preset);
  const fs::path dir = test::scratch_dir("loop_closing_run", plan + "_" + std::to_string(seed) + "_" + preset);
  sim_building::write_data_set(sim_building::simulate(settings), dir);
  return {dir, settings.laser};
}

/// config/intel_walls.yaml pointed at a generated building the way a user
/// points it at another log (as on the command line: the file, the
/// no-return range, the ground truth, the relations and the laser's mount).
RunConfig intel_walls_on(const fs::path& dir, const sim_building::LaserSpec& laser, PluginRegistry& registry) {
  return load_config(fs::path(MSPACE_SOURCE_DIR) / "config" / "intel_walls.yaml", registry,
                     {"source.file=" + (dir / "building.clf").string(), "source.no_return_range=0",
                      "source.ground_truth=" + (dir / "ground_truth.tum").string(),
                      "evaluation.relations=" + (dir / "building.relations").string(),
                      "sensors.laser.mount=[" + std::to_string(laser.mount_x) + "," + std::to_string(laser.mount_y) +
                          ",0,0,0,0]"});
}

/// Runs `config` to the end (no outputs written).
void run_quietly(Slam& slam) {
  RunOptions options;
  options.progress = false;
  options.write_outputs = false;
  run_to_end(slam, options);
}

/// The errors of `trajectory` on the building's relations between poses at least 60 s apart.
RelationErrors long_relations(const fs::path& dir, const std::vector<StampedPose>& trajectory) {
  std::vector<Relation> far;
  for (const Relation& r : read_relations(dir / "building.relations"))
    if (r.t2 - r.t1 >= 60.0) far.push_back(r);
  return evaluate_relations(trajectory, far, 1e-4);
}

/// config/intel_walls.yaml on the building in `dir`, changed by `adjust`, run
/// to the end: its statistics and its long relations.
struct WallsRun {
  RunStats stats;
  RelationErrors long_relations;
};
WallsRun run_intel_walls(const fs::path& dir, const sim_building::LaserSpec& laser,
                         const std::function<void(RunConfig&)>& adjust) {
  PluginRegistry registry;
  registry.add_search_dir(MSPACE_PLUGIN_DIR);
  RunConfig config = intel_walls_on(dir, laser, registry);
  adjust(config);
  Slam slam(config, registry);
  run_quietly(slam);
  return {slam.stats(), long_relations(dir, slam.trajectory())};
}

TEST(LoopClosingRun, RingClosesItsLoopAfterALoggingGap) { check("ring", 1, true); }

TEST(LoopClosingRun, SymmetricBuildingHasNoFalseClosure) { check("symmetric", 1, false); }

// A building the thresholds were not chosen on, where a single search once
// accepted two false closures (a 7.5 m shift along a corridor with doors at
// a regular spacing; ATE 5.2 → 20 m): a placement must now be found again by
// the next search, with local features the first did not pair.
// Its one closure (ATE 5.24 → 1.83 m) once paired nine walls right (within
// 0.03 m in the true frame) and one wrong, 4.3 m apart: a room's back wall
// with the corridor wall above it, which the old map — two passes 300 m of
// travel apart, the loop between them not closed — held exactly there. The
// pairing now keeps to one pass of the old map (MapMatchOptions::pass_gap);
// measured 2026-11-28: ten pairs within 0.03 m, ATE 1.83 m.
TEST(LoopClosingRun, LongLoopIsNotClosedByAChanceFit) { check("long_loop", 2, false); }

// A building the thresholds were not chosen on where map matching under the
// smoother does close loops after gaps, so a wrong placement has a chance to
// be taken: every closure is checked against the ground truth and one false
// closure fails the test. Measured (2026-11-25): 3 closures (26 features
// merged) in 136 searches, 2 refused as ambiguous, 0 of 3 false; ATE 1.613 m
// without, 1.730 m with — right closures that leave the smoothed map slightly
// worse (README, "The gap buildings under the smoother"), inside the 10 %.
TEST(LoopClosingRun, LRingClosesAfterGapsWithoutAFalseClosure) { check("l_ring", 2, true); }

// Range scans as evidence (association.loop_scans): config/intel_walls.yaml
// pointed at a generated building logged like the held-out ROBOTLASER1 log
// (robotlaser_logged: a scan every 0.6 s ± 50 %, 12 % of beams without a
// return, gaps of minutes). The symmetric plan, seed 6: the features alone
// close nothing (long relations 1.03 m, measured 2026-11-28); the scans
// place the local map on the old one. At least one closure, none false,
// and the long relations (≥ 60 s apart) at most half of what they are
// without the scans (0.05 m measured). One seed: the many-world figures are
// in the README ("Range scans as evidence").
TEST(LoopClosingRun, ScansCloseASparseLoopTheFeaturesCannot) {
  set_log_level(LogLevel::Warn);
  const auto [dir, laser] = logged_building("symmetric", 6, "robotlaser_logged");
  const auto run_with = [&](bool scans) {
    const auto [stats, e] = run_intel_walls(dir, laser, [&](RunConfig& config) {
      EXPECT_TRUE(config.association.loop_closing);
      config.association.loop_scans = scans;
    });
    std::cout << (scans ? "with" : "without") << " scans: " << stats.loop_closures << " closures ("
              << stats.loop_scan_placed << " placed by the scans), " << stats.loop_false
              << " false; long relations " << e.translation.mean << " m over " << e.matched << "\n";
    EXPECT_GT(e.matched, 10u);
    EXPECT_EQ(stats.loop_wrong_pairs, 0);
    return std::tuple{stats.loop_scan_placed, stats.loop_false, e.translation.mean};
  };
  const auto [placed_without, false_without, long_without] = run_with(false);
  const auto [placed_with, false_with, long_with] = run_with(true);
  EXPECT_EQ(placed_without, 0);
  EXPECT_GE(placed_with, 1);
  EXPECT_EQ(false_with, 0);
  EXPECT_LT(long_with, 0.5 * long_without);
}

// Long relations never worse than the laser odometry's own on a long loop
// with logging gaps, config/intel_walls.yaml pointed at the log as a user
// would (the sick181 preset, gaps of 40–80 s). Before two changes
// (2026-11-29) this building's map was worse than its odometry (long
// relations 3.46 m against 1.81 m): the robot kept matching walls it had
// followed since creating them 30 m back, which counted as anchors to the
// old map and held the search window at 0.2–1.5 m while the true placement
// was 3–5 m away (the debug log's ground-truth counts: ≥ 6 local features
// had an old counterpart in 69 searches that found no placement). With
// association.loop_revisit_window (on in intel_walls.yaml) only a revisit
// widens the window, and an accepted placement moves each old feature at
// most by the drift since it was last seen (MapMatchOptions::drift_per_metre),
// which keeps the wider window from laying a corridor 14 m along itself
// (long_loop 2 with gaps, where the wider window alone made one false
// closure). Measured: 3 closures, 0 false, long relations 0.64 m against
// 1.81 m.
TEST(LoopClosingRun, LongLoopWithGapsIsNoWorseThanItsOdometry) {
  const fs::path dir = building_with_gaps("long_loop", 4);  // the sick181 preset, as building_with_gaps logs it
  set_log_level(LogLevel::Warn);
  PluginRegistry registry;
  registry.add_search_dir(MSPACE_PLUGIN_DIR);
  Slam slam(intel_walls_on(dir, sim_building::GeneratorSettings{}.laser, registry), registry);
  run_quietly(slam);
  const RelationErrors mapped = long_relations(dir, slam.trajectory());
  const RelationErrors odometry = long_relations(dir, slam.dead_reckoning());
  std::cout << slam.stats().loop_closures << " closures, " << slam.stats().loop_false << " false, "
            << slam.stats().loop_wrong_pairs << " pairing a wrong object; long relations " << mapped.translation.mean
            << " m against " << odometry.translation.mean << " m for the laser odometry (" << mapped.matched
            << " relations)\n";
  EXPECT_GT(mapped.matched, 10u);
  EXPECT_GE(slam.stats().loop_closures, 1);
  EXPECT_EQ(slam.stats().loop_false, 0);
  EXPECT_EQ(slam.stats().loop_wrong_pairs, 0);
  EXPECT_LE(mapped.translation.mean, odometry.translation.mean);
}

// A robot that only crosses an old corridor pairs the same few walls at each
// search there, and a placement waiting for "new pairs" then never gets them
// (association.loop_confirm_repeats). config/intel_walls.yaml on a long loop
// logged like the ROBOTLASER1 log (robotlaser_logged, world seed 1): the
// robot crosses its old path for 3 m of travel at step 1653, 5.2 m off; map
// matching places the local map there right (0.06 m from the truth) three
// times in a row, pairing 2–3 of the same walls each time, and leaves the
// old place without a closure (measured 2026-12-06: 0 closures; long
// relations 3.31 m). With repeats confirming, the crossing closes the loop
// and no closure is false.
TEST(LoopClosingRun, ACrossingIsConfirmedByRepeatedSearches) {
  set_log_level(LogLevel::Warn);
  const auto [dir, laser] = logged_building("long_loop", 1, "robotlaser_logged");
  const auto run_with = [&](int repeats) {
    const auto [stats, e] =
        run_intel_walls(dir, laser, [&](RunConfig& config) { config.association.loop_confirm_repeats = repeats; });
    std::cout << "loop_confirm_repeats " << repeats << ": " << stats.loop_closures << " closures ("
              << stats.loop_confirmed_by_repeats << " confirmed by repeats), " << stats.loop_false << " false, "
              << stats.loop_wrong_pairs << " pairing a wrong object; long relations " << e.translation.mean
              << " m over " << e.matched << "\n";
    EXPECT_GT(e.matched, 10u);
    EXPECT_EQ(stats.loop_false, 0);
    EXPECT_EQ(stats.loop_wrong_pairs, 0);
    return std::tuple{stats.loop_closures, stats.loop_confirmed_by_repeats, e.translation.mean};
  };
  const auto [closures_without, repeats_without, long_without] = run_with(0);
  const auto [closures_with, repeats_with, long_with] = run_with(2);
  EXPECT_EQ(closures_without, 0);
  EXPECT_EQ(repeats_without, 0);  // counted only when the key is on
  EXPECT_GE(closures_with, 1);
  EXPECT_GE(repeats_with, 1);
  EXPECT_LT(long_with, long_without);
}

// After a logging gap the robot is metres and degrees from where its wheels
// say (association.relocalize_by_scans, README "Relocalizing after a logging
// gap"). config/intel_walls.yaml on long_loop, world seed 6, logged like the
// ROBOTLASER1 log: five gaps of 122–238 s, four of them ending where the
// robot had been; map matching closes no loop, and the long relations are
// 3.13 m (its laser odometry's 4.01 m; measured 2026-12-07). With the scans
// gathered after each gap placed on the older ones, four placements set the
// pose (corrections 0.1–2.7 m), each within 0.16 m and 0.8° of the truth, and
// the long relations fall to 0.22 m. The assertions: every placement checked
// and none wrong, no false closure, the long relations at most half.
TEST(LoopClosingRun, AfterALoggingGapTheScansRelocalizeTheRobot) {
  set_log_level(LogLevel::Warn);
  const auto [dir, laser] = logged_building("long_loop", 6, "robotlaser_logged");
  const auto run_with = [&](bool relocalize) {
    const auto [stats, e] =
        run_intel_walls(dir, laser, [&](RunConfig& config) { config.association.relocalize_by_scans = relocalize; });
    std::cout << (relocalize ? "with" : "without") << " relocalization: " << stats.relocalize_steps
              << " uncertain steps, " << stats.relocalized << " placed, " << stats.relocalized_along_a_line
              << " across a corridor, " << stats.relocalize_wrong << " of " << stats.relocalize_checked
              << " wrong; " << stats.loop_closures << " closures, " << stats.loop_false
              << " false; long relations " << e.translation.mean << " m over " << e.matched << "\n";
    EXPECT_GT(e.matched, 10u);
    EXPECT_EQ(stats.loop_false, 0);
    return std::tuple{stats, e.translation.mean};
  };
  const auto [without, long_without] = run_with(false);
  const auto [with, long_with] = run_with(true);
  EXPECT_EQ(without.relocalize_steps, 0);  // counted only when the key is on
  EXPECT_GE(with.relocalize_steps, 3);
  EXPECT_GE(with.relocalized + with.relocalized_along_a_line, 2);
  EXPECT_EQ(with.relocalize_checked, with.relocalized + with.relocalized_along_a_line);  // every placement checked
  EXPECT_EQ(with.relocalize_wrong, 0);
  EXPECT_LT(long_with, 0.5 * long_without);
}

// Every match of a measurement with a mapped feature is checked against the
// ground truth (Slam::check_matches_against_ground_truth): is it the object
// the feature was when last seen? Here the verdicts are checked on their own
// terms. config/intel_walls.yaml on two robotlaser_logged buildings: ring 2,
// whose map is right (long relations 0.03 m), has no wrong match in 3000;
// l_ring 7, whose map is worse than its own laser odometry, has 12 (measured
// 2026-12-07), all with walls unseen for 100-500 m of travel, and for each
// the final map confirms it: the wall's two sightings, each taken into the
// true frame through the pose that saw it, are different walls (0.7-6.2 m
// apart across; a corridor is 2 m wide).
namespace {
struct TwoSightings {
  double across = 0.0;  ///< m: the later sighting's middle from the earlier's line
  double angle = 0.0;   ///< rad
};
/// A two-point feature (a wall) of the final map taken into the true frame
/// through the final pose of step `a` and of step `b`.
TwoSightings two_sightings(const Slam& slam, const MapFeature& f, std::int64_t a, std::int64_t b) {
  const auto to_truth = [&](std::int64_t step, const Eigen::Vector2d& p) {
    const StampedPose& e = slam.trajectory().at(static_cast<std::size_t>(step - 1));  // (step k is record k - 1)
    const auto g = std::lower_bound(slam.ground_truth().begin(), slam.ground_truth().end(), e.t - 1e-9,
                                    [](const StampedPose& x, double t) { return x.t < t; });
    EXPECT_NE(g, slam.ground_truth().end());
    const double turn = g->pose[kTheta] - e.pose[kTheta];
    const Eigen::Vector2d d = p - Eigen::Vector2d(e.pose[kX], e.pose[kY]);
    return Eigen::Vector2d(std::cos(turn) * d.x() - std::sin(turn) * d.y() + g->pose[kX],
                           std::sin(turn) * d.x() + std::cos(turn) * d.y() + g->pose[kY]);
  };
  const Eigen::VectorXd x = f.feature->coords();
  const Eigen::Vector2d a1 = to_truth(a, x.head<2>()), a2 = to_truth(a, x.segment<2>(2));
  const Eigen::Vector2d b1 = to_truth(b, x.head<2>()), b2 = to_truth(b, x.segment<2>(2));
  const Eigen::Vector2d along = (a2 - a1).normalized(), normal(-along.y(), along.x());
  const Eigen::Vector2d db = b2 - b1;
  return {std::abs(normal.dot(0.5 * (b1 + b2) - a1)),
          std::abs(std::remainder(std::atan2(db.y(), db.x()) - std::atan2(along.y(), along.x()), std::numbers::pi))};
}
}  // namespace

TEST(LoopClosingRun, AWrongAssociationIsSeenAgainstTheGroundTruth) {
  set_log_level(LogLevel::Warn);
  for (const auto& [plan, seed] : {std::pair<std::string, int>{"ring", 2}, {"l_ring", 7}}) {
    const auto [dir, laser] = logged_building(plan, static_cast<std::uint64_t>(seed), "robotlaser_logged");
    PluginRegistry registry;
    registry.add_search_dir(MSPACE_PLUGIN_DIR);
    Slam slam(intel_walls_on(dir, laser, registry), registry);
    run_quietly(slam);
    const RunStats& s = slam.stats();
    std::cout << plan << " " << seed << ": " << s.matches_wrong << " of " << s.matches_checked
              << " matches pair another object (" << s.matches_wrong_long_unseen << " of the " << s.matches_long_unseen
              << " with features long unseen); long relations " << long_relations(dir, slam.trajectory()).translation.mean
              << " m\n";
    EXPECT_GT(s.matches_checked, 1500);
    EXPECT_EQ(s.matches_wrong, static_cast<std::int64_t>(slam.wrong_matches().size()));
    if (plan == "ring") {
      EXPECT_EQ(s.matches_wrong, 0);  // no verdict against a right map
      continue;
    }
    EXPECT_GE(s.matches_wrong, 5);
    EXPECT_EQ(s.matches_wrong_long_unseen, s.matches_wrong);
    for (const Slam::WrongMatch& w : slam.wrong_matches()) {
      const auto f = std::find_if(slam.features().begin(), slam.features().end(),
                                  [&](const MapFeature& m) { return m.id == w.feature; });
      ASSERT_NE(f, slam.features().end());
      ASSERT_EQ(f->feature->coords().size(), 4);
      const TwoSightings t = two_sightings(slam, *f, w.previous_step, w.step);
      std::cout << "  step " << w.step << ": #" << w.feature << " (last seen at step " << w.previous_step
                << "): its two sightings in the true frame " << t.across << " m apart across, "
                << t.angle * 180.0 / std::numbers::pi << " deg\n";
      EXPECT_GT(t.across, 0.3) << "step " << w.step << ", feature #" << w.feature;
    }
  }
}

// The re-entry test (association.reentry_joint_test): a match with a wall
// unseen for over 30 m of travel stays only when, with the robot's
// covariance widened to 2² Σ_r, the reading's re-entry measurements pick it
// jointly and uniquely. robotlaser_logged l_ring 7, whose 12 wrong re-entries
// leave the map worse than its odometry (2.34 m against 1.17 m; the test
// above), keeps none of them and comes under 0.2 m (measured 0.173 m,
// 2026-12-07); ring 2, right without it (0.028 m), stays right. The test is
// off in config/intel_walls.yaml: on 144 generated buildings it helps as many
// runs as it harms (README, "The re-entry test").
TEST(LoopClosingRun, TheReentryTestRefusesTheWrongReturns) {
  set_log_level(LogLevel::Warn);
  for (const auto& [plan, seed] : {std::pair<std::string, int>{"l_ring", 7}, {"ring", 2}}) {
    const auto [dir, laser] = logged_building(plan, static_cast<std::uint64_t>(seed), "robotlaser_logged");
    PluginRegistry registry;
    registry.add_search_dir(MSPACE_PLUGIN_DIR);
    RunConfig config = intel_walls_on(dir, laser, registry);
    config.association.reentry_joint_test = true;
    Slam slam(config, registry);
    run_quietly(slam);
    const RunStats& s = slam.stats();
    const AssociationStats& a = slam.association_stats();
    const double error = long_relations(dir, slam.trajectory()).translation.mean;
    std::cout << plan << " " << seed << ": re-entries confirmed " << a.reentry_confirmed << ", refused "
              << a.reentry_refused << "; " << s.matches_wrong << " of " << s.matches_checked
              << " matches pair another object; long relations " << error << " m\n";
    EXPECT_GT(a.reentry_confirmed, 20) << "re-entries are still made";
    EXPECT_GT(a.reentry_refused, 0);
    EXPECT_LE(s.matches_wrong_long_unseen, 1);
    EXPECT_LT(error, plan == "ring" ? 0.05 : 0.2);
  }
}

// A robot anchored to one pass of the old map that comes back to another
// pass, which has drifted from it, needs a motion beyond the window its last
// anchor allows (README, "Why the remaining runs miss their loops"). The
// second search (association.loop_wide_drift_per_metre) looks as far as a
// nearby old feature can have drifted at the measured rate since the robot
// last saw it. config/intel_walls.yaml on l_ring, world seed 15, sick181 with
// gaps: the first search alone closes the loop once and leaves the map worse
// than its own laser odometry; the second closes it right and brings the
// long relations under 0.15 m, with no false closure and no wrong pair.
TEST(LoopClosingRun, ASecondSearchInAWiderWindowFindsADriftedPass) {
  const fs::path dir = building_with_gaps("l_ring", 15);
  set_log_level(LogLevel::Warn);
  const auto run_with = [&](double rate) {
    PluginRegistry registry;
    registry.add_search_dir(MSPACE_PLUGIN_DIR);
    RunConfig config = intel_walls_on(dir, sim_building::GeneratorSettings{}.laser, registry);
    config.association.loop_wide_drift_per_metre = rate;
    Slam slam(config, registry);
    run_quietly(slam);
    const RunStats& stats = slam.stats();
    const RelationErrors e = long_relations(dir, slam.trajectory());
    const RelationErrors odometry = long_relations(dir, slam.dead_reckoning());
    std::cout << "loop_wide_drift_per_metre " << rate << ": " << stats.loop_closures << " closures ("
              << stats.loop_wide_closures << " in the wider window, " << stats.loop_wide_searches << " searches there), "
              << stats.loop_false << " false, " << stats.loop_wrong_pairs << " pairing a wrong object; long relations "
              << e.translation.mean << " m against " << odometry.translation.mean << " m for the laser odometry\n";
    EXPECT_GT(e.matched, 10u);
    EXPECT_EQ(stats.loop_false, 0);
    EXPECT_EQ(stats.loop_wrong_pairs, 0);
    return std::tuple{stats.loop_wide_closures, stats.loop_wide_searches, e.translation.mean, odometry.translation.mean};
  };
  const auto [wide_without, searches_without, long_without, odometry] = run_with(0.0);
  const auto [wide_with, searches_with, long_with, odometry_again] = run_with(0.025);
  EXPECT_EQ(searches_without, 0);
  EXPECT_EQ(wide_without, 0);
  EXPECT_GT(long_without, odometry);  // the first search alone: worse than the odometry
  EXPECT_GE(wide_with, 1);
  EXPECT_LT(long_with, 0.15);
  EXPECT_LT(long_with, odometry_again);
}

// Frames (output.frames, MapFrames) mark where the loop closed: on the ring
// with a logging gap (one closure), a magenta ring at the robot's pose of the
// closing step appears in the frames from that step on and in none before.
TEST(LoopClosingRun, FramesMarkTheLoopClosureFromItsStepOn) {
  const fs::path dir = building_with_gaps("ring", 1);
  set_log_level(LogLevel::Warn);
  setenv("MSPACE_SIM_BUILDING", dir.c_str(), 1);
  PluginRegistry registry;
  registry.add_search_dir(MSPACE_PLUGIN_DIR);
  RunConfig config = load_config(fs::path(MSPACE_SOURCE_DIR) / "config" / "sim_building.yaml", registry);
  config.source.params.set("odometry", std::string("wheel"));
  config.association.loop_closing = true;
  override_estimator(config, "smoother", registry);
  const fs::path out = fs::path(MSPACE_BINARY_DIR) / "test-output" / "loop_closing_run" / "frames";
  fs::remove_all(out);
  config.output.dir = out.string();
  config.output.trajectory = config.output.map = config.output.summary = config.output.picture = false;
  config.output.grid.enabled = false;
  config.output.picture_size = 400;
  config.output.frames = 200;
  Slam slam(config, registry);
  RunOptions options;
  options.progress = false;
  std::int64_t closed_at = -1;  // the step of the first closure
  options.after_step = [&](std::size_t) {
    if (closed_at < 0 && slam.stats().loop_closures > 0) closed_at = slam.steps_done();
  };
  const RunResult result = run_to_end(slam, options);
  ASSERT_GE(slam.stats().loop_closures, 1);
  ASSERT_TRUE(result.frames.has_value());
  int before = 0, after = 0;
  for (const fs::directory_entry& e : fs::directory_iterator(out / "frames")) {
    png_image image{};
    image.version = PNG_IMAGE_VERSION;
    ASSERT_NE(png_image_begin_read_from_file(&image, e.path().c_str()), 0) << e.path();
    image.format = PNG_FORMAT_BGR;
    std::vector<unsigned char> px(PNG_IMAGE_SIZE(image));
    ASSERT_NE(png_image_finish_read(&image, nullptr, px.data(), 0, nullptr), 0) << e.path();
    int marked = 0;  // pixels of the marker's colour exactly, (B, G, R) = (220, 0, 220)
    for (std::size_t i = 0; i + 2 < px.size(); i += 3) marked += px[i] == 220 && px[i + 1] == 0 && px[i + 2] == 220;
    const long long step = std::stoll(e.path().stem().string().substr(6));  // frame_<step>
    if (step < closed_at) {
      ++before;
      EXPECT_EQ(marked, 0) << e.path().filename() << ", before the closure at step " << closed_at;
    } else {
      ++after;
      EXPECT_GT(marked, 0) << e.path().filename() << ", after the closure at step " << closed_at;
    }
  }
  std::cout << "loop closed at step " << closed_at << "; " << before << " frames before, " << after << " from then on ("
            << result.frames->view_changes << " view changes)\n";
  EXPECT_GT(before, 0);
  EXPECT_GT(after, 0);
}

}  // namespace
