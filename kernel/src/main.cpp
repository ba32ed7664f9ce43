// mspace — the command line tool.
//
//   mspace run [CONFIG] [--out DIR]   a SLAM run (the built-in simulated world without CONFIG);
//              [--set KEY=VALUE]...   any configuration key overridden (also for `mspace config`)
//              [--frames N]           the map's picture every N steps (frames/, picture.cpp)
//   mspace run --resume DIR           continues a run from its checkpoint
//   mspace plugins                    every plugin found, with kind, ABI tag and parameters
//   mspace config [CONFIG]            the fully resolved configuration
//   mspace check PLUGIN... [--junit F] the plugin conformance suite (files or names); with an
//                                     extractor and a feature type also their pair check
//   mspace eval TRAJECTORY [--reference REF] [--relations FILE]
//                                     scores any trajectory file (TUM or `t x y theta`):
//                                     ATE and relations, all / short / long (eval_command.cpp)
#include <algorithm>
#include <cstdlib>
#include <filesystem>
#include <iostream>
#include <optional>
#include <sstream>
#include <string>
#include <vector>

#include <CLI/CLI.hpp>

#include "check.hpp"
#include "checkpoint.hpp"
#include "config.hpp"
#include "eval_command.hpp"
#include "logging.hpp"
#include "mspace/abi.hpp"
#include "plugin_registry.hpp"
#include "run_request.hpp"
#include "runner.hpp"
#include "slam.hpp"

