// config.hpp — a run's YAML configuration, parsed and validated.
//
// Layout of a run file (every key is optional unless marked required):
//
//   run:          {name, log_level: info, max_steps: 0 (= all), checkpoint_every: 0 (steps; 0 = none),
//                  health_check_every: 0 (steps; 0 = at the end only), plugin_path: [dirs], seed,
//                  skip_steps: 0 (data steps discarded before the first)}
//   map:          {load: <map folder or map.bin>, mode: mapping | localize | extend,
//                  start: config | map_end}                                  # docs/maps.md
//   source:       {plugin: <name>, <parameters>}                        # required
//   motion:       {plugin: <name>, <parameters>}                        # required
//   estimator:    {plugin: <name>, <parameters>}                        # required
//   features:     {<instance>: {plugin: <name>, <parameters>}, ...}     # required, >= 1
//   sensors:                                                            # required, >= 1
//     <sensor>:
//       channel: <data channel, default = sensor name>
//       mount: [x, y, z, theta, phi, psi]   # required; x_rs, angles in degrees
//       extractor: {plugin: <name>, <parameters>}                       # required
//       feeds: [<feature instances>]                                    # required
//       max_range: 0 (m; features farther away are not associated; 0 = no limit)
//       silent_readings: 200 (warn when this many readings gave no measurement or no match; 0 = never)
//   association:  {gate_probability: 0.99, new_feature_probability: 0.9999, tentative_max_age: 20,
//                  join_distance: 0 (m; 0 = no shared coordinates),
//                  method: nearest_neighbour | jcbb, jcbb_max_nodes: 100000,
//                  spatial_index: true, index_cell_size: 0 (m; 0 = the largest sensor max_range)}
//   initial_pose: {pose: [6 numbers], sigma: [6 numbers]}               # angles in degrees, default 0
//                 or `search` (localize only: the pose is found in the loaded map)
//   output:       {dir: out/<run name>, trajectory, map, summary, picture: true, picture_size: 1000,
//                  frames: 0 (steps between pictures of the map as the run goes; 0 = none),
//                  map_covariance: joint | marginal,
//                  robot_frame: <text for the pose files' headers>,
//                  grid: {enabled: true, resolution: 0.05, max_range: 20}}
//   evaluation:   {relations: <file>, relations_max_dt: 1e-4, ground_truth_sensor: <sensor>, reference: <name>}
//
// Plugin parameters are checked against the plugin's descriptor (loaded
// through the registry) and completed with their defaults. Any scalar value
// (string, number, integer, bool) may use ${VAR} and ${VAR:-default}. Every problem is a ConfigError
// "<file>:<line>:<col>: <dotted.key>: <problem>". Angles are stored in radians.
// Relative directories (output.dir, run.plugin_path) are relative to the
// working directory; data paths inside plugin parameters are the plugins'.
#pragma once

#include <cstdint>
#include <filesystem>
#include <optional>
#include <stdexcept>
#include <string>
#include <vector>

#include "mspace/params.hpp"
#include "mspace/pose.hpp"
#include "plugin_registry.hpp"

