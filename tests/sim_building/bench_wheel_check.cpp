// bench_wheel_check — sensitivity of the wheels' veto on laser odometry
// (wheel_check.hpp) to its two settings, on generated buildings logged as a
// real ROBOTLASER1 log (preset robotlaser_logged). Not a CTest test: run by
// hand on a Release build,
//
//   build/bin/bench_wheel_check [--plans ring,ladder,l_ring] [--seeds 1,2] [--length-m 0]
//                               [--gates 0,16.27,25.9,50,100] [--gap-factors 10] [--gap-probability 0.01]
//
// For each building it prints, per (gate, gap factor), the increments kept as
// matched / failed / across gaps / contradicted by the wheels, and the
// per-increment translation error against the truth off the logging gaps
// (median, 95th, 99th percentile, worst) next to the wheels' own.
#include <CLI/CLI.hpp>
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <sstream>
#include <string>
#include <vector>

#include "building_log.hpp"
#include "carmen_log.hpp"
#include "logged_source.hpp"
#include "logging.hpp"

namespace {

using namespace mspace;
namespace fs = std::filesystem;
namespace sm = mspace::scan_matching;

std::vector<double> numbers(const std::string& text) {
  std::vector<double> out;
  std::stringstream s(text);
  for (std::string item; std::getline(s, item, ',');)
    if (!item.empty()) out.push_back(std::stod(item));
  return out;
}

double quantile(std::vector<double> v, double q) {
  std::sort(v.begin(), v.end());
  return v.empty() ? 0.0 : v[static_cast<std::size_t>(q * static_cast<double>(v.size() - 1))];
}

}  // namespace

int main(int argc, char** argv) {
  std::string plans = "ring,ladder,l_ring", seeds = "1,2", gates = "0,16.27,25.9,50,100", gap_factors = "10";
  double length = 0.0, gap_probability = 0.01;
  CLI::App app{"sensitivity of the wheels' check of laser odometry"};
  app.add_option("--plans", plans)->capture_default_str();
  app.add_option("--seeds", seeds)->capture_default_str();
  app.add_option("--length-m", length, "route length before the final lap")->capture_default_str();
  app.add_option("--gates", gates, "scan_match_wheel_gate values")->capture_default_str();
  app.add_option("--gap-factors", gap_factors, "scan_match_gap_factor values")->capture_default_str();
  app.add_option("--gap-probability", gap_probability, "the preset's chance per scan of a 1-4 min gap")
      ->capture_default_str();
  CLI11_PARSE(app, argc, argv);
  kernel::set_log_level(LogLevel::Error);
  std::stringstream plan_list(plans);
  for (std::string plan; std::getline(plan_list, plan, ',');)
    for (const double seed : numbers(seeds)) {
      sim_building::GeneratorSettings settings;
      settings.plan = plan;
      settings.world_seed = settings.seed = static_cast<std::uint64_t>(seed);
      settings.route.length_m = length;
      settings.laser = sim_building::laser_preset("robotlaser_logged");
      settings.laser.gap_probability = gap_probability;
      const sim_building::Simulation sim = sim_building::simulate(settings);
      const fs::path dir = fs::temp_directory_path() / ("bench_wheel_check_" + plan + "_" + std::to_string(settings.seed));
      sim_building::write_data_set(sim, dir);
      std::vector<bool> gap(sim.scans.size(), false);
      for (std::size_t k = 1; k < sim.scans.size(); ++k)
        gap[k] = sim.time(sim.scans[k].sample) - sim.time(sim.scans[k - 1].sample) > 20.0 * settings.laser.interval;
      auto errors = [&](const std::string& odometry, double gate, double factor, std::vector<std::size_t>* counts) {
        const PluginArgs a = test_logged::source_args(dir, odometry, gate, factor);
        const carmen_log::CarmenLogSource source(a);
        const auto& scans = source.contents().scans;
        std::vector<double> e;
        for (std::size_t k = 1; k < scans.size(); ++k) {
          if (gap[k]) continue;
          const Eigen::Vector3d o = carmen_log::odometry_increment(scans[k - 1].odometry, scans[k].odometry);
          const Eigen::Vector3d g = carmen_log::odometry_increment(*scans[k - 1].ground_truth, *scans[k].ground_truth);
          e.push_back((o - g).head<2>().norm());
        }
        if (counts)
          for (const sm::IncrementSource s : {sm::IncrementSource::matched, sm::IncrementSource::failed,
                                              sm::IncrementSource::gap, sm::IncrementSource::inconsistent})
            counts->push_back(source.wheel_check().count(s));
        return std::vector<double>{quantile(e, 0.5), quantile(e, 0.95), quantile(e, 0.99), quantile(e, 1.0)};
      };
      const std::vector<double> w = errors("wheel", 0.0, 0.0, nullptr);
      std::printf("%s %d: %zu scans, %zu across gaps | wheels median %.4f p95 %.4f p99 %.4f worst %.3f m\n",
                  plan.c_str(), static_cast<int>(seed), sim.scans.size(),
                  static_cast<std::size_t>(std::count(gap.begin(), gap.end(), true)), w[0], w[1], w[2], w[3]);
      for (const double factor : numbers(gap_factors))
        for (const double gate : numbers(gates)) {
          std::vector<std::size_t> c;
          const std::vector<double> l = errors("scan_matched", gate, factor, &c);
          std::printf("  gate %6.2f gap factor %4.1f | matched %4zu failed %3zu gap %3zu inconsistent %3zu | median "
                      "%.4f p95 %.4f p99 %.4f worst %.3f m\n",
                      gate, factor, c[0], c[1], c[2], c[3], l[0], l[1], l[2], l[3]);
          std::fflush(stdout);
        }
    }
  return 0;
}
