// The spatial index of association: the grid against brute force, and whole
// runs with and without it, which must be identical (every pose of the
// trajectory, every match count, every feature's coordinates).
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <random>
#include <set>
#include <string>
#include <vector>

#include "association.hpp"
#include "build_path.hpp"
#include "config.hpp"
#include "logging.hpp"
#include "plugin_registry.hpp"
#include "runner.hpp"
#include "slam.hpp"

namespace {

using namespace mspace;
using namespace mspace::kernel;

double box_distance(const PlanarBox& b, const Eigen::Vector2d& p) {
  const double dx = std::max({b.min_x - p.x(), 0.0, p.x() - b.max_x});
  const double dy = std::max({b.min_y - p.y(), 0.0, p.y() - b.max_y});
  return std::hypot(dx, dy);
}

std::set<int> within(const std::vector<PlanarBox>& boxes, const std::vector<bool>& alive, const Eigen::Vector2d& p,
                     double r) {
  std::set<int> out;
  for (std::size_t i = 0; i < boxes.size(); ++i)
    if (alive[i] && (boxes[i].everywhere || box_distance(boxes[i], p) <= r)) out.insert(static_cast<int>(i));
  return out;
}

// Random points, segments (short and long), boxes without a position and
// boxes far away; moved, erased and re-inserted between queries. Every query
// returns each box within range exactly once, and none beyond it (but for
// round-off slack).
TEST(PlanarGrid, AgreesWithBruteForceThroughMovesAndRemovals) {
  std::mt19937 rng(3);
  std::uniform_real_distribution<double> pos(-100.0, 100.0), len(0.0, 30.0), unit(0.0, 1.0);
  const auto random_box = [&]() {
    PlanarBox b;
    const double u = unit(rng);
    if (u < 0.02) {
      b.everywhere = true;
      return b;
    }
    b.min_x = pos(rng);
    b.min_y = pos(rng);
    b.max_x = b.min_x + (u < 0.5 ? 0.0 : len(rng) * (u > 0.97 ? 100.0 : 1.0));  // points, segments, a few huge
    b.max_y = b.min_y + (u < 0.5 ? 0.0 : len(rng));
    return b;
  };
  for (double cell : {1.0, 7.5, 40.0}) {
    PlanarGrid grid(cell);
    std::vector<PlanarBox> boxes(500);
    std::vector<bool> alive(boxes.size(), true);
    for (std::size_t i = 0; i < boxes.size(); ++i) {
      boxes[i] = random_box();
      grid.set(static_cast<int>(i), boxes[i]);
    }
    for (int round = 0; round < 200; ++round) {
      for (int change = 0; change < 10; ++change) {
        const auto i = static_cast<std::size_t>(rng() % boxes.size());
        if (unit(rng) < 0.2) {
          grid.erase(static_cast<int>(i));
          alive[i] = false;
        } else {
          boxes[i] = unit(rng) < 0.5 ? random_box()  // jump anywhere
                                     : PlanarBox{boxes[i].min_x + 0.3, boxes[i].min_y - 0.2, boxes[i].max_x + 0.3,
                                                 boxes[i].max_y - 0.2, boxes[i].everywhere};  // small move
          grid.set(static_cast<int>(i), boxes[i]);
          alive[i] = true;
        }
      }
      const Eigen::Vector2d p(pos(rng), pos(rng));
      const double r = unit(rng) < 0.1 ? 500.0 : 20.0 * unit(rng);
      std::vector<int> keys;
      grid.query(p, r, keys);
      const std::set<int> got(keys.begin(), keys.end());
      ASSERT_EQ(got.size(), keys.size()) << "a key came twice";
      const std::set<int> need = within(boxes, alive, p, r);
      const std::set<int> allowed = within(boxes, alive, p, r * (1.0 + 1e-6) + 1e-6);
      for (int k : need) ASSERT_TRUE(got.count(k)) << "missed box " << k << " (cell " << cell << ", round " << round << ")";
      for (int k : got) ASSERT_TRUE(allowed.count(k)) << "box " << k << " is out of range";
    }
    EXPECT_EQ(grid.size(), static_cast<std::size_t>(std::count(alive.begin(), alive.end(), true)));
  }
}

class IndexRun : public ::testing::Test {
 protected:
  void SetUp() override {
    registry_.add_search_dir(MSPACE_PLUGIN_DIR);
    registry_.add_search_dir(MSPACE_INTEL_FIXTURE_DIR);
    set_log_level(LogLevel::Warn);
  }

  struct Outcome {
    std::vector<StampedPose> trajectory;
    RunStats stats;
    AssociationStats association;
    std::vector<std::pair<int, Eigen::VectorXd>> features;
  };

  Outcome run(const RunConfig& c) {
    Slam slam(c, registry_);
    while (slam.step()) {
    }
    Outcome o{slam.trajectory(), slam.stats(), slam.association_stats(), {}};
    for (const MapFeature& f : slam.features()) o.features.emplace_back(f.id, f.feature->coords());
    return o;
  }

