// persistence.hpp — map files (and, later, checkpoints): one versioned
// container, written in one place (docs/persistence.md).
//
// The exact store, `map.bin`, is a little-endian binary file: a magic number,
// the format version, then records, each framed as
//   tag (4 ASCII) | key (i64: the feature id of a feature record) |
//   aux (i32: its feature-type index) | payload length (u64) | CRC-32 of
//   those 24 bytes | payload | CRC-32 of the payload,
// and a final END record holding the number of records before it. Doubles
// are stored as their IEEE-754 bits, so load(save(map)) is exact; a
// truncated file lacks END; a flipped bit fails a CRC; the framing CRC keeps
// the feature id and plugin readable even when the payload is damaged.
// Records of version 1: HEAD (the SDK ABI tag of the writer, the kind of
// file, the run name, the robot pose), TYPE (feature-type instances and their
// plugins), FEAT (one per feature: the kernel's bookkeeping and the plugin's
// SavedFeature with its named arrays), SHRD (one per shared coordinate), END.
//
// Format version 2 adds the records of a checkpoint (HEAD kind "checkpoint",
// docs/persistence.md §4): PARM (the fully resolved configuration), RUN (the
// kernel's own state: step, ids, robot pose, counters, trajectory so far) and
// PSTA (one per plugin instance with run-time state: the estimator, a data
// source's position and random generators, …; PluginObject::save_state).
// Format version 3 adds PROB (at most one, in a checkpoint): the kernel's
// nonlinear problem of a re-linearising estimator (pose nodes, factors with
// their last linearisations; Problem::save_state, problem_state.cpp).
// Version 1 maps and version 2 files are still read (they have no PROB: a
// re-linearising run cannot resume from one, and says so).
//
// Format version 3 also adds the covariance of a map (issue 16, docs/maps.md):
// COVM (every estimated feature's marginal covariance over its own rows: what
// `localize` needs) and COVJ (the joint covariance of all the estimator's
// rows, the robot's and the map's, lower triangle packed by columns, in
// records of at most 64 MiB: what `extend` needs to go on exactly). Versions 1 and 2 are still read.
//
// Every feature goes through its plugin: Feature::save() on the way out,
// FeatureType::restore() on the way in. Reading checks the whole file before
// anything is restored, and restore_features() returns all features or none.
// Errors are PersistenceError: they name the file and, where one is
// concerned, the feature id and the plugin.
#pragma once

#include <cstdint>
#include <filesystem>
#include <map>
#include <memory>
#include <optional>
#include <stdexcept>
#include <string>
#include <utility>
#include <vector>

#include "feature_bookkeeping.hpp"
#include "mspace/coords.hpp"
#include "mspace/feature.hpp"
#include "mspace/pose.hpp"
#include "mspace/state.hpp"

namespace mspace::kernel {

class Slam;
struct FeatureTypeSlot;

/// The container format this build writes; it reads this one and the older ones down to kOldestMapFormatVersion.
inline constexpr std::uint32_t kMapFormatVersion = 3;
/// The oldest container format this build reads (a map without checkpoint records).
inline constexpr std::uint32_t kOldestMapFormatVersion = 1;

/// Why a map file cannot be written or read: names the file and, when one
/// feature is concerned, its id and plugin.
class PersistenceError : public std::runtime_error {
 public:
  PersistenceError(const std::filesystem::path& file, const std::string& what,
                   std::optional<std::int64_t> feature_id = std::nullopt, const std::string& plugin = {});
  const std::filesystem::path& file() const { return file_; }
  std::optional<std::int64_t> feature_id() const { return feature_id_; }
  const std::string& plugin() const { return plugin_; }

 private:
  std::filesystem::path file_;
  std::optional<std::int64_t> feature_id_;
  std::string plugin_;
};

/// A feature-type instance of the run (`features: {instance: {plugin: …}}`).
struct StoredType {
  std::string instance;
  std::string plugin;
};

/// One feature: the kernel's bookkeeping (as in MapFeature) and the state the
/// plugin's save() returned.
struct StoredFeature : FeatureBookkeeping {
  std::int64_t id = 0;
  int type = 0;  ///< index into StoredMap::types
  SavedFeature saved;
  /// Covariance of its M-space perturbations (dim × dim, over state_idx; from
  /// COVM, format 3); empty for a tentative feature or an older file.
  Eigen::MatrixXd covariance;
};

/// A shared coordinate (T-RO §VI) as in SharedCoordinate.
struct StoredShared {
  int id = 0;
  BlockKind kind = BlockKind::Point2D;
  std::vector<int> state_idx;
  std::vector<std::pair<int, int>> members;  ///< (feature id, block)
};

/// Named matrices and byte strings of one object's run-time state (a plugin
/// object through save_state(), or the kernel's own bookkeeping).
class StoredState final : public StateWriter, public StateReader {
 public:
  /// std::logic_error when the name is already taken.
  void put(const std::string& name, const Eigen::MatrixXd& value) override;
  void put_bytes(const std::string& name, const std::string& bytes) override;
  bool has(const std::string& name) const override;
  /// std::invalid_argument "no saved array '<name>'" when absent.
  const Eigen::MatrixXd& get(const std::string& name) const override;
  const std::string& get_bytes(const std::string& name) const override;
  const std::map<std::string, Eigen::MatrixXd>& arrays() const { return arrays_; }
  const std::map<std::string, std::string>& bytes() const { return bytes_; }