namespace mspace::kernel {

class ConfigError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

/// One plugin instance: its name, its plugin and the complete parameters.
struct InstanceConfig {
  std::string instance;  ///< "source", "motion", "estimator", a feature instance or a sensor name
  std::string plugin;
  Params params;      ///< every declared parameter, defaults filled in
  std::string where;  ///< "file:line" of the instance in the YAML, for messages
};

struct SensorConfig {
  std::string name;
  std::string channel;             ///< the data channel whose readings this sensor extracts
  Pose6 mount = Pose6::Zero();     ///< x_rs: sensor pose on the robot (radians)
  InstanceConfig extractor;        ///< instance name = sensor name
  std::vector<std::string> feeds;  ///< feature instances its measurements go to
  /// Features farther than this (m) from the sensor are not considered for
  /// association; 0 = no limit.
  double max_range = 0.0;
  /// Health report: warn when the sensor has produced no measurement (or none
  /// matched) in this many readings; 0 = never.
  std::int64_t silent_readings = 200;
};

struct AssociationConfig {
  double gate_probability = 0.99;
  double new_feature_probability = 0.9999;
  int tentative_max_age = 20;  ///< steps
  /// Shared coordinates (T-RO §VI): blocks of two features closer than this
  /// (m) may be merged into one shared coordinate; 0 turns sharing off.
  double join_distance = 0.0;
  /// How the gated candidates of one reading become matches: greedy nearest
  /// neighbour, or joint compatibility branch and bound (Neira & Tardós 2001).
  enum class Method { NearestNeighbour, Jcbb };
  Method method = Method::NearestNeighbour;
  /// JCBB visits at most this many interpretation-tree nodes per reading,
  /// then falls back to nearest neighbour (counted in the summary).
  std::int64_t jcbb_max_nodes = 100000;
  /// JCBB only: a pairing is used only when no other jointly compatible
  /// hypothesis with as many pairings contradicts it (associate() drops the
  /// disputed ones; they start no feature either). Without it JCBB takes the
  /// hypothesis with the smallest joint distance however close a rival is.
  bool refuse_ambiguous = false;
  /// JCBB only: a pairing with a feature last seen over loop_min_gap_path
  /// metres of travel ago (a re-entry: a loop closed by ordinary association)
  /// is used only when, with the robot's covariance widened to
  /// reentry_covariance_scale² Σ_r, the reading's re-entry measurements
  /// jointly pick that pairing and no rival hypothesis with as many pairings
  /// leaves it out (association.hpp, confirm_reentries). Refused pairings
  /// update nothing and start no feature; the loop closer may still close
  /// the loop.
  bool reentry_joint_test = false;
  /// The re-entry test's widening of the robot's standard deviations (≥ 1).
  double reentry_covariance_scale = 2.0;
  /// Sensors with a max_range look their features up in a uniform grid over
  /// the features' planar bounding boxes instead of scanning the whole map
  /// (same result); false scans everything.
  bool spatial_index = true;
  double index_cell_size = 0.0;  ///< m, the grid's cell side; 0 = the largest sensors.<name>.max_range
  /// Map matching for loop closure (loop_closing.hpp): when features created
  /// in the last loop_local_path metres of travel (the local map) fit
  /// features last seen more than loop_min_gap_path metres ago (the old map)
  /// after a planar motion, uniquely and jointly compatibly, the two copies
  /// are declared one (coincidence factors for a re-linearising estimator,
  /// one EKF update otherwise).
  bool loop_closing = false;
  double loop_local_path = 15.0;  ///< m of travel
  double loop_min_gap_path = 30.0;  ///< m of travel
  /// The search window: 3σ of the robot's position (heading) plus this
  /// fraction of the path travelled since the old features were last seen
  /// (degrees per metre of it) — the drift the odometry may have had.
  double loop_drift_per_metre = 0.05;
  double loop_drift_deg_per_metre = 0.5;
  int loop_min_matches = 6;  ///< local features paired with old ones, at least
  /// A hypothesis is refused when a clearly different one pairs this
  /// fraction of its features (a symmetric building).
  double loop_ambiguity_ratio = 0.7;
  /// Range scans as evidence (scan_evidence.hpp): the recent scans are
  /// placed on the old ones by an exhaustive correlative search in the same
  /// window; a placement the scans contradict is refused, and a unique scan
  /// placement is offered to the features as a hypothesis of its own.
  bool loop_scans = false;
  /// After a step whose own odometry σ is large (a logging gap), that step's
  /// range scan is placed on every older one within 3σ of the prediction and
  /// the pose is updated to where it fits uniquely (slam_loop_closure.cpp,
  /// Slam::relocalize). Independent of loop_closing.
  bool relocalize_by_scans = false;
  /// The search window grows with the path since matches with *revisited*
  /// features (seen again after loop_min_gap_path m unseen) fixed the robot,
  /// not since any feature created that long ago did, and each old feature
  /// may be moved onto only by the drift since it was last seen (README,
  /// "Only a revisit widens the window").
  bool loop_revisit_window = false;
  /// A placement waiting for confirmation is confirmed by a later search that
  /// pairs local features it did not pair (independent evidence), or — when
  /// the robot only crosses the old place and maps nothing new there — by
  /// this many later searches, each over a changed local map, that find the
  /// same placement again with no other placement found in between (a search
  /// that places nothing neither counts nor interrupts; 0: only by new pairs).
  int loop_confirm_repeats = 0;
  /// A second, wider search when the first placed nothing (0: off; needs
  /// loop_revisit_window): its window reaches as far as a nearby old feature
  /// can have drifted at this many metres per metre of the travel since the
  /// robot last saw it — a drift rate measured on closures, not a bound —
  /// and each pair is held to the same rate. A placement there must be
  /// found twice like any other, and one the scans seeded must explain half
  /// of their end points (README, "A second search in a wider window").
  double loop_wide_drift_per_metre = 0.0;
};

/// "nearest_neighbour" or "jcbb".
/// Every key the loader accepts outside plugin parameters, dotted, with
/// <instance> and <sensor> for the names a file chooses: "run.name",
/// "sensors.<sensor>.max_range", "output.grid.resolution", "source.plugin", …
/// (from the same lists the loader checks against; config/README.md must
/// document each, tests/loading).
std::vector<std::string> accepted_keys();

const char* association_method_name(AssociationConfig::Method method);

/// Extra references a run is scored against (in the summary).
struct EvaluationConfig {
  /// Relations file (`t1 t2 x y z roll pitch yaw`, Kümmerle et al. 2009); empty: none.
  std::string relations;
  /// Largest |Δt| (s) between a relation's time stamp and a trajectory pose.
  double relations_max_dt = 1e-4;
  /// Ground truth is the pose of this sensor (x_r ⊕ x_rs), e.g. a GPS antenna
  /// mounted with the laser; empty: the robot pose itself.
  std::string ground_truth_sensor;
  /// What the source's ground truth is when it is not the truth (e.g.
  /// "GMapping" for corrected poses, "GPS"): the picture's legend and the
  /// summary name it; empty: the truth.
  std::string reference;
};

/// The occupancy grid written from the range scans (occupancy_grid.hpp).
struct GridConfig {
  bool enabled = true;
  double resolution = 0.05;  ///< m per cell
  double max_range = 20.0;   ///< m: longer beams clear cells up to here and mark nothing
};

struct OutputConfig {
  std::string dir;  ///< default "out/<run name>"
  bool trajectory = true, map = true, summary = true, picture = true;
  int picture_size = 1000;  ///< pixels
  /// frames/frame_<step>.png, the map's picture, every this many steps (0 = none; MapFrames).
  std::int64_t frames = 0;
  /// What the robot pose is, named in the header of every pose file (e.g.
  /// "rear-axle centre"); empty: "robot base".
  std::string robot_frame;
  /// map.bin holds the joint covariance of the map (`joint`, what `extend`
  /// needs) or only each feature's marginal (`marginal`, enough to `localize`).
  bool map_joint_covariance = true;
  GridConfig grid;
};

/// What a run does with a saved map (docs/maps.md): modes of the one loop.
struct MapConfig {
  enum class Mode {
    Mapping,   ///< start from an empty map (the default)
    Localize,  ///< the loaded map is read-only: only the robot is estimated
    Extend,    ///< the loaded map is the start: features gain dimensions, new ones enter
  };
  Mode mode = Mode::Mapping;
  std::string load;  ///< the map folder (or its map.bin); required by localize and extend
  /// The robot starts where the map's run ended (its last pose) instead of at
  /// initial_pose / the source's initial pose.
  bool start_at_map_end = false;
  /// Localize: the map rows whose correlation with the robot is kept (the
  /// Schmidt update's working set, kernel/src/considered_map.hpp): the
  /// least recently observed beyond this many forget it.
  int working_set_rows = 512;
  /// Localize: after this many metres of path (kernel path distance) with no
  /// measurement matching the map, switch to mapping (extend) for the rest
  /// of the run; 0 = never (docs/maps.md §2).
  double extend_when_unmapped = 0.0;
  /// Localize: `initial_pose: search` — the robot's place in the map is
  /// unknown (the kidnapped robot) and is found by map matching
  /// (kernel/src/slam_pose_search.cpp, docs/maps.md §3).
  bool search_pose = false;
};

const char* map_mode_name(MapConfig::Mode mode);
/// Why a map section cannot run (a mode without a map, a map without a mode
/// that uses it, …); empty when it can. The YAML reader and the CLI share it.
std::string map_config_problem(const MapConfig& map);

/// The nonlinear problem the kernel records for a re-linearising estimator
/// (problem.hpp; the `smoother`).
struct ProblemConfig {
  /// A frozen observation (and an extension's prior) is linear in the frame
  /// of the sensor (robot) at its pose node, so a rigid move of node and
  /// feature changes nothing; false: linear in the world frame (the
  /// frozen-factor rule, docs/writing-an-estimator.md).
  bool freeze_in_sensor_frame = false;
};

struct RunConfig {
  std::filesystem::path file;
  std::string name;
  std::string log_level = "info";
  std::int64_t max_steps = 0;  ///< 0 = all
  /// Write <output.dir>/checkpoint/ after every this many steps (0 = never).
  std::int64_t checkpoint_every = 0;
  /// Check the whole estimator covariance (asymmetry, smallest eigenvalue)
  /// after every this many steps (0 = only at the end; covariance_health.hpp).
  std::int64_t health_check_every = 0;
  std::vector<std::string> plugin_path;
  std::optional<std::int64_t> seed;
  /// Data steps read and discarded before the first step (a session that
  /// starts part-way through a log).
  std::int64_t skip_steps = 0;
  MapConfig map;
  ProblemConfig problem;
  InstanceConfig source, motion, estimator;
  std::vector<InstanceConfig> features;
  std::vector<SensorConfig> sensors;
  AssociationConfig association;
  Pose6 initial_pose = Pose6::Zero();                                               ///< radians
  Eigen::Matrix<double, 6, 1> initial_sigma = Eigen::Matrix<double, 6, 1>::Zero();  ///< radians for angles
  OutputConfig output;
  EvaluationConfig evaluation;
};

/// Reads and validates a run file. Directories of run.plugin_path are added to
/// `registry`, and the plugins the run names are loaded to check parameters.
/// `overrides` are the command line's --set assignments, "dotted.key=VALUE"
/// (VALUE is YAML: 5, true, [1, 2], text), applied over the file before it is
/// read: any key, plugin parameters included, checked like the file's own
/// values; a problem with one names its --set instead of a file position.
/// `map_from_command_line`: the command line gives --map / --mode, applied
/// after reading (resolve_run_request); the map section's consistency (a mode
/// without a map to load, start: map_end, initial_pose: search) is then
/// checked there, with the command line's values, instead of here.
/// `estimator_plugin` (the command line's --estimator, checked with
/// check_estimator_plugin first): when the file's estimator is another
/// plugin, its section is replaced by that plugin with its own defaults
/// before `overrides` apply, so that --set estimator.KEY=VALUE sets a key of
/// the chosen plugin (override_estimator, applied after reading, would drop
/// such a key with the file's section).
RunConfig load_config(const std::filesystem::path& file, PluginRegistry& registry,
                      const std::vector<std::string>& overrides = {}, bool map_from_command_line = false,
                      const std::string& estimator_plugin = {});

/// Same, from text; `file_name_for_messages` prefixes every error message and
/// its stem is the default run name.
RunConfig parse_config(const std::string& text, const std::string& file_name_for_messages, PluginRegistry& registry,
                       const std::vector<std::string>& overrides = {}, bool map_from_command_line = false,
                       const std::string& estimator_plugin = {});

/// The fully resolved configuration (every parameter with its effective value)
/// as YAML text in the run-file layout; parse_config accepts it back.
/// run.seed (or the CLI's --seed), when set, becomes the value of the `seed`
/// parameter of every plugin instance that declares one.
void apply_run_seed(RunConfig& config);

std::string effective_config_yaml(const RunConfig& config);

/// The CLI's --estimator: runs `plugin` as the estimator. The YAML's estimator
/// parameters are kept when it names the same plugin; otherwise the plugin's
/// own defaults are used (each estimator keeps its own options, so e.g. cekf's
/// max_active does not follow a switch to ekf). ConfigError for an unknown
/// plugin or one that is not an estimator, naming the known ones.
void override_estimator(RunConfig& config, const std::string& plugin, PluginRegistry& registry);

/// Loads `plugin` and checks that it is an estimator: ConfigError "--estimator
/// NAME: …" otherwise (unknown plugin, naming the known ones; another kind).
void check_estimator_plugin(const std::string& plugin, PluginRegistry& registry);

/// Expands ${VAR} and ${VAR:-default} (default used when VAR is unset or
/// empty). Throws std::invalid_argument for an unset variable without default
/// or an unterminated "${".
std::string expand_env_vars(const std::string& text);

}  // namespace mspace::kernel