  /// Runs `c` with the spatial index (at two cell sizes) and without it and
  /// requires identical results.
  void expect_identical_with_and_without_index(RunConfig c) {
    c.association.spatial_index = false;
    const Outcome full = run(c);
    EXPECT_EQ(full.association.index_queries, 0);
    ASSERT_GT(full.stats.matched, 0);
    for (double cell : {0.0, 1.5}) {  // the default (largest max_range) and small cells
      c.association.spatial_index = true;
      c.association.index_cell_size = cell;
      const Outcome indexed = run(c);
      EXPECT_GT(indexed.association.index_queries, 0);
      EXPECT_EQ(indexed.stats.matched, full.stats.matched) << "cell " << cell;
      EXPECT_EQ(indexed.stats.updates, full.stats.updates);
      EXPECT_EQ(indexed.stats.created, full.stats.created);
      EXPECT_EQ(indexed.stats.pruned, full.stats.pruned);
      EXPECT_EQ(indexed.stats.extended, full.stats.extended);
      ASSERT_EQ(indexed.trajectory.size(), full.trajectory.size());
      for (std::size_t i = 0; i < full.trajectory.size(); ++i)
        ASSERT_EQ(indexed.trajectory[i].pose, full.trajectory[i].pose) << "pose " << i << ", cell " << cell;
      ASSERT_EQ(indexed.features.size(), full.features.size());
      for (std::size_t i = 0; i < full.features.size(); ++i) {
        EXPECT_EQ(indexed.features[i].first, full.features[i].first);
        EXPECT_EQ(indexed.features[i].second, full.features[i].second);
      }
    }
  }

  PluginRegistry registry_;
};

const std::filesystem::path kSource = MSPACE_SOURCE_DIR;

// The built-in simulated world (point landmarks, sensor max_range 10 m).
TEST_F(IndexRun, SimulatedPointsIdenticalWithAndWithoutIndex) {
  RunConfig c = load_config(kSource / "config" / "sim_points.yaml", registry_);
  c.max_steps = 2500;
  ASSERT_GT(c.sensors.at(0).max_range, 0.0);
  expect_identical_with_and_without_index(c);
}

// Walls (segments indexed by their bounding boxes, end points sliding with
// dense information, tentative walls pruned, shared corners) in the
// simulated floor of tests/intel, with the laser's association range cut to
// 6 m so that the index leaves walls out.
TEST_F(IndexRun, SimulatedWallsIdenticalWithAndWithoutIndex) {
  const std::string text = R"(
run: {name: laser_room_index}
source: {plugin: laser_room, seed: 2, laps: 2, step: 0.3, range_sigma: 0.01}
motion: {plugin: odometry2d}
estimator: {plugin: ekf}
features:
  wall: {plugin: wall, min_observations: 3, min_points: 30, min_length: 1.0, max_normal_std: 0.05,
         min_end_observations: 3, max_end_spread: 0.1, max_path_distance: 15, max_observations: 40,
         match_margin: 0.5}
sensors:
  laser:
    mount: [0, 0, 0, 0, 0, 0]
    extractor: {plugin: laser_lines, range_sigma: 0.01, max_range: 20, split_distance: 0.06, min_points: 10,
                min_length: 0.6, max_rms: 0.03, depth_jump: 0.2}
    feeds: [wall]
    max_range: 6
association: {tentative_max_age: 10, join_distance: 0.3}
)";
  const RunConfig c = parse_config(text, "laser_room_index.yaml", registry_);
  expect_identical_with_and_without_index(c);
}

// The Intel Research Lab with the laser's association range set to 10 m.
TEST_F(IndexRun, IntelLabIdenticalWithAndWithoutIndex) {
  const std::filesystem::path data = kSource.parent_path() / "shared" / "datasets" / "intel_lab";
  if (!std::filesystem::is_regular_file(data / "intel_910_scans.txt") ||
      !std::filesystem::is_regular_file(data / "intel.relations"))
    GTEST_SKIP() << "Intel Research Lab data not found in " << data;
  setenv("MSPACE_DATA", data.parent_path().c_str(), /*overwrite=*/0);
  RunConfig c = load_config(kSource / "config" / "intel_walls.yaml", registry_);
  for (SensorConfig& s : c.sensors) s.max_range = 10.0;
  c.max_steps = 400;
  expect_identical_with_and_without_index(c);
}

// A node bound of 1 stops every search that has a candidate: each such
// reading falls back to nearest neighbour, is counted, and the run is the
// nearest-neighbour run.
TEST_F(IndexRun, JointCompatibilityAtItsNodeBoundFallsBackToNearestNeighbour) {
  RunConfig c = load_config(kSource / "config" / "sim_points.yaml", registry_);
  c.max_steps = 1500;
  const Outcome greedy = run(c);
  c.association.method = AssociationConfig::Method::Jcbb;
  c.association.jcbb_max_nodes = 1;
  const Outcome bounded = run(c);
  EXPECT_EQ(greedy.association.jcbb_readings, 0);
  EXPECT_EQ(bounded.association.jcbb_readings, greedy.stats.readings);
  EXPECT_GT(bounded.association.jcbb_bounded, bounded.association.jcbb_readings / 2);
  EXPECT_EQ(bounded.stats.matched, greedy.stats.matched);
  ASSERT_EQ(bounded.trajectory.size(), greedy.trajectory.size());
  for (std::size_t i = 0; i < greedy.trajectory.size(); ++i)
    ASSERT_EQ(bounded.trajectory[i].pose, greedy.trajectory[i].pose) << "pose " << i;
}

// JCBB through the kernel on the simulated world: it runs within its node
// bound and keeps the accuracy of the default run (ATE bound of tests/run).
TEST_F(IndexRun, JointCompatibilityOnTheSimulatedWorld) {
  RunConfig c = load_config(kSource / "config" / "sim_points.yaml", registry_);
  c.association.method = AssociationConfig::Method::Jcbb;
  c.output.dir = (std::filesystem::path(MSPACE_BINARY_DIR) / "test-output" / "association_jcbb").string();
  Slam slam(c, registry_);
  RunOptions options;
  options.progress = false;
  options.write_outputs = false;
  const RunResult r = run_to_end(slam, options);
  EXPECT_GT(slam.association_stats().jcbb_readings, 1000);
  EXPECT_EQ(slam.association_stats().jcbb_bounded, 0);
  ASSERT_TRUE(r.summary.errors.has_value());
  EXPECT_LT(r.summary.errors->ate_rmse, 0.15);
}

}  // namespace