 private:
  std::map<std::string, Eigen::MatrixXd> arrays_;
  std::map<std::string, std::string> bytes_;
};

/// The run-time state of one plugin instance (a PSTA record).
struct StoredPluginState {
  std::string instance;  ///< "source", "estimator", a sensor name, …
  std::string plugin;
  int version = 1;       ///< PluginObject::state_version()
  StoredState state;
};

/// What a checkpoint adds to a map (docs/persistence.md §4).
struct StoredCheckpoint {
  std::string config_yaml;  ///< the fully resolved configuration (effective_config_yaml)
  std::string config_file;  ///< the run file it came from (for messages)
  StoredState run;          ///< the kernel's state (Slam::save_run_state)
  std::vector<StoredPluginState> plugins;
  /// The nonlinear problem (PROB, format version 3), when the estimator re-linearises.
  std::optional<StoredState> problem;
};

/// The covariance of a map's estimator rows (format version 3): the rows are
/// numbered as the writing run's estimator had them, the robot's first
/// (0 .. first_row − 1), then the map's (first_row .. first_row + rows − 1).
struct StoredCovariance {
  int first_row = 0;  ///< estimator rows of the robot when the map was saved
  int rows = 0;       ///< estimator rows of the map
  /// The joint covariance of the robot's and the map's rows ((first_row +
  /// rows)², COVJ): the map's block is what `extend` needs; with the robot's
  /// rows a session that starts where the map's run ended goes on exactly.
  /// Absent when the map was saved with output.map_covariance: marginal.
  std::optional<Eigen::MatrixXd> joint;
};

/// Everything a map file holds (format version 3; a checkpoint when `checkpoint` is set).
struct StoredMap {
  std::uint32_t format_version = kMapFormatVersion;
  std::string abi_tag;       ///< SDK ABI tag of the writer (sdk_abi_tag())
  std::string kind = "map";  ///< "map" or "checkpoint" (docs/persistence.md)
  std::string run;           ///< the run's name
  Pose6 robot_pose = Pose6::Zero();
  std::vector<StoredType> types;
  std::vector<StoredFeature> features;
  std::vector<StoredShared> shared;
  std::optional<StoredCheckpoint> checkpoint;  ///< set exactly when kind == "checkpoint"
  /// Maps of format 3: the marginals are in the features, the rest here.
  std::optional<StoredCovariance> covariance;
};

/// A list of strings as one byte string (each as a u64 length and its bytes),
/// for StoredState::put_bytes; unpack_strings throws std::invalid_argument on
/// bytes pack_strings did not write.
std::string pack_strings(const std::vector<std::string>& strings);
std::vector<std::string> unpack_strings(const std::string& bytes);

/// What snapshot_map takes of the estimator's covariance.
enum class SnapshotCovariance { None, Marginal, Joint };

/// The map of a run, every feature through its plugin's save(), with the
/// covariance `covariance` asks for. A plugin that throws is reported with the
/// feature id and the plugin (as a PersistenceError naming `file`, the file
/// it is meant for).
StoredMap snapshot_map(const Slam& slam, const std::filesystem::path& file,
                       SnapshotCovariance covariance = SnapshotCovariance::None);

/// Writes `map` to `file` atomically: into a temporary file beside it, flushed
/// to disk, then renamed over `file`; on any error `file` is untouched.
void write_map_file(const std::filesystem::path& file, const StoredMap& map);

/// Reads and checks a whole map file (magic, format version, SDK version of
/// the ABI tag, every CRC, the END record, the records' consistency).
/// `kind`: the file must be a "map" or a "checkpoint". A map may come from
/// SDK major version 3 (same feature layout); a checkpoint, whose plugin
/// states follow the plugin interfaces, only from this build's major version.
StoredMap read_map_file(const std::filesystem::path& file, const std::string& kind = "map");

/// A feature rebuilt through its plugin's FeatureType::restore().
struct RestoredFeature {
  std::int64_t id = 0;
  int type = 0;                      ///< index into the `types` given to restore_features
  std::shared_ptr<Feature> feature;  ///< keeps its plugin library loaded
};

/// Rebuilds every feature of `map` through the feature types of the run
/// (matched by instance name and plugin name). All or nothing: the first
/// feature whose plugin is not loaded or whose restore() throws ends it with a
/// PersistenceError naming `file`, the feature id and the plugin.
std::vector<RestoredFeature> restore_features(const StoredMap& map, const std::filesystem::path& file,
                                              const std::vector<FeatureTypeSlot>& types);

/// snapshot_map + write_map_file: the run's `map.bin`, with the covariance
/// output.map_covariance asks for.
void write_map_bin(const std::filesystem::path& file, const Slam& slam);

/// The map file `given` names: a map.bin itself or a folder holding one.
/// PersistenceError when there is none.
std::filesystem::path find_map_file(const std::filesystem::path& given);

}  // namespace mspace::kernel
