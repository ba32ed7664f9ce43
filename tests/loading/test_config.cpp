// Run configuration: parsing, validation against plugin descriptors, error
// messages with file:line:col and dotted keys, environment variables and the
// effective-configuration round trip. Uses only the fixture plugins.
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <numbers>
#include <string>

#include <gtest/gtest.h>

#include "build_path.hpp"
#include "config.hpp"

namespace fs = std::filesystem;
using mspace::kernel::ConfigError;
using mspace::kernel::PluginRegistry;
using mspace::kernel::RunConfig;

namespace {

const fs::path kFixtureDir = MSPACE_FIXTURE_DIR;

// Line numbers in the expected messages below refer to this text.
const std::string kBase = R"(run:
  name: t1
source:
  plugin: stub_source
  data: /data/run.log
motion:
  plugin: stub_motion
estimator:
  plugin: stub_estimator
features:
  points:
    plugin: stub_feature
    weight: 0.25
sensors:
  laser:
    mount: [0.1, 0, 0.5, 90, 0, 0]
    extractor:
      plugin: good
      gain: 2
    feeds: [points]
)";

/// kBase with the one occurrence of `from` replaced by `to`.
std::string edited(const std::string& from, const std::string& to, std::string text = kBase) {
  const std::size_t at = text.find(from);
  EXPECT_NE(at, std::string::npos) << from;
  EXPECT_EQ(text.find(from, at + 1), std::string::npos) << from << " occurs twice";
  if (at != std::string::npos) text.replace(at, from.size(), to);
  return text;
}

RunConfig parse(const std::string& text) {
  PluginRegistry registry;
  registry.add_search_dir(kFixtureDir);
  return mspace::kernel::parse_config(text, "test.yaml", registry);
}

/// The ConfigError message parsing `text` gives ("" if it parses).
std::string config_error(const std::string& text) {
  try {
    parse(text);
  } catch (const ConfigError& e) {
    return e.what();
  }
  ADD_FAILURE() << "expected a ConfigError for:\n" << text;
  return "";
}

}  // namespace

TEST(Config, ParsesAValidRunAndFillsInDefaults) {
  const RunConfig c = parse(kBase);
  EXPECT_EQ(c.file, "test.yaml");
  EXPECT_EQ(c.name, "t1");
  EXPECT_EQ(c.log_level, "info");
  EXPECT_EQ(c.max_steps, 0);
  EXPECT_FALSE(c.seed.has_value());

  EXPECT_EQ(c.source.instance, "source");
  EXPECT_EQ(c.source.plugin, "stub_source");
  EXPECT_EQ(c.source.where, "test.yaml:3");
  EXPECT_EQ(c.source.params.get_string("data"), "/data/run.log");
  EXPECT_EQ(c.source.params.get_double("weight"), 1.0);
  EXPECT_EQ(c.motion.plugin, "stub_motion");
  EXPECT_EQ(c.estimator.plugin, "stub_estimator");

  ASSERT_EQ(c.features.size(), 1u);
  EXPECT_EQ(c.features[0].instance, "points");
  EXPECT_EQ(c.features[0].where, "test.yaml:11");
  EXPECT_EQ(c.features[0].params.get_double("weight"), 0.25);

  ASSERT_EQ(c.sensors.size(), 1u);
  const mspace::kernel::SensorConfig& s = c.sensors[0];
  EXPECT_EQ(s.name, "laser");
  EXPECT_EQ(s.channel, "laser");
  EXPECT_EQ(s.mount[0], 0.1);
  EXPECT_EQ(s.mount[2], 0.5);
  EXPECT_DOUBLE_EQ(s.mount[3], std::numbers::pi / 2);  // degrees in YAML, radians inside
  EXPECT_EQ(s.extractor.instance, "laser");
  EXPECT_EQ(s.extractor.plugin, "good");
  // "gain: 2" is an int in YAML, accepted for a double parameter and stored as a double.
  EXPECT_TRUE(std::holds_alternative<double>(s.extractor.params.values().at("gain")));
  EXPECT_EQ(s.extractor.params.get_double("gain"), 2.0);
  EXPECT_EQ(s.extractor.params.get_int("count"), 3);
  EXPECT_EQ(s.extractor.params.get_bool("verbose"), false);
  EXPECT_EQ(s.extractor.params.get_string("mode"), "fast");
  EXPECT_EQ(s.extractor.params.get_list("offset"), (std::vector<double>{0.0, 0.0}));
  EXPECT_EQ(s.extractor.params.get_string("label"), "none");
  EXPECT_EQ(s.feeds, std::vector<std::string>{"points"});

  EXPECT_EQ(c.association.gate_probability, 0.99);
  EXPECT_EQ(c.association.new_feature_probability, 0.9999);
  EXPECT_EQ(c.association.tentative_max_age, 20);
  EXPECT_EQ(c.initial_pose, mspace::Pose6::Zero());
  EXPECT_EQ(c.initial_sigma, mspace::Pose6::Zero());
  EXPECT_EQ(c.output.dir, "out/t1");
  EXPECT_TRUE(c.output.trajectory && c.output.map && c.output.summary && c.output.picture);
  EXPECT_EQ(c.output.picture_size, 1000);
}

