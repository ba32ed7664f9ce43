// mspace-sim-building — writes a simulated office building data set for 2-D
// laser SLAM (building_log.hpp): a CARMEN log with drifting wheel odometry,
// ground truth, relations, the floor plan and a picture.
//
//   mspace-sim-building --out out/sim_building --plan ring --world-seed 1 --seed 1 --laser sick181
//   mspace-sim-building --out /tmp/b --plan 3 --laser sick_interleaved --laser-param max_range=30
//   mspace-sim-building --list
#include <CLI/CLI.hpp>
#include <cstdio>
#include <exception>
#include <map>
#include <string>
#include <vector>

#include "building_log.hpp"

namespace {

using namespace mspace::sim_building;

/// Sets one odometry-error or route parameter from "key=value".
void set_param(GeneratorSettings& s, const std::string& key_value) {
  const auto eq = key_value.find('=');
  if (eq == std::string::npos) throw std::invalid_argument("parameter '" + key_value + "': expected key=value");
  const std::string key = key_value.substr(0, eq), text = key_value.substr(eq + 1);
  const std::map<std::string, double*> keys = {{"scale_error", &s.odometry.scale_error},
                                               {"turn_scale_error", &s.odometry.turn_scale_error},
                                               {"heading_bias_deg_per_m", &s.odometry.heading_bias_deg_per_m},
                                               {"xy_noise", &s.odometry.xy_noise},
                                               {"heading_noise_deg", &s.odometry.heading_noise_deg},
                                               {"turn_noise", &s.odometry.turn_noise},
                                               {"room_visit_probability", &s.route.room_visit_probability},
                                               {"min_speed", &s.route.min_speed},
                                               {"max_speed", &s.route.max_speed},
                                               {"accel", &s.route.accel},
                                               {"arc_radius", &s.route.arc_radius},
                                               {"arc_speed", &s.route.arc_speed},
                                               {"turn_rate", &s.route.turn_rate},
                                               {"turn_accel", &s.route.turn_accel}};
  const auto it = keys.find(key);
  if (it == keys.end()) {
    std::string list;
    for (const auto& [k, unused] : keys) list += (list.empty() ? "" : ", ") + k;
    throw std::invalid_argument("unknown parameter '" + key + "' (keys: " + list + ")");
  }
  std::size_t used = 0;
  double v = 0.0;
  try {
    v = std::stod(text, &used);
  } catch (const std::exception&) {
    used = 0;
  }
  if (used == 0 || used != text.size() || !std::isfinite(v))
    throw std::invalid_argument("parameter " + key + ": '" + text + "' is not a finite number");
  *it->second = v;
}

}  // namespace

int main(int argc, char** argv) {
  const CLI::Validator kSeed(
      [](std::string& text) {
        return text.find_first_not_of("0123456789") == std::string::npos && !text.empty()
                   ? std::string()
                   : "'" + text + "' is not a non-negative integer";
      },
      "UINT");
  GeneratorSettings settings;
  std::string out, preset = "sick181";
  std::vector<std::string> laser_params, params;
  bool list = false, no_clutter = false;
  CLI::App app{
      "Write a simulated office building data set for 2-D laser SLAM: building.clf (CARMEN log), "
      "ground_truth.tum, odometry.tum, building.relations, floor_plan.yaml, floor_plan.png, README.txt"};
  app.add_option("--out", out, "output folder (created if needed)");
  app.add_option("--plan", settings.plan, "plan family, by name or index (--list)")->capture_default_str();
  app.add_option("--world-seed", settings.world_seed, "seed of the floor plan")
      ->check(kSeed)
      ->capture_default_str();
  app.add_option("--seed", settings.seed, "seed of the route, the odometry errors and the laser noise")
      ->check(kSeed)
      ->capture_default_str();
  app.add_option("--laser", preset, "laser preset (--list)")->capture_default_str();
  app.add_option("--laser-param", laser_params,
                 "override a laser parameter, key=value (repeatable), e.g. "
                 "beams=360 resolution_deg=0.5 interleave=4 no_return=50 mount_x=0.22");
  app.add_option("--param", params,
                 "override an odometry-error or route parameter, key=value (repeatable), e.g. "
                 "heading_bias_deg_per_m=0.3 scale_error=0.02 max_speed=0.8");
  app.add_option("--length-m", settings.route.length_m, "drive at least this far before the final lap of loop 0")
      ->check(CLI::Range(0.0, 20000.0))
      ->capture_default_str();
  app.add_option("--people", settings.plan_options.people, "moving people (default: the plan's, -1)")
      ->check(CLI::Range(-1, 50));
  app.add_flag("--no-clutter", no_clutter, "no boxes or pillars in the rooms");
  app.add_flag("--list", list, "list the plans and laser presets and exit");
  CLI11_PARSE(app, argc, argv);
  if (list) {
    std::printf("plans:\n");
    for (std::size_t i = 0; i < plan_names().size(); ++i) std::printf("  %zu %s\n", i, plan_names()[i].c_str());
    std::printf("laser presets:\n");
    for (const auto& [name, text] : laser_presets()) std::printf("  %-17s %s\n", name.c_str(), text.c_str());
    return 0;
  }
  if (out.empty()) {
    std::fprintf(stderr, "mspace-sim-building: --out DIR is required\n");
    return 2;
  }
  try {
    settings.plan_options.clutter = !no_clutter;
    settings.laser = laser_preset(preset);
    for (const std::string& kv : laser_params) set_laser_param(settings.laser, kv);
    for (const std::string& kv : params) set_param(settings, kv);
    for (int i = 0; i < argc; ++i) settings.command_line += (i ? " " : "") + std::string(argv[i]);
    const Simulation sim = simulate(settings);
    write_data_set(sim, out);
    std::printf("%s (world seed %llu, seed %llu, laser %s): %.1f m, %zu scans, %zu + %zu relations, written to %s\n",
                sim.plan.name.c_str(), static_cast<unsigned long long>(settings.world_seed),
                static_cast<unsigned long long>(settings.seed), settings.laser.preset.c_str(), sim.route.length,
                sim.scans.size(), sim.short_relations, sim.long_relations, out.c_str());
  } catch (const std::exception& e) {
    std::fprintf(stderr, "mspace-sim-building: %s\n", e.what());
    return 1;
  }
  return 0;
}
