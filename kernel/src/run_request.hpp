// run_request.hpp — what a user asks of one run (a configuration file and the
// overrides of the command line or of the Python module), resolved into the
// RunConfig a Slam is built from. `mspace run` and `import mspace` share it,
// so both accept the same overrides with the same checks and errors.
#pragma once

#include <optional>
#include <string>
#include <vector>

#include "config.hpp"

namespace mspace::kernel {

class PluginRegistry;

struct RunRequest {
  std::string config_file;           ///< YAML run configuration; empty: the built-in default
  std::vector<std::string> sets;     ///< KEY=VALUE overrides (--set), checked like the file's values
  std::string output_dir;            ///< overrides output.dir when not empty
  std::string estimator;             ///< another estimator plugin with its own default options
  std::string map, mode;             ///< --map DIR / --mode mapping|localize|extend (docs/maps.md)
  std::string log_level;             ///< overrides run.log_level when not empty
  long long max_steps = 0;           ///< 0: the whole data
  std::optional<long long> seed;     ///< overrides run.seed
  std::optional<long long> checkpoint_every;
  std::optional<long long> frames;   ///< --frames N: overrides output.frames; must be >= 1
};

/// --frames N into output.frames: ConfigError naming --frames unless N >= 1.
void apply_frames_option(RunConfig& config, long long every);

/// Loads the request's configuration (adding its plugin_path folders to
/// `registry`), applies every override, sets the log level and returns the
/// configuration to build a Slam from. ConfigError naming the file, line and
/// key (or the option) for anything wrong.
RunConfig resolve_run_request(const RunRequest& request, PluginRegistry& registry);

/// One line saying which file and plugins a run uses (logged at its start).
std::string describe_run(const RunConfig& config);

}  // namespace mspace::kernel