TEST(Config, RunNameDefaultsToTheFileStem) {
  PluginRegistry registry;
  registry.add_search_dir(kFixtureDir);
  const RunConfig c =
      mspace::kernel::parse_config(edited("  name: t1\n", "  max_steps: 5\n"), "config/victoria.yaml", registry);
  EXPECT_EQ(c.name, "victoria");
  EXPECT_EQ(c.max_steps, 5);
  EXPECT_EQ(c.output.dir, "out/victoria");
}

TEST(Config, MalformedYamlReportsFileLineAndColumn) {
  EXPECT_EQ(config_error(edited("    feeds: [points]\n", "    feeds: [points\n")),
            "test.yaml:21:1: YAML syntax error: end of sequence flow not found");
  EXPECT_EQ(config_error("run:\n  name: a\n   bad: 1\n"), "test.yaml:3:7: YAML syntax error: illegal map value");
}

TEST(Config, EmptyOrNonMapDocumentIsAnError) {
  EXPECT_EQ(config_error(""), "test.yaml:1:1: the configuration is empty");
  EXPECT_EQ(config_error("- a\n- b\n"),
            "test.yaml:1:1: the configuration must be a map of sections (run, source, motion, estimator, "
            "features, sensors, association, initial_pose, output, evaluation, map, problem)");
}

TEST(Config, UnknownKeysListTheAllowedOnes) {
  EXPECT_EQ(config_error(kBase + "outputs:\n  dir: x\n"),
            "test.yaml:21:1: outputs: unknown key (allowed: run, source, motion, estimator, features, sensors, "
            "association, initial_pose, output, evaluation, map, problem)");
  EXPECT_EQ(config_error(edited("    mount:", "    mounts:")),
            "test.yaml:16:5: sensors.laser.mounts: unknown key (allowed: channel, mount, extractor, feeds, max_range, silent_readings)");
  EXPECT_EQ(config_error(edited("  name: t1\n", "  name: t1\n  speed: 3\n")),
            "test.yaml:3:3: run.speed: unknown key (allowed: name, log_level, max_steps, checkpoint_every, "
            "health_check_every, plugin_path, seed, skip_steps)");
}

TEST(Config, DuplicateKeyIsAnError) {
  EXPECT_EQ(config_error(edited("      gain: 2\n", "      gain: 2\n      gain: 3\n")),
            "test.yaml:20:7: sensors.laser.extractor.gain: duplicate key");
}

