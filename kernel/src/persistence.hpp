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

#include "mspace/coords.hpp"
#include "mspace/feature.hpp"
#include "mspace/pose.hpp"

namespace mspace::kernel {

class Slam;
struct FeatureTypeSlot;

/// The container format this build writes and reads.
inline constexpr std::uint32_t kMapFormatVersion = 1;

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
struct StoredFeature {
  std::int64_t id = 0;
  int type = 0;  ///< index into StoredMap::types
  std::vector<int> state_idx;
  std::vector<int> own_idx;
  std::map<int, int> shared;  ///< coordinate block → shared coordinate id
  std::int64_t created_step = 0;
  std::int64_t last_seen_step = 0;
  int last_sensor = 0;
  double last_seen_t = 0.0;
  int times_matched = 0;
  SavedFeature saved;
};

/// A shared coordinate (T-RO §VI) as in SharedCoordinate.
struct StoredShared {
  int id = 0;
  BlockKind kind = BlockKind::Point2D;
  std::vector<int> state_idx;
  std::vector<std::pair<int, int>> members;  ///< (feature id, block)
};

/// Everything a map file holds (format version 1).
struct StoredMap {
  std::uint32_t format_version = kMapFormatVersion;
  std::string abi_tag;       ///< SDK ABI tag of the writer (sdk_abi_tag())
  std::string kind = "map";  ///< "map"; "checkpoint" later (docs/persistence.md)
  std::string run;           ///< the run's name
  Pose6 robot_pose = Pose6::Zero();
  std::vector<StoredType> types;
  std::vector<StoredFeature> features;
  std::vector<StoredShared> shared;
};

/// The map of a run, every feature through its plugin's save(). A plugin
/// that throws is reported with the feature id and the plugin (as a
/// PersistenceError naming `file`, the file it is meant for).
StoredMap snapshot_map(const Slam& slam, const std::filesystem::path& file);

/// Writes `map` to `file` atomically: into a temporary file beside it, flushed
/// to disk, then renamed over `file`; on any error `file` is untouched.
void write_map_file(const std::filesystem::path& file, const StoredMap& map);

/// Reads and checks a whole map file (magic, format version, SDK version of
/// the ABI tag, every CRC, the END record, the records' consistency).
StoredMap read_map_file(const std::filesystem::path& file);

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

/// snapshot_map + write_map_file: the run's `map.bin`.
void write_map_bin(const std::filesystem::path& file, const Slam& slam);

}  // namespace mspace::kernel
