// Never worse than its own odometry (issue 18): config/sim_building.yaml on
// laser odometry, with each increment's measured covariance as its motion
// noise (`scan_match_covariance: true`), on generated buildings with people
// walking — three plans × two seeds × two laser presets, one of them the
// sparse one (a scan every 1.5 s, gaps of 2–6 s). The SLAM run's relations
// must be no worse than those of the laser odometry it started from, read by
// the same source (mean errors): long ones (≥ 60 s apart, the loop closures)
// in translation and rotation, short ones (< 60 s) in rotation. The short
// relations' translation is NOT asserted: it is 0.1–3 mm worse than the
// odometry's 5–6.5 mm in all 12 runs (measured, 2026-11-25). The bound is
// the odometry's own error on the same relations: nothing tuned. One test per
// plan, preset and seed (shortest route: loop 0 twice; 10–60 s each).
#include <gtest/gtest.h>

#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <string>
#include <vector>

#include "building_log.hpp"
#include "carmen_log.hpp"
#include "config.hpp"
#include "logging.hpp"
#include "plugin_registry.hpp"
#include "relations.hpp"
#include "runner.hpp"
#include "slam.hpp"

namespace {

using namespace mspace;
using namespace mspace::kernel;
namespace fs = std::filesystem;

struct Case {
  std::string plan, laser;
  std::uint64_t seed;
};

class NeverWorse : public ::testing::TestWithParam<Case> {};

/// The odometry the run starts from: the source's own reading of the log.
std::vector<StampedPose> odometry_poses(const InstanceConfig& source) {
  PluginArgs args;
  args.instance_name = "source";
  args.params = source.params;
  const carmen_log::CarmenLogSource log(args);
  std::vector<StampedPose> out;
  for (const carmen_log::Scan& s : log.contents().scans)
    out.push_back({s.t, make_pose2d(s.odometry[0], s.odometry[1], s.odometry[2])});
  return out;
}

TEST_P(NeverWorse, SlamRelationsAreNoWorseThanTheLaserOdometry) {
  set_log_level(LogLevel::Warn);
  const Case c = GetParam();
  {
    const std::uint64_t seed = c.seed;
    sim_building::GeneratorSettings settings;
    settings.plan = c.plan;
    settings.world_seed = settings.seed = seed;
    settings.route.length_m = 0.0;
    settings.laser = sim_building::laser_preset(c.laser);
    const sim_building::Simulation sim = sim_building::simulate(settings);
    ASSERT_GE(sim.plan.people.size(), 1u) << c.plan;
    const fs::path dir =
        fs::path(MSPACE_BINARY_DIR) / "tests" / "sim_building" / (c.plan + "_" + c.laser + "_" + std::to_string(seed));
    sim_building::write_data_set(sim, dir);
    setenv("MSPACE_SIM_BUILDING", dir.c_str(), 1);

    PluginRegistry registry;
    registry.add_search_dir(MSPACE_PLUGIN_DIR);
    RunConfig config = load_config(fs::path(MSPACE_SOURCE_DIR) / "config" / "sim_building.yaml", registry);
    ASSERT_EQ(config.source.params.get_string("odometry"), "scan_matched");
    config.source.params.set("scan_match_covariance", true);
    const std::vector<StampedPose> odometry = odometry_poses(config.source);
    Slam slam(config, registry);
    RunOptions options;
    options.progress = false;
    options.write_outputs = false;
    run_to_end(slam, options);

    std::vector<Relation> near, far;
    for (const Relation& r : read_relations(dir / "building.relations")) (r.t2 - r.t1 >= 60.0 ? far : near).push_back(r);
    const RelationErrors odo_near = evaluate_relations(odometry, near, 1e-4);
    const RelationErrors odo_far = evaluate_relations(odometry, far, 1e-4);
    const RelationErrors slam_near = evaluate_relations(slam.trajectory(), near, 1e-4);
    const RelationErrors slam_far = evaluate_relations(slam.trajectory(), far, 1e-4);
    std::printf("%s %s seed %d: short (%zu) odometry %.4f m / %.3f deg, SLAM %.4f m / %.3f deg | long (%zu) odometry "
                "%.3f m / %.2f deg, SLAM %.3f m / %.2f deg\n",
                c.plan.c_str(), c.laser.c_str(), static_cast<int>(seed), slam_near.matched,
                odo_near.translation.mean, odo_near.rotation_deg.mean, slam_near.translation.mean,
                slam_near.rotation_deg.mean, slam_far.matched, odo_far.translation.mean, odo_far.rotation_deg.mean,
                slam_far.translation.mean, slam_far.rotation_deg.mean);
    ASSERT_GT(near.size(), 10u);
    ASSERT_GT(far.size(), 5u);
    ASSERT_EQ(slam_far.matched, far.size());
    // Not asserted: the short relations' translation, which the walls make
    // slightly worse than the laser odometry's (all 12 runs, by 0.1–3 mm on
    // 5–6.5 mm; README, issue 18).
    EXPECT_LE(slam_near.rotation_deg.mean, odo_near.rotation_deg.mean) << c.plan << " " << c.laser << " seed " << seed;
    EXPECT_LE(slam_far.translation.mean, odo_far.translation.mean) << c.plan << " " << c.laser << " seed " << seed;
    EXPECT_LE(slam_far.rotation_deg.mean, odo_far.rotation_deg.mean) << c.plan << " " << c.laser << " seed " << seed;
  }
}

INSTANTIATE_TEST_SUITE_P(Buildings, NeverWorse,
                         ::testing::Values(Case{"ring", "sick181", 1}, Case{"ring", "sick181", 2},
                                           Case{"ladder", "sick181", 1}, Case{"ladder", "sick181", 2},
                                           Case{"l_ring", "sick181", 1}, Case{"l_ring", "sick181", 2},
                                           Case{"ring", "sparse", 1}, Case{"ring", "sparse", 2},
                                           Case{"ladder", "sparse", 1}, Case{"ladder", "sparse", 2},
                                           Case{"l_ring", "sparse", 1}, Case{"l_ring", "sparse", 2}),
                         [](const ::testing::TestParamInfo<Case>& info) {
                           return info.param.plan + "_" + info.param.laser + "_" + std::to_string(info.param.seed);
                         });

}  // namespace