TEST(Config, MissingSectionOrKeyIsNamed) {
  EXPECT_EQ(config_error(edited("estimator:\n  plugin: stub_estimator\n", "")),
            "test.yaml:1:1: estimator: missing required key");
  EXPECT_EQ(config_error(edited("    mount: [0.1, 0, 0.5, 90, 0, 0]\n", "")),
            "test.yaml:15:3: sensors.laser.mount: missing required key");
  EXPECT_EQ(config_error(edited("  plugin: stub_motion\n", "  weight: 0.5\n")),
            "test.yaml:6:1: motion.plugin: missing required key");
}

TEST(Config, UnknownParameterListsThePluginsParameters) {
  EXPECT_EQ(config_error(edited("      gain: 2", "      gian: 2")),
            "test.yaml:19:7: sensors.laser.extractor.gian: unknown parameter of plugin 'good' (its parameters: "
            "gain, count, verbose, mode, offset, label)");
}

TEST(Config, MissingRequiredParameter) {
  EXPECT_EQ(config_error(edited("  data: /data/run.log\n", "")),
            "test.yaml:3:1: source.data: missing required parameter of plugin 'stub_source' (data file)");
}

TEST(Config, OutOfRangeValueShowsTheRange) {
  EXPECT_EQ(config_error(edited("      gain: 2", "      gain: 20")),
            "test.yaml:19:13: sensors.laser.extractor.gain: 20 is out of range [0, 10] (plugin 'good')");
  EXPECT_EQ(config_error(edited("      gain: 2", "      gain: 2\n      count: 0")),
            "test.yaml:20:14: sensors.laser.extractor.count: 0 is out of range [1, 100] (plugin 'good')");
  EXPECT_EQ(config_error(edited("    weight: 0.25", "    weight: -0.5")),
            "test.yaml:13:13: features.points.weight: -0.5 is out of range [0, 1] (plugin 'stub_feature')");
}

TEST(Config, WrongTypeIsNamed) {
  EXPECT_EQ(config_error(edited("      gain: 2", "      gain: 2\n      count: 2.5")),
            "test.yaml:20:14: sensors.laser.extractor.count: expected an integer, got '2.5' (plugin 'good')");
  EXPECT_EQ(config_error(edited("      gain: 2", "      gain: fast")),
            "test.yaml:19:13: sensors.laser.extractor.gain: expected a number, got 'fast' (plugin 'good')");
  EXPECT_EQ(config_error(edited("      gain: 2", "      gain: [2]")),
            "test.yaml:19:13: sensors.laser.extractor.gain: expected a number, got a list (plugin 'good')");
  EXPECT_EQ(config_error(edited("      gain: 2", "      verbose: maybe")),
            "test.yaml:19:16: sensors.laser.extractor.verbose: expected true or false, got 'maybe' (plugin 'good')");
  EXPECT_EQ(config_error(edited("      gain: 2", "      label: [a]")),
            "test.yaml:19:14: sensors.laser.extractor.label: expected a string, got a list (plugin 'good')");
}

TEST(Config, StringChoicesAndListsAreChecked) {
  EXPECT_EQ(config_error(edited("      gain: 2", "      mode: medium")),
            "test.yaml:19:13: sensors.laser.extractor.mode: 'medium' is not one of: fast, slow (plugin 'good')");
  EXPECT_EQ(config_error(edited("      gain: 2", "      offset: [1, 2, 3]")),
            "test.yaml:19:15: sensors.laser.extractor.offset: expected a list of 2 numbers, got 3 (plugin 'good')");
  EXPECT_EQ(config_error(edited("      gain: 2", "      offset: [1, 9]")),
            "test.yaml:19:19: sensors.laser.extractor.offset[1]: 9 is out of range [-5, 5] (plugin 'good')");
  const RunConfig c = parse(edited("      gain: 2", "      mode: slow\n      offset: [-1, 2.5]"));
  EXPECT_EQ(c.sensors[0].extractor.params.get_string("mode"), "slow");
  EXPECT_EQ(c.sensors[0].extractor.params.get_list("offset"), (std::vector<double>{-1.0, 2.5}));
}

