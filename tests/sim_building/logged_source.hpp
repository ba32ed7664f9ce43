// logged_source.hpp — carmen_log on a generated building as config/intel_walls.yaml
// reads a log (the matcher's defaults, beams to 30 m), with the wheels' check
// set explicitly; shared by test_laser_fallback and bench_wheel_check.
#pragma once

#include <filesystem>
#include <string>

#include "carmen_log.hpp"
#include "mspace/params.hpp"

namespace mspace::test_logged {

/// The source's arguments for DIR/building.clf with ground truth DIR/ground_truth.tum.
inline PluginArgs source_args(const std::filesystem::path& dir, const std::string& odometry, double wheel_gate,
                              double gap_factor, bool wheel_model = true) {
  PluginArgs a;
  a.instance_name = "source";
  a.params = Params::defaults(carmen_log::CarmenLogSource::param_specs());
  a.params.set("file", (dir / "building.clf").string());
  a.params.set("ground_truth", (dir / "ground_truth.tum").string());
  a.params.set("odometry", odometry);
  a.params.set("scan_match_max_range", 30.0);  // as config/intel_walls.yaml
  a.params.set("scan_match_wheel_gate", wheel_gate);
  a.params.set("scan_match_gap_factor", gap_factor);
  a.params.set("scan_match_wheel_model", wheel_model);
  return a;
}

}  // namespace mspace::test_logged
