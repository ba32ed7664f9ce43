// bench_sim_building — config/sim_building.yaml (walls, shared corners, ekf)
// on many simulated buildings, scored with the relations metric against the
// odometry it runs on. Not a CTest test (minutes, not seconds): run by hand on a
// Release build,
//
//   build/bin/bench_sim_building [--plans ring,ladder,l_ring,long_loop,grid] [--seeds 1,2,3]
//                                [--length-m 400] [--laser sick181] [--modes scan_matched,wheel]
//                                [--out out/bench_sim_building] [--estimator smoother] [--loop-closing]
//
// For each plan and seed s (world seed = seed = s) it writes a data set with
// mspace-sim-building's library into OUT/<plan>_<s>/ and runs the config on it
// twice: on laser odometry (`odometry: scan_matched`, the config as it is) and
// on the drifting wheel odometry (`odometry: wheel`, with a motion noise for
// it, below). Each run is scored on the data set's relations, split into short
// ones (< 60 s apart: local accuracy) and long ones (≥ 60 s apart: the loop
// closures), next to the same relations of the odometry alone. "worse" counts
// the runs whose long-relation error exceeds their odometry's: the map should
// never be worse than the odometry it was built on.
#include <CLI/CLI.hpp>
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <exception>
#include <numbers>
#include <filesystem>
#include <sstream>
#include <string>
#include <vector>

#include "build_path.hpp"
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

std::vector<std::string> split(const std::string& text) {
  std::vector<std::string> out;
  std::stringstream s(text);
  for (std::string item; std::getline(s, item, ',');)
    if (!item.empty()) out.push_back(item);
  return out;
}

struct Score {
  std::size_t n = 0;
  double translation = 0.0;  ///< mean, m
  double rotation = 0.0;     ///< mean, deg
};

Score score(const std::vector<StampedPose>& trajectory, const std::vector<Relation>& relations) {
  const RelationErrors e = evaluate_relations(trajectory, relations, 1e-4);
  return {e.matched, e.translation.mean, e.rotation_deg.mean};
}

/// The odometry the run used, as poses at the scan times (carmen_log's own
/// reading of the log, with laser odometry when asked for).
std::vector<StampedPose> odometry_poses(const InstanceConfig& source) {
  PluginArgs args;
  args.instance_name = "source";
  args.params = source.params;
  carmen_log::CarmenLogSource log(args);
  // Per-step errors of the odometry increments against the ground truth's.
  std::vector<double> dxy, dth;
  double worst = 0.0, worst_t = 0.0;
  const auto& scans = log.contents().scans;
  for (std::size_t k = 1; k < scans.size(); ++k) {
    if (!scans[k].ground_truth || !scans[k - 1].ground_truth) continue;
    const Eigen::Vector3d o = carmen_log::odometry_increment(scans[k - 1].odometry, scans[k].odometry);
    const Eigen::Vector3d g = carmen_log::odometry_increment(*scans[k - 1].ground_truth, *scans[k].ground_truth);
    dxy.push_back(std::hypot(o[0] - g[0], o[1] - g[1]));
    dth.push_back(std::abs(std::remainder(o[2] - g[2], 2.0 * std::numbers::pi)) * 180.0 / std::numbers::pi);
    if (dxy.back() > worst) worst = dxy.back(), worst_t = scans[k].t;
  }
  auto quantile = [](std::vector<double> v, double q) {
    if (v.empty()) return 0.0;
    std::sort(v.begin(), v.end());
    return v[static_cast<std::size_t>(q * static_cast<double>(v.size() - 1))];
  };
  std::fprintf(
      stderr,
      "  %s odometry per step: xy median %.4f p99 %.4f max %.3f m (t %.1f), theta median %.3f p99 %.3f max %.2f deg\n",
      source.params.get_string("odometry").c_str(), quantile(dxy, 0.5), quantile(dxy, 0.99), worst, worst_t,
      quantile(dth, 0.5), quantile(dth, 0.99), quantile(dth, 1.0));
  std::vector<StampedPose> out;
  for (const carmen_log::Scan& s : log.contents().scans)
    out.push_back({s.t, make_pose2d(s.odometry[0], s.odometry[1], s.odometry[2])});
  return out;
}