TEST(Config, UnknownPluginListsTheKnownOnes) {
  EXPECT_EQ(config_error(edited("    plugin: stub_feature", "    plugin: nope")),
            "test.yaml:12:13: features.points.plugin: unknown plugin 'nope'; known plugins: badabi, good, misnamed, "
            "notaplugin, otherheap, stub_estimator, stub_feature, stub_motion, stub_source, throwing (searched: " +
                kFixtureDir.string() + ")");
}

TEST(Config, PluginOfTheWrongKindIsRefused) {
  EXPECT_EQ(config_error(edited("    plugin: stub_feature", "    plugin: good")),
            "test.yaml:12:13: features.points.plugin: plugin 'good' is an extractor, but a feature is needed here");
  EXPECT_EQ(config_error(edited("  plugin: stub_motion", "  plugin: stub_estimator")),
            "test.yaml:7:11: motion.plugin: plugin 'stub_estimator' is an estimator, but a motion_model is needed "
            "here");
}

TEST(Config, PluginThatFailsToLoadIsReportedAtItsKey) {
  const std::string message = config_error(edited("  plugin: stub_source", "  plugin: badabi"));
  EXPECT_EQ(message.rfind("test.yaml:4:11: source.plugin: plugin library '", 0), 0u) << message;
  EXPECT_NE(message.find("was built for SDK ABI 'mspace-sdk0/gcc4/cxx98/eigen3.2/align16'"), std::string::npos);
}

TEST(Config, FeedsMustNameFeatureInstances) {
  EXPECT_EQ(config_error(edited("    feeds: [points]", "    feeds: [points, walls]")),
            "test.yaml:20:21: sensors.laser.feeds[1]: unknown feature instance 'walls' (instances under features: "
            "points)");
  EXPECT_EQ(config_error(edited("    feeds: [points]", "    feeds: []")),
            "test.yaml:20:12: sensors.laser.feeds: a sensor must feed at least one feature instance");
}

TEST(Config, MountMustHaveSixNumbers) {
  EXPECT_EQ(config_error(edited("[0.1, 0, 0.5, 90, 0, 0]", "[0.1, 0, 90]")),
            "test.yaml:16:12: sensors.laser.mount: expected a list of 6 numbers, got 3");
  EXPECT_EQ(config_error(edited("[0.1, 0, 0.5, 90, 0, 0]", "[0.1, 0, 0.5, 90, x, 0]")),
            "test.yaml:16:30: sensors.laser.mount[4]: expected a number, got 'x'");
}

TEST(Config, InstanceNamesAreChecked) {
  EXPECT_EQ(config_error(edited("  laser:", "  laser.front:")),
            "test.yaml:15:3: sensors.laser.front: names may only use letters, digits, '_' and '-'");
}

TEST(Config, RunAndAssociationValuesAreChecked) {
  EXPECT_EQ(config_error(edited("  name: t1", "  name: t1\n  log_level: loud")),
            "test.yaml:3:14: run.log_level: unknown log level 'loud' (choose trace, debug, info, warn, error or off)");
  EXPECT_EQ(config_error(edited("  name: t1", "  max_steps: -1")),
            "test.yaml:2:14: run.max_steps: -1 is out of range [0, inf]");
  EXPECT_EQ(config_error(kBase + "association:\n  gate_probability: 1\n"),
            "test.yaml:22:21: association.gate_probability: 1 is out of range (0, 1)");
  EXPECT_EQ(config_error(kBase + "initial_pose:\n  sigma: [1, 1, 0, -2, 0, 0]\n"),
            "test.yaml:22:20: initial_pose.sigma[3]: -2 is out of range [0, inf]");
}

