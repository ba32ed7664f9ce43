// Saved maps (issue 16, docs/maps.md): loading a map of 10 000 features, and
// the cost of a localize-mode step in a map of ~110 features against one of
// ~10 000 (the bound: within 10 %).
//
// The maps are made, not typed in: sim_points is mapped once (its map.bin
// holds ~110 point features with their covariance), and a map of T tiles is
// that map repeated T times side by side, 60 m apart in x and 40 m in y (the
// world's size), each copy with its own ids and estimator rows and the same
// marginal covariances — a large map made of real features. Localization runs
// in tile 0 (the simulated world with the same layout, other noise), so every
// tile beyond it only makes the map bigger.
//
//   ./build/bin/bench_maps --benchmark_repetitions=5 --benchmark_report_aggregates_only=true
#include <benchmark/benchmark.h>

#include <chrono>
#include <filesystem>
#include <memory>
#include <string>

#include "build_path.hpp"
#include "config.hpp"
#include "logging.hpp"
#include "persistence.hpp"
#include "plugin_registry.hpp"
#include "runner.hpp"
#include "slam.hpp"

namespace {

using namespace mspace;
using namespace mspace::kernel;
namespace fs = std::filesystem;

const fs::path kSource = MSPACE_SOURCE_DIR;
const fs::path kWork = fs::temp_directory_path() / "mspace_bench_maps";
constexpr double kTileWidth = 60.0, kTileHeight = 40.0;  // sim_points' world
constexpr int kTilesPerRow = 10;

RunConfig sim_config(PluginRegistry& registry, std::int64_t seed) {
  registry.add_search_dir(MSPACE_PLUGIN_DIR);
  RunConfig c = load_config(kSource / "config" / "sim_points.yaml", registry);
  c.seed = seed;
  c.source.params.set("world_seed", std::int64_t{1});
  apply_run_seed(c);
  c.output.picture = false;
  c.output.grid.enabled = false;
  return c;
}

/// The map of one sim_points run (made once per process).
const StoredMap& base_map() {
  static const StoredMap map = [] {
    set_log_level(LogLevel::Warn);
    fs::remove_all(kWork);  // maps of an earlier build are not reused
    PluginRegistry registry;
    RunConfig c = sim_config(registry, 1);
    c.output.dir = (kWork / "base").string();
    Slam slam(c, registry);
    RunOptions options;
    options.progress = false;
    run_to_end(slam, options);
    StoredMap m = read_map_file(kWork / "base" / "map.bin");
    // Only what is in the map proper: tentative features are dropped by localize anyway.
    std::erase_if(m.features, [](const StoredFeature& f) { return f.saved.mspace_dim == 0; });
    return m;
  }();
  return map;
}

/// The base map repeated `tiles` times; with its joint covariance (block
/// diagonal: the copies are independent) when `joint`. Written once per size.
fs::path tiled_map(int tiles, bool joint) {
  const StoredMap& base = base_map();  // first: it clears what an earlier process left
  const fs::path dir = kWork / ("tiles_" + std::to_string(tiles) + (joint ? "_joint" : ""));
  if (fs::exists(dir / "map.bin")) return dir;
  StoredMap m = base;
  m.features.clear();
  const int rows = base.covariance->rows;
  std::int64_t next_id = 1;
  for (int t = 0; t < tiles; ++t) {
    const double dx = kTileWidth * (t % kTilesPerRow), dy = kTileHeight * (t / kTilesPerRow);
    for (const StoredFeature& f : base.features) {
      StoredFeature copy = f;
      copy.id = next_id++;
      copy.saved.coords[0] += dx;  // a point feature: (x, y, z)
      copy.saved.coords[1] += dy;
      for (int& i : copy.state_idx) i += t * rows;
      for (int& i : copy.own_idx) i += t * rows;
      m.features.push_back(std::move(copy));
    }
  }
  m.covariance->rows = rows * tiles;
  m.covariance->joint.reset();
  if (joint) {
    // The robot's rows first (correlated with tile 0, where it was), then
    // each tile's copy of the map's block; the tiles are independent.
    const StoredMap full = read_map_file(kWork / "base" / "map.bin");  // base_map() dropped nothing from it
    const Eigen::MatrixXd& P = *full.covariance->joint;
    const int k = full.covariance->first_row;
    Eigen::MatrixXd J = Eigen::MatrixXd::Zero(k + rows * tiles, k + rows * tiles);
    J.topLeftCorner(k + rows, k + rows) = P;
    for (int t = 1; t < tiles; ++t) J.block(k + t * rows, k + t * rows, rows, rows) = P.bottomRightCorner(rows, rows);
    m.covariance->joint = std::move(J);
  }
  fs::create_directories(dir);
  write_map_file(dir / "map.bin", m);
  return dir;
}

/// A localize run in the map of `tiles` tiles (noise seed 2).
std::unique_ptr<Slam> localize_in(const fs::path& map, PluginRegistry& registry) {
  RunConfig c = sim_config(registry, 2);
  c.output.dir = (kWork / "localize").string();
  c.map.load = map.string();
  c.map.mode = MapConfig::Mode::Localize;
  return std::make_unique<Slam>(c, registry);
}

// Reading and checking the whole file and restoring every feature through
// its plugin: constructing the localize run (plugins loaded, map in place).
void BM_LoadMap(benchmark::State& state) {
  set_log_level(LogLevel::Warn);
  const int tiles = static_cast<int>(state.range(0));
  const bool joint = state.range(1) != 0;
  const fs::path map = tiled_map(tiles, joint);
  std::size_t features = 0;
  for (auto _ : state) {
    PluginRegistry registry;
    RunConfig c = sim_config(registry, 2);
    c.output.dir = (kWork / "load").string();
    c.map.load = map.string();
    c.map.mode = joint ? MapConfig::Mode::Extend : MapConfig::Mode::Localize;
    Slam slam(c, registry);
    features = slam.features().size();
  }
  state.counters["features"] = static_cast<double>(features);
  state.counters["MB"] = static_cast<double>(fs::file_size(map / "map.bin")) / 1e6;
}
// {tiles, joint}: 90 tiles ≈ 10 000 features with marginal covariances (what
// localize reads); 9 tiles ≈ 1 000 features with the joint covariance (extend).
BENCHMARK(BM_LoadMap)->Args({90, 0})->Args({1, 0})->Args({9, 1})->Unit(benchmark::kMillisecond)->UseRealTime();

// Steps 1 001 to 2 000 of a localize run (the robot is then well inside the
// map), timed step by step; the time reported is per step.
void BM_LocalizeStep(benchmark::State& state) {
  set_log_level(LogLevel::Warn);
  const fs::path map = tiled_map(static_cast<int>(state.range(0)), false);
  constexpr int kWarm = 1000, kTimed = 1000;
  std::size_t features = 0;
  for (auto _ : state) {
    PluginRegistry registry;
    std::unique_ptr<Slam> slam = localize_in(map, registry);
    features = slam->features().size();
    for (int i = 0; i < kWarm; ++i) slam->step();
    const auto t0 = std::chrono::steady_clock::now();
    for (int i = 0; i < kTimed; ++i) slam->step();
    const double seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    state.SetIterationTime(seconds / kTimed);
  }
  state.counters["features"] = static_cast<double>(features);
}
// Each iteration is a whole run of 2 000 steps whose reported time is that of one
// step: the iteration count is fixed (manual time would otherwise ask for
// thousands of runs to fill the minimum time).
BENCHMARK(BM_LocalizeStep)->Arg(1)->Arg(90)->Iterations(2)->Unit(benchmark::kMicrosecond)->UseManualTime();

}  // namespace

BENCHMARK_MAIN();