/// key=value overrides, parsed as the plugin declares the key.
void override_params(InstanceConfig& instance, const std::vector<std::string>& overrides) {
  PluginRegistry registry;
  registry.add_search_dir(MSPACE_PLUGIN_DIR);
  for (const std::string& kv : overrides) {
    const auto eq = kv.find('=');
    if (eq == std::string::npos) throw std::invalid_argument("'" + kv + "': expected key=value");
    const std::string key = kv.substr(0, eq);
    const std::string value = kv.substr(eq + 1);
    const ParamSpec* spec = nullptr;
    for (const ParamSpec& p : registry.load(instance.plugin)->descriptor->params)
      if (p.name == key) spec = &p;
    if (spec == nullptr) throw std::invalid_argument(instance.plugin + " has no parameter '" + key + "'");
    instance.params.set(key, parse_param(*spec, value));
  }
}

}  // namespace

int main(int argc, char** argv) {
  std::string plans = "ring,ladder,l_ring,long_loop,grid", seeds = "1,2,3", modes = "scan_matched,wheel";
  std::string laser = "sick181", out = "out/bench_sim_building";
  double length = 400.0;
  std::vector<std::string> source_params, motion_params, laser_params;
  int people = -1;
  std::string estimator;
  bool loop_closing = false;
  CLI::App app{"config/sim_building.yaml on simulated buildings: relations of the SLAM run against its odometry"};
  app.add_option("--plans", plans, "comma-separated plan names or indices")->capture_default_str();
  app.add_option("--seeds", seeds, "comma-separated seeds (world seed = seed)")->capture_default_str();
  app.add_option("--modes", modes, "odometry modes: scan_matched, wheel")->capture_default_str();
  app.add_option("--laser", laser, "laser preset (the config assumes sick181's mount and codes)")
      ->capture_default_str();
  app.add_option("--length-m", length, "route length before the final lap")->capture_default_str();
  app.add_option("--out", out, "folder for the data sets")->capture_default_str();
  app.add_option("--laser-param", laser_params, "override a laser parameter of the generator, key=value");
  app.add_option("--people", people, "moving people in the buildings (-1: the plan's default)");
  app.add_option("--source-param", source_params, "override a source parameter, key=value (lists: a,b,c)");
  app.add_option("--motion-param", motion_params, "override a motion parameter, key=value (after the mode's)");
  app.add_option("--estimator", estimator, "run this estimator plugin instead of the configuration's (e.g. smoother)");
  app.add_flag("--loop-closing", loop_closing, "turn on map matching (association.loop_closing)");
  CLI11_PARSE(app, argc, argv);

  set_log_level(LogLevel::Warn);
  PluginRegistry registry;
  registry.add_search_dir(MSPACE_PLUGIN_DIR);
  std::printf("%-10s %4s %-12s %5s %5s | %-15s %-15s | %-15s %-15s | %6s %5s %6s %6s %s %s\n", "plan", "seed", "odometry",
              "short", "long", "odo short m/deg", "SLAM short", "odo long m/deg", "SLAM long", "ATE m", "walls",
              "slam s", "data s", "loops", "search s");
  int worse = 0, runs = 0;
  try {
    for (const std::string& plan : split(plans)) {
      for (const std::string& seed_text : split(seeds)) {
        const auto seed = static_cast<std::uint64_t>(std::stoull(seed_text));
        sim_building::GeneratorSettings settings;
        settings.plan = plan;
        settings.world_seed = settings.seed = seed;
        settings.route.length_m = length;
        settings.laser = sim_building::laser_preset(laser);
        for (const std::string& kv : laser_params) sim_building::set_laser_param(settings.laser, kv);
        settings.plan_options.people = people;
        const auto t_gen = std::chrono::steady_clock::now();
        const sim_building::Simulation sim = sim_building::simulate(settings);
        const fs::path dir = fs::path(out) / (sim.plan.name + "_" + seed_text);
        sim_building::write_data_set(sim, dir);
        const double gen_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - t_gen).count();
        setenv("MSPACE_SIM_BUILDING", dir.c_str(), 1);
        std::vector<Relation> all = read_relations(dir / "building.relations"), near, far;
        for (const Relation& r : all) (r.t2 - r.t1 >= 60.0 ? far : near).push_back(r);
        for (const std::string& mode : split(modes)) {
          RunConfig config = load_config(fs::path(MSPACE_SOURCE_DIR) / "config" / "sim_building.yaml", registry);
          config.source.params.set("odometry", mode);
          if (mode == "wheel") {
            // The simulated wheel odometry per 5 Hz step (≈ 0.15 m): 1 % scale
            // and turn-scale errors, 0.05°/m heading bias, white noise; σ set
            // a few times above those systematic errors.
            config.motion.params.set("xy_noise_per_m", 0.05);
            config.motion.params.set("xy_noise_floor", 0.005);
            config.motion.params.set("theta_noise_per_rad", 0.05);
            config.motion.params.set("theta_noise_per_m", 1.0);
            config.motion.params.set("theta_noise_floor", 0.1);
          }
          if (!estimator.empty()) override_estimator(config, estimator, registry);
          config.association.loop_closing = config.association.loop_closing || loop_closing;
          override_params(config.source, source_params);
          override_params(config.motion, motion_params);
          const std::vector<StampedPose> odometry = odometry_poses(config.source);
          const auto t0 = std::chrono::steady_clock::now();
          Slam slam(config, registry);
          RunOptions options;
          options.progress = false;
          options.write_outputs = false;
          const RunResult r = run_to_end(slam, options);
          const double slam_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
          const Score on = score(odometry, near), of = score(odometry, far);
          const Score sn = score(slam.trajectory(), near), sf = score(slam.trajectory(), far);
          int walls = 0;  // (features of every type)
          for (const auto& [type, dims] : r.summary.features_by_dim)
            for (const auto& [dim, n] : dims) walls += n;
          // Map matching: closures accepted / of them false against the ground truth.
          const RunStats& st = slam.stats();
          const std::string loops = config.association.loop_closing
                                        ? std::to_string(st.loop_closures) + "/" + std::to_string(st.loop_false)
                                        : std::string("-");
          ++runs;
          if (sf.translation > of.translation) ++worse;
          std::printf(
              "%-10s %4s %-12s %5zu %5zu | %6.3f / %5.2f  %6.3f / %5.2f  | %6.2f / %5.1f  %6.2f / %5.1f  | "
              "%6.2f %5d %6.1f %6.0f %s %.2f\n",
              sim.plan.name.c_str(), seed_text.c_str(), mode.c_str(), sn.n, sf.n, on.translation, on.rotation,
              sn.translation, sn.rotation, of.translation, of.rotation, sf.translation, sf.rotation,
              r.summary.errors ? r.summary.errors->ate_rmse : -1.0, walls, slam_s, r.summary.data_seconds,
              loops.c_str(), st.seconds_loops);
          std::fflush(stdout);
        }
        std::fprintf(stderr, "  (%s seed %s: %.0f m route, %zu scans, generated in %.1f s)\n", sim.plan.name.c_str(),
                     seed_text.c_str(), sim.route.length, sim.scans.size(), gen_s);
      }
    }
  } catch (const std::exception& e) {
    std::fprintf(stderr, "bench_sim_building: %s\n", e.what());
    return 1;
  }
  std::printf("runs whose long relations are worse than their odometry's: %d of %d\n", worse, runs);
  return 0;
}