TEST(Config, AssociationMethodAndIndexKeys) {
  EXPECT_EQ(config_error(kBase + "association:\n  method: greedy\n"),
            "test.yaml:22:11: association.method: 'greedy' is not one of: nearest_neighbour, jcbb");
  EXPECT_EQ(config_error(kBase + "association:\n  jcbb_max_nodes: 0\n"),
            "test.yaml:22:19: association.jcbb_max_nodes: 0 is out of range [1, inf]");
  EXPECT_EQ(config_error(kBase + "association:\n  spatial_index: sometimes\n"),
            "test.yaml:22:18: association.spatial_index: expected true or false, got 'sometimes'");
  EXPECT_EQ(config_error(kBase + "association:\n  index_cell_size: -1\n"),
            "test.yaml:22:20: association.index_cell_size: -1 is out of range [0, inf]");
  const RunConfig defaults = parse(kBase);
  EXPECT_EQ(defaults.association.method, mspace::kernel::AssociationConfig::Method::NearestNeighbour);
  EXPECT_TRUE(defaults.association.spatial_index);
  const RunConfig c = parse(kBase + "association:\n  method: jcbb\n  jcbb_max_nodes: 500\n  spatial_index: false\n"
                                    "  index_cell_size: 2.5\n");
  EXPECT_EQ(c.association.method, mspace::kernel::AssociationConfig::Method::Jcbb);
  EXPECT_EQ(c.association.jcbb_max_nodes, 500);
  EXPECT_FALSE(c.association.spatial_index);
  EXPECT_EQ(c.association.index_cell_size, 2.5);
  const RunConfig again = parse(mspace::kernel::effective_config_yaml(c));
  EXPECT_EQ(again.association.method, mspace::kernel::AssociationConfig::Method::Jcbb);
  EXPECT_EQ(again.association.jcbb_max_nodes, 500);
  EXPECT_FALSE(again.association.spatial_index);
  EXPECT_EQ(again.association.index_cell_size, 2.5);
}

// The re-entry test is a joint compatibility search: asked for under nearest
// neighbour, the key is named; its scale round-trips through the effective
// configuration and is at least 1.
TEST(Config, TheReentryTestNeedsJointCompatibility) {
  EXPECT_EQ(config_error(kBase + "association:\n  reentry_joint_test: true\n"),
            "test.yaml:22:23: association.reentry_joint_test: needs method: jcbb (the test is a joint compatibility "
            "search)");
  EXPECT_EQ(config_error(kBase + "association:\n  method: jcbb\n  reentry_covariance_scale: 0.5\n"),
            "test.yaml:23:29: association.reentry_covariance_scale: 0.5 is out of range [1, 100]");
  const RunConfig c =
      parse(kBase + "association:\n  method: jcbb\n  reentry_joint_test: true\n  reentry_covariance_scale: 3\n");
  EXPECT_TRUE(c.association.reentry_joint_test);
  EXPECT_EQ(c.association.reentry_covariance_scale, 3.0);
  const RunConfig again = parse(mspace::kernel::effective_config_yaml(c));
  EXPECT_TRUE(again.association.reentry_joint_test);
  EXPECT_EQ(again.association.reentry_covariance_scale, 3.0);
  EXPECT_FALSE(parse(kBase).association.reentry_joint_test);  // off by default
  EXPECT_EQ(parse(kBase).association.reentry_covariance_scale, 2.0);
}

// The wider second search is reckoned from the travel since each old feature
// was last seen, which only loop_revisit_window keeps: asked for without it,
// the key is named (not silently ignored).
TEST(Config, TheWideLoopWindowNeedsTheRevisitWindow) {
  EXPECT_EQ(config_error(kBase + "association:\n  loop_closing: true\n  loop_wide_drift_per_metre: 0.025\n"),
            "test.yaml:23:30: association.loop_wide_drift_per_metre: needs loop_revisit_window: true (the wider "
            "window is reckoned from the travel since each old feature was last seen)");
  EXPECT_EQ(config_error(kBase + "association:\n  loop_wide_drift_per_metre: 2\n"),
            "test.yaml:22:30: association.loop_wide_drift_per_metre: 2 is out of range [0, 1]");
  const RunConfig c = parse(kBase + "association:\n  loop_closing: true\n  loop_revisit_window: true\n"
                                    "  loop_wide_drift_per_metre: 0.025\n");
  EXPECT_EQ(c.association.loop_wide_drift_per_metre, 0.025);
  EXPECT_EQ(parse(mspace::kernel::effective_config_yaml(c)).association.loop_wide_drift_per_metre, 0.025);
  EXPECT_EQ(parse(kBase).association.loop_wide_drift_per_metre, 0.0);  // off by default
}

