// bench_line_sweep — laser_lines swept over the laser presets of the
// generated buildings (issue 18 item 3): precision and recall of lines and of
// their real ends against the floor plan (line_truth.hpp), with the
// extractor settings of config/intel_walls.yaml, bridge_no_returns N (2
// unless --bridge says) beside 0 (every no-return cuts a line). Not a
// CTest test: run by hand on a Release build,
//
//   build/bin/bench_line_sweep [--plans ring,ladder,l_ring,long_loop,grid,symmetric] [--seeds 1,2]
//                              [--lasers all] [--stride 2] [--bridge N]
//
// One line per laser preset, summed over the plans and seeds (the shortest
// route of each: loop 0 twice).
#include <CLI/CLI.hpp>
#include <cstdint>
#include <cstdio>
#include <string>
#include <vector>

#include "building_log.hpp"
#include "laser.hpp"
#include "line_truth.hpp"

using namespace mspace::sim_building;

int main(int argc, char** argv) {
  CLI::App app{"laser_lines against the floor plan, per laser preset"};
  std::vector<std::string> plans{"ring", "ladder", "l_ring", "long_loop", "grid", "symmetric"}, lasers{"all"};
  std::vector<std::uint64_t> seeds{1, 2};
  std::size_t stride = 2;
  int bridge = 2;
  app.add_option("--plans", plans, "comma-separated plan names")->delimiter(',');
  app.add_option("--seeds", seeds, "comma-separated seeds (world seed = seed)")->delimiter(',');
  app.add_option("--lasers", lasers, "comma-separated laser presets, or all")->delimiter(',');
  app.add_option("--stride", stride, "score every stride-th scan");
  app.add_option("--bridge", bridge, "bridge_no_returns to compare with 0");
  bool sigma_from_data = false;
  app.add_flag("--sigma-from-data", sigma_from_data,
               "compare the range noise measured on the scans (range_sigma_from_data) with the configured one, "
               "both at --bridge, instead of --bridge with 0");
  CLI11_PARSE(app, argc, argv);

  std::vector<std::string> presets = lasers;
  if (lasers == std::vector<std::string>{"all"}) {
    presets.clear();
    for (const auto& [name, description] : laser_presets()) presets.push_back(name);
  }
  mspace::laser_lines::LineConfig configured = intel_walls_line_config();
  configured.bridge_no_returns = bridge;
  mspace::laser_lines::LineConfig cutting = configured;
  if (!sigma_from_data) cutting.bridge_no_returns = 0;

  if (sigma_from_data)
    std::printf("laser_lines (config/intel_walls.yaml, bridge_no_returns %d; range noise measured | configured) on "
                "%zu plans × %zu seeds, every %zu-th scan\n",
                configured.bridge_no_returns, plans.size(), seeds.size(), stride);
  else
    std::printf("laser_lines (config/intel_walls.yaml, bridge_no_returns %d | 0) on %zu plans × %zu seeds, every "
                "%zu-th scan\n",
                configured.bridge_no_returns, plans.size(), seeds.size(), stride);
  std::printf("%-20s %6s %7s | %9s %9s %9s %9s | %9s %9s %9s %9s\n", "laser", "scans", "pieces", "precision",
              "recall", "end prec", "end rec", "prec (0)", "rec (0)", "e.prec(0)", "e.rec(0)");
  for (const std::string& preset : presets) {
    LineScore with, without;
    for (const std::string& plan : plans)
      for (const std::uint64_t seed : seeds) {
        GeneratorSettings settings;
        settings.plan = plan;
        settings.world_seed = settings.seed = seed;
        settings.route.length_m = 0.0;
        settings.laser = laser_preset(preset);
        const Simulation sim = simulate(settings);
        with += score_lines(sim, configured, stride, sigma_from_data);
        without += score_lines(sim, cutting, stride);
      }
    std::printf("%-20s %6zu %7zu | %9.3f %9.3f %9.3f %9.3f | %9.3f %9.3f %9.3f %9.3f\n", preset.c_str(), with.scans,
                with.visible, with.precision(), with.recall(), with.end_precision(), with.end_recall(),
                without.precision(), without.recall(), without.end_precision(), without.end_recall());
    std::fflush(stdout);
  }
  return 0;
}