namespace {

using namespace mspace;
using namespace mspace::kernel;

struct CommonOptions {
  std::vector<std::string> plugin_files;
  std::vector<std::string> plugin_dirs;
  std::string log_level;
};

void add_common(CLI::App* cmd, CommonOptions& o) {
  cmd->add_option("--plugin", o.plugin_files, "load this plugin library (repeatable)");
  cmd->add_option("--plugin-dir", o.plugin_dirs, "also search this folder for plugins (repeatable)");
  cmd->add_option("--log-level", o.log_level, "trace, debug, info, warn, error or off (overrides the YAML)");
}

void setup_registry(PluginRegistry& registry, const CommonOptions& o) {
  for (const auto& dir : o.plugin_dirs) registry.add_search_dir(dir);
  for (const auto& dir : PluginRegistry::default_search_dirs()) registry.add_search_dir(dir);
  for (const auto& file : o.plugin_files) registry.add_plugin_file(file);
}

struct RunCommand {
  std::string file, out, estimator, resume, map, mode;
  std::vector<std::string> sets;  ///< --set KEY=VALUE overrides of the configuration
  long long max_steps = 0;
  std::optional<long long> seed, checkpoint_every, frames;
  bool quiet = false;
};

/// Runs `slam` to its end and prints the summary; the exit code.
int run_and_report(Slam& slam, bool quiet) {
  RunOptions options;
  options.progress = !quiet;
  options.stop_on_signals = true;
  const RunResult result = run_to_end(slam, options);
  std::cout << format_summary(result.summary, slam);
  std::cout << "  outputs in " << result.output_dir.string() << "/ (";
  for (std::size_t i = 0; i < result.files.size(); ++i) std::cout << (i > 0 ? ", " : "") << result.files[i];
  std::cout << ")\n";
  if (result.frames) {
    const FramesReport& f = *result.frames;
    std::cout << "  " << f.written << " frame(s) of the map, every " << f.every << " steps and the last, in "
              << f.folder.string() << "/";
    if (f.written > 0) std::cout << " (" << f.first << " .. " << f.last << ")";
    std::ostringstream seconds;
    seconds.precision(3);
    seconds << f.seconds;
    std::cout << ", " << seconds.str() << " s to draw; "
              << (f.view_changes == 0 ? std::string("one view throughout")
                                      : "the view grew " + std::to_string(f.view_changes) +
                                            " time(s) to take in the map (the scale changes there)")
              << "\n";
  }
  if (result.checkpoints > 0)
    std::cout << "  " << result.checkpoints << " checkpoint(s) written, the last at "
              << checkpoint_dir(slam.config()).string() << "/ (" << result.checkpoint_bytes
              << " bytes); continue with: mspace run --resume " << checkpoint_dir(slam.config()).string() << "\n";
  return result.stop_signal != 0 ? 128 + result.stop_signal : 0;  // 130 for SIGINT, 143 for SIGTERM
}

/// `mspace run --resume DIR`: the configuration is the checkpoint's; only the
/// output folder, the step limit and the checkpoint interval may change.
int cmd_resume(const RunCommand& c, const CommonOptions& common) {
  if (!c.file.empty() || c.seed || !c.estimator.empty() || !c.sets.empty() || !c.map.empty() || !c.mode.empty())
    throw ConfigError(
        "--resume takes the configuration from the checkpoint: give no CONFIG, --seed, --set, --estimator, --map or "
        "--mode (only --out, --max-steps, --checkpoint-every, --frames and --log-level)");
  PluginRegistry registry;
  setup_registry(registry, common);
  std::unique_ptr<Slam> slam = resume_from_checkpoint(c.resume, registry, [&](RunConfig& config) {
    set_log_level(parse_log_level(common.log_level.empty() ? config.log_level : common.log_level));
    if (!c.out.empty()) config.output.dir = c.out;
    if (c.max_steps > 0) config.max_steps = c.max_steps;
    if (c.checkpoint_every) config.checkpoint_every = *c.checkpoint_every;
    if (c.frames) apply_frames_option(config, *c.frames);
  });
  kernel_log().info("resumed ", find_checkpoint_file(c.resume).string(), " (run ", slam->config().name, " of ",
                    slam->config().file.string(), ") at step ", slam->steps_done());
  return run_and_report(*slam, c.quiet);
}

int cmd_run(const RunCommand& c, const CommonOptions& common) {
  if (!c.resume.empty()) return cmd_resume(c, common);
  PluginRegistry registry;
  setup_registry(registry, common);
  RunRequest request;
  request.config_file = c.file;
  request.sets = c.sets;
  request.output_dir = c.out;
  request.estimator = c.estimator;
  request.map = c.map;
  request.mode = c.mode;
  request.log_level = common.log_level;
  request.max_steps = c.max_steps;
  request.seed = c.seed;
  request.checkpoint_every = c.checkpoint_every;
  request.frames = c.frames;
  const RunConfig config = resolve_run_request(request, registry);
  // One line of what runs; the whole resolved configuration at debug level
  // (or with `mspace config`).
  kernel_log().info("running ", describe_run(config));
  kernel_log().debug("configuration ", config.file.string(), ":\n", effective_config_yaml(config));
  Slam slam(config, registry);
  return run_and_report(slam, c.quiet);
}

int cmd_plugins(const CommonOptions& common) {
  PluginRegistry registry;
  setup_registry(registry, common);
  std::vector<std::string> errors;
  const auto plugins = registry.load_all(&errors);
  std::cout << "SDK ABI tag: " << MSPACE_ABI_TAG << "\n";
  std::cout << "searched: ";
  for (const auto& dir : registry.search_dirs()) std::cout << dir.string() << "  ";
  std::cout << "\n\n";
  for (const auto& p : plugins) {
    const PluginDescriptor& d = *p->descriptor;
    std::cout << d.name << "  [" << plugin_kind_name(d.kind) << "]  " << p->path.string() << "\n";
    std::cout << "    " << d.description << "\n";
    std::cout << "    ABI " << d.abi_tag << "\n";
    for (const ParamSpec& s : d.params) {
      std::cout << "    - " << s.name << " (" << param_type_name(s.type) << ")";
      if (s.required)
        std::cout << " required";
      else
        std::cout << " = " << format_param(s.default_value);
      if (std::isfinite(s.min) || std::isfinite(s.max)) std::cout << "  range [" << s.min << ", " << s.max << "]";
      if (!s.choices.empty()) {
        std::cout << "  one of:";
        for (const auto& c : s.choices) std::cout << ' ' << c;
      }
      std::cout << "\n        " << s.description << "\n";
    }
    std::cout << "\n";
  }
  for (const auto& e : errors) std::cerr << "error: " << e << "\n";
  return errors.empty() ? 0 : 1;
}

int cmd_config(const std::string& file, const std::vector<std::string>& sets, const CommonOptions& common) {
  PluginRegistry registry;
  setup_registry(registry, common);
  RunRequest request;
  request.config_file = file;
  request.sets = sets;
  request.log_level = common.log_level;
  const RunConfig config = resolve_run_request(request, registry);
  std::cout << effective_config_yaml(config);
  return 0;
}

/// Levenshtein distance, for "did you mean" on a mistyped subcommand.
std::size_t edit_distance(const std::string& a, const std::string& b) {
  std::vector<std::size_t> row(b.size() + 1);
  for (std::size_t j = 0; j <= b.size(); ++j) row[j] = j;
  for (std::size_t i = 1; i <= a.size(); ++i) {
    std::size_t diagonal = row[0];
    row[0] = i;
    for (std::size_t j = 1; j <= b.size(); ++j) {
      const std::size_t up = row[j];
      row[j] = std::min({row[j] + 1, row[j - 1] + 1, diagonal + (a[i - 1] == b[j - 1] ? 0 : 1)});
      diagonal = up;
    }
  }
  return row[b.size()];
}

/// A first argument that is neither an option nor a subcommand: the error
/// names it and the nearest subcommand.
std::optional<std::string> unknown_subcommand(int argc, char** argv, const std::vector<std::string>& known) {
  if (argc < 2 || argv[1][0] == '-') return std::nullopt;
  const std::string given = argv[1];
  if (std::find(known.begin(), known.end(), given) != known.end()) return std::nullopt;
  std::string best = known.front();
  for (const std::string& k : known)
    if (edit_distance(given, k) < edit_distance(given, best)) best = k;
  std::string message = "unknown command '" + given + "'";
  if (edit_distance(given, best) <= 2) message += "; did you mean '" + best + "'?";
  message += " (commands:";
  for (const std::string& k : known) message += " " + k;
  return message + "; see mspace --help)";
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{"mspace — feature-based SLAM on the M-space feature representation"};
  app.set_version_flag("--version", std::string("mspace 0.1.0, SDK ABI ") + MSPACE_ABI_TAG);
  app.require_subcommand(1);

  CommonOptions common;
  RunCommand run_cmd;
  CLI::App* run = app.add_subcommand("run", "run SLAM as a YAML file describes (the built-in simulated world without one)");
  run->add_option("config", run_cmd.file, "YAML run configuration");
  run->add_option("--out", run_cmd.out, "output folder (overrides output.dir)");
  run->add_option("--max-steps", run_cmd.max_steps, "stop after this many steps (counted from the start of the data)");
  run->add_option("--seed", run_cmd.seed, "seed for every plugin with a `seed` parameter (overrides run.seed)");
  run->add_option("--estimator", run_cmd.estimator,
                  "run this estimator plugin instead of the configuration's (e.g. ekf, cekf, smoother), with its "
                  "own default options; --set estimator.KEY=VALUE sets its keys");
  run->add_option("--checkpoint-every", run_cmd.checkpoint_every,
                  "write <out>/checkpoint/ every N steps, replacing the previous one atomically (overrides "
                  "run.checkpoint_every; 0 = none)")
      ->check(CLI::NonNegativeNumber);
  run->add_option("--frames", run_cmd.frames,
                  "every N steps (and after the last) write <out>/frames/frame_<step>.png, the map's picture as the run "
                  "goes, in one view, loop closures marked (overrides output.frames; N >= 1)");
  run->add_option("--resume", run_cmd.resume,
                  "continue the run saved in this checkpoint (a checkpoint folder, or a run's output folder); the "
                  "configuration is the checkpoint's");
  run->add_option("--set", run_cmd.sets,
                  "KEY=VALUE: override any configuration key, plugin parameters included, e.g. "
                  "features.points.min_observations=5 (repeatable; checked like the file's values)");
  run->add_option("--map", run_cmd.map,
                  "a saved map (a run's output folder or its map.bin) to localize in or extend (map.load); alone "
                  "it means --mode localize");
  run->add_option("--mode", run_cmd.mode, "mapping, localize or extend (map.mode; docs/maps.md)");
  run->add_flag("--quiet", run_cmd.quiet, "no progress output");
  add_common(run, common);

  CLI::App* plugins = app.add_subcommand("plugins", "list every plugin found with kind, ABI tag and parameters");
  add_common(plugins, common);

  std::string config_file;
  CLI::App* config = app.add_subcommand("config", "print the fully resolved configuration");
  config->add_option("config", config_file, "YAML run configuration (the built-in one without)");
  std::vector<std::string> config_sets;
  config->add_option("--set", config_sets, "KEY=VALUE: override any configuration key (repeatable)");
  add_common(config, common);

  CheckCommand check_cmd;
  CLI::App* check = app.add_subcommand("check", "run the conformance suite on plugin files or names");
  check->add_option("plugins", check_cmd.targets,
                    "plugin library files or registered names; each extractor is also checked with each feature "
                    "type given (their measurement conventions against true geometry)")
      ->required();
  check->add_option("--junit", check_cmd.junit_file, "also write JUnit XML to this file");
  check->add_option("--samples", check_cmd.samples, "random samples per check")->check(CLI::PositiveNumber);
  check->add_option("--seed", check_cmd.seed, "base seed of the samples");
  check->add_option("--param", check_cmd.params, "NAME=VALUE for the checked instances, e.g. a data file (repeatable)");
  add_common(check, common);

  EvalOptions eval_options;
  std::string eval_yaml;
  CLI::App* eval = app.add_subcommand(
      "eval", "score a trajectory file (TUM `t x y z qx qy qz qw` or `t x y theta`) against a reference trajectory "
              "(ATE, SE(2) alignment) and/or Kuemmerle relations (all, short and long)");
  eval->add_option("trajectory", eval_options.estimate, "the estimated trajectory")->required();
  eval->add_option("--reference", eval_options.reference, "reference trajectory for the ATE (TUM or `t x y theta`)");
  eval->add_option("--relations", eval_options.relations, "relations file: `t1 t2 x y z roll pitch yaw` per line");
  eval->add_option("--max-gap", eval_options.max_gap,
                   "ATE: do not interpolate the estimate between poses further apart than this (s)")
      ->capture_default_str()
      ->check(CLI::PositiveNumber);
  eval->add_option("--relations-max-dt", eval_options.relations_max_dt,
                   "relations: a stamp must be this close to an estimated pose (s)")
      ->capture_default_str()
      ->check(CLI::PositiveNumber);
  eval->add_option("--long", eval_options.long_seconds,
                   "relations at least this many seconds long are reported as the long ones")
      ->capture_default_str()
      ->check(CLI::PositiveNumber);
  eval->add_option("--yaml", eval_yaml, "also write the figures to this file as `key: value` lines");

  if (const auto unknown = unknown_subcommand(argc, argv, {"run", "plugins", "config", "check", "eval"})) {
    std::cerr << "mspace: error: " << *unknown << "\n";
    return 2;
  }
  CLI11_PARSE(app, argc, argv);
  try {
    if (run->parsed()) return cmd_run(run_cmd, common);
    if (plugins->parsed()) return cmd_plugins(common);
    if (config->parsed()) return cmd_config(config_file, config_sets, common);
    if (eval->parsed()) {
      const EvalResult result = evaluate_files(eval_options);
      print_eval(std::cout, result, eval_options);
      if (!eval_yaml.empty()) write_eval_yaml(eval_yaml, result, eval_options);
      return 0;
    }
    if (check->parsed()) {
      PluginRegistry registry;
      setup_registry(registry, common);
      return run_check(check_cmd, registry, std::cout);
    }
  } catch (const CheckUsageError& e) {
    std::cerr << "mspace: usage error: " << e.what() << "\n";
    return 2;
  } catch (const std::exception& e) {
    std::cerr << "mspace: error: " << e.what() << "\n";
    return 1;
  }
  return 0;
}