TEST(Config, EnvironmentVariablesAreExpandedInStrings) {
  ASSERT_EQ(setenv("MSPACE_TEST_DATA", "/mnt/data", 1), 0);
  unsetenv("MSPACE_TEST_UNSET_VAR");
  const RunConfig c = parse(edited("  data: /data/run.log", "  data: ${MSPACE_TEST_DATA}/run.log") +
                            "output:\n  dir: ${MSPACE_TEST_UNSET_VAR:-/tmp/out}/${MSPACE_TEST_DATA:-x}\n");
  EXPECT_EQ(c.source.params.get_string("data"), "/mnt/data/run.log");
  EXPECT_EQ(c.output.dir, "/tmp/out//mnt/data");
  EXPECT_EQ(config_error(edited("  data: /data/run.log", "  data: ${MSPACE_TEST_UNSET_VAR}/run.log")),
            "test.yaml:5:9: source.data: environment variable 'MSPACE_TEST_UNSET_VAR' is not set (write "
            "${MSPACE_TEST_UNSET_VAR:-default} to give a default) (plugin 'stub_source')");
  unsetenv("MSPACE_TEST_DATA");
}

TEST(Config, EnvironmentVariablesGiveNumbersIntegersAndBools) {
  ASSERT_EQ(setenv("MSPACE_TEST_WEIGHT", "0.5", 1), 0);
  ASSERT_EQ(setenv("MSPACE_TEST_INDEX", "false", 1), 0);
  ASSERT_EQ(setenv("MSPACE_TEST_BAD", "lots", 1), 0);
  unsetenv("MSPACE_TEST_NODES");
  const RunConfig c = parse(edited("    weight: 0.25", "    weight: ${MSPACE_TEST_WEIGHT}") +
                            "association:\n  jcbb_max_nodes: ${MSPACE_TEST_NODES:-300}\n"
                            "  spatial_index: ${MSPACE_TEST_INDEX}\n");
  EXPECT_EQ(c.features[0].params.get_double("weight"), 0.5);  // a plugin parameter
  EXPECT_EQ(c.association.jcbb_max_nodes, 300);                // an integer, from the default
  EXPECT_FALSE(c.association.spatial_index);                   // a bool
  // A value that is no number names the key, the text and where it came from.
  const std::string bad = config_error(edited("    weight: 0.25", "    weight: ${MSPACE_TEST_BAD}"));
  EXPECT_NE(bad.find("test.yaml:13:13: features.points.weight: expected a number, got 'lots' (from "
                     "'${MSPACE_TEST_BAD}')"),
            std::string::npos)
      << bad;
  EXPECT_EQ(config_error(kBase + "association:\n  jcbb_max_nodes: ${MSPACE_TEST_NODES}\n"),
            "test.yaml:22:19: association.jcbb_max_nodes: environment variable 'MSPACE_TEST_NODES' is not set "
            "(write ${MSPACE_TEST_NODES:-default} to give a default)");
  // Range checks apply to the expanded value.
  ASSERT_EQ(setenv("MSPACE_TEST_NODES", "0", 1), 0);
  EXPECT_EQ(config_error(kBase + "association:\n  jcbb_max_nodes: ${MSPACE_TEST_NODES}\n"),
            "test.yaml:22:19: association.jcbb_max_nodes: 0 is out of range [1, inf]");
  for (const char* var : {"MSPACE_TEST_WEIGHT", "MSPACE_TEST_INDEX", "MSPACE_TEST_BAD", "MSPACE_TEST_NODES"})
    unsetenv(var);
}

