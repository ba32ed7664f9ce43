#include "run_request.hpp"

#include "default_config.hpp"
#include "logging.hpp"
#include "plugin_registry.hpp"

namespace mspace::kernel {
namespace {

/// The request's map and mode over the YAML's map section.
void apply_map_request(RunConfig& config, const RunRequest& r) {
  if (!r.map.empty()) {
    config.map.load = r.map;
    // A map given on the command line alone is one to localize in.
    if (r.mode.empty() && config.map.mode == MapConfig::Mode::Mapping) config.map.mode = MapConfig::Mode::Localize;
  }
  if (!r.mode.empty()) {
    bool known = false;
    for (auto mode : {MapConfig::Mode::Mapping, MapConfig::Mode::Localize, MapConfig::Mode::Extend})
      if (r.mode == map_mode_name(mode)) {
        config.map.mode = mode;
        known = true;
      }
    if (!known) throw ConfigError("--mode: '" + r.mode + "' is not one of: mapping, localize, extend");
  }
  const std::string problem = map_config_problem(config.map);
  if (!problem.empty())
    throw ConfigError(config.file.string() + " with --map / --mode: map: " + problem);
}

/// --seed on a run none of whose plugins draws random numbers changes
/// nothing: say so rather than let the user believe the runs differ.
void warn_if_nothing_seeded(const RunConfig& config) {
  std::vector<const InstanceConfig*> all = {&config.source, &config.motion, &config.estimator};
  for (const InstanceConfig& f : config.features) all.push_back(&f);
  for (const SensorConfig& s : config.sensors) all.push_back(&s.extractor);
  for (const InstanceConfig* instance : all)
    if (instance->params.has("seed")) return;
  std::string plugins;
  for (const InstanceConfig* instance : all) plugins += (plugins.empty() ? "" : ", ") + instance->plugin;
  kernel_log().warn("--seed ", *config.seed, ": no plugin of this run has a seed parameter (", plugins,
                    "); it changes nothing, the run is deterministic as it is");
}

}  // namespace

void apply_frames_option(RunConfig& config, long long every) {
  // 0 is output.frames' "none"; on the command line an option asked for
  // frames, so 0 is as wrong as a negative count.
  if (every < 1)
    throw ConfigError("--frames: " + std::to_string(every) +
                      " is not a number of steps between frames; give N >= 1 (or leave --frames out for none)");
  config.output.frames = every;
}

RunConfig resolve_run_request(const RunRequest& r, PluginRegistry& registry) {
  const bool map_given = !r.map.empty() || !r.mode.empty();  // apply_map_request checks the map section then
  const auto read = [&](const std::vector<std::string>& sets, const std::string& estimator) {
    return r.config_file.empty()
               ? parse_config(default_config_text(), default_config_name(), registry, sets, map_given, estimator)
               : load_config(r.config_file, registry, sets, map_given, estimator);
  };
  if (!r.estimator.empty()) {
    // --estimator goes in before the --set overrides, so that --set
    // estimator.KEY=VALUE sets a key of the estimator the run will use. The
    // plugin is checked first (with the file's plugin_path), so that a wrong
    // name is reported as the --estimator's.
    std::vector<std::string> others;
    for (const std::string& set : r.sets)
      if (set.rfind("estimator.", 0) != 0) others.push_back(set);
    for (const auto& dir : read(others, {}).plugin_path) registry.add_search_dir(dir);
    check_estimator_plugin(r.estimator, registry);
  }
  RunConfig config = read(r.sets, r.estimator);
  for (const auto& dir : config.plugin_path) registry.add_search_dir(dir);
  set_log_level(parse_log_level(r.log_level.empty() ? config.log_level : r.log_level));
  if (!r.output_dir.empty()) config.output.dir = r.output_dir;
  if (r.max_steps > 0) config.max_steps = r.max_steps;
  if (r.checkpoint_every) config.checkpoint_every = *r.checkpoint_every;
  if (r.frames) apply_frames_option(config, *r.frames);
  if (r.seed) config.seed = *r.seed;
  apply_run_seed(config);
  if (r.seed) warn_if_nothing_seeded(config);
  apply_map_request(config, r);
  return config;
}

std::string describe_run(const RunConfig& config) {
  std::string text = config.file.string() + ": source " + config.source.plugin + ", motion " +
                     config.motion.plugin + ", estimator " + config.estimator.plugin + ", features";
  for (const InstanceConfig& f : config.features) text += " " + f.instance + " (" + f.plugin + ")";
  text += ", sensors";
  for (const SensorConfig& s : config.sensors) text += " " + s.name + " (" + s.extractor.plugin + ")";
  return text;
}

}  // namespace mspace::kernel