TEST(Config, SetOverridesAnyKeyAndIsCheckedLikeTheFile) {
  PluginRegistry registry;
  registry.add_search_dir(kFixtureDir);
  auto parse_with = [&](const std::vector<std::string>& sets) {
    return mspace::kernel::parse_config(kBase, "test.yaml", registry, sets);
  };
  // A plugin parameter, a kernel key, and a section the file does not have.
  const RunConfig c = parse_with({"features.points.weight=0.75", "sensors.laser.extractor.gain=4",
                                  "run.name=overridden", "association.jcbb_max_nodes=77"});
  EXPECT_EQ(c.features[0].params.get_double("weight"), 0.75);
  EXPECT_EQ(c.sensors[0].extractor.params.get_double("gain"), 4.0);
  EXPECT_EQ(c.name, "overridden");
  EXPECT_EQ(c.association.jcbb_max_nodes, 77);
  // Errors name the --set, the key and the problem, like the file's.
  auto error_of = [&](const std::vector<std::string>& sets) {
    try {
      parse_with(sets);
    } catch (const mspace::kernel::ConfigError& e) {
      return std::string(e.what());
    }
    return std::string("no error");
  };
  EXPECT_EQ(error_of({"association.jcbb_max_nodes=0"}),
            "--set association.jcbb_max_nodes=0: association.jcbb_max_nodes: 0 is out of range [1, inf]");
  EXPECT_EQ(error_of({"features.points.weight=heavy"}),
            "--set features.points.weight=heavy: features.points.weight: expected a number, got 'heavy' "
            "(plugin 'stub_feature')");
  EXPECT_NE(error_of({"features.points.wieght=1"}).find("--set features.points.wieght=1: features.points.wieght: "
                                                        "unknown parameter"),
            std::string::npos)
      << error_of({"features.points.wieght=1"});
  EXPECT_EQ(error_of({"features.points.weight"}),
            "--set features.points.weight: expected KEY=VALUE, e.g. features.points.min_observations=5");
  EXPECT_EQ(error_of({"run.name.first=x"}), "--set run.name.first=x: 'name' is 't1', not a map of keys");
}

TEST(Config, ExpandEnvVars) {
  using mspace::kernel::expand_env_vars;
  ASSERT_EQ(setenv("MSPACE_TEST_A", "alpha", 1), 0);
  ASSERT_EQ(setenv("MSPACE_TEST_EMPTY", "", 1), 0);
  EXPECT_EQ(expand_env_vars("no variables, $5 and $HOME stay"), "no variables, $5 and $HOME stay");
  EXPECT_EQ(expand_env_vars("${MSPACE_TEST_A}/${MSPACE_TEST_A}"), "alpha/alpha");
  EXPECT_EQ(expand_env_vars("${MSPACE_TEST_A:-beta}"), "alpha");
  EXPECT_EQ(expand_env_vars("${MSPACE_TEST_EMPTY:-beta}"), "beta");  // as in the shell: empty uses the default
  EXPECT_EQ(expand_env_vars("${MSPACE_TEST_EMPTY}"), "");
  EXPECT_EQ(expand_env_vars("x${MSPACE_TEST_NOPE:-}y"), "xy");
  EXPECT_THROW(expand_env_vars("${MSPACE_TEST_A"), std::invalid_argument);
  EXPECT_THROW(expand_env_vars("${MSPACE_TEST_NOPE}"), std::invalid_argument);
  unsetenv("MSPACE_TEST_A");
  unsetenv("MSPACE_TEST_EMPTY");
}

TEST(Config, RunPluginPathIsSearched) {
  PluginRegistry registry;  // no directories of its own
  const RunConfig c = mspace::kernel::parse_config(
      edited("  name: t1\n", "  name: t1\n  plugin_path: [" + kFixtureDir.string() + "]\n"), "test.yaml", registry);
  EXPECT_EQ(c.plugin_path, std::vector<std::string>{kFixtureDir.string()});
  EXPECT_EQ(registry.search_dirs(), std::vector<fs::path>{kFixtureDir});
}

TEST(Config, LoadConfigReadsAFile) {
  const fs::path file = fs::temp_directory_path() / "mspace_test_load_config.yaml";
  {
    std::ofstream out(file);
    out << kBase;
  }
  PluginRegistry registry;
  registry.add_search_dir(kFixtureDir);
  const RunConfig c = mspace::kernel::load_config(file, registry);
  EXPECT_EQ(c.file, file);
  EXPECT_EQ(c.sensors[0].extractor.where, file.string() + ":17");
  fs::remove(file);
  try {
    mspace::kernel::load_config(file, registry);
    ADD_FAILURE() << "expected a ConfigError";
  } catch (const ConfigError& e) {
    EXPECT_EQ(std::string(e.what()), file.string() + ": no such file");
  }
  try {
    mspace::kernel::load_config(file.parent_path(), registry);
    ADD_FAILURE() << "expected a ConfigError";
  } catch (const ConfigError& e) {
    EXPECT_EQ(std::string(e.what()), file.parent_path().string() +
                                         ": is a directory, not a configuration file (e.g. config/sim_points.yaml)");
  }
}

TEST(Config, EffectiveYamlRoundTrips) {
  const std::string full = edited("  name: t1\n", "  name: t1\n  seed: 42\n  max_steps: 7\n  log_level: debug\n") +
                           "association:\n  gate_probability: 0.95\n  tentative_max_age: 5\n"
                           "initial_pose:\n  pose: [1, 2, 0, 30, 0, 0]\n  sigma: [0.1, 0.1, 0, 1.5, 0, 0]\n"
                           "output:\n  dir: results/x\n  picture: false\n  picture_size: 640\n";
  const RunConfig first = parse(edited("      gain: 2", "      gain: 0.1\n      label: \"yes\"", full));
  const std::string yaml = mspace::kernel::effective_config_yaml(first);
  const RunConfig second = parse(yaml);
  // A second round gives the same text: nothing drifts.
  EXPECT_EQ(mspace::kernel::effective_config_yaml(second), yaml);

  EXPECT_EQ(second.name, "t1");
  EXPECT_EQ(second.seed, std::optional<std::int64_t>(42));
  EXPECT_EQ(second.max_steps, 7);
  EXPECT_EQ(second.log_level, "debug");
  EXPECT_EQ(second.source.params.values(), first.source.params.values());
  EXPECT_EQ(second.features[0].params.values(), first.features[0].params.values());
  EXPECT_EQ(second.sensors[0].extractor.params.values(), first.sensors[0].extractor.params.values());
  EXPECT_EQ(second.sensors[0].extractor.params.get_string("label"), "yes");  // stays a string
  EXPECT_EQ(second.sensors[0].extractor.params.get_double("gain"), 0.1);
  EXPECT_EQ(second.sensors[0].mount, first.sensors[0].mount);
  EXPECT_EQ(second.sensors[0].feeds, first.sensors[0].feeds);
  EXPECT_EQ(second.sensors[0].channel, "laser");
  EXPECT_EQ(second.association.gate_probability, 0.95);
  EXPECT_EQ(second.association.new_feature_probability, 0.9999);
  EXPECT_EQ(second.association.tentative_max_age, 5);
  EXPECT_EQ(second.initial_pose, first.initial_pose);
  EXPECT_EQ(second.initial_sigma, first.initial_sigma);
  EXPECT_DOUBLE_EQ(second.initial_pose[3], std::numbers::pi / 6);
  EXPECT_EQ(second.output.dir, "results/x");
  EXPECT_FALSE(second.output.picture);
  EXPECT_TRUE(second.output.map);
  EXPECT_EQ(second.output.picture_size, 640);
}
