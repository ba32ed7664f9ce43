// libFuzzer harness: the map file / checkpoint container reader
// (kernel/src/persistence.cpp, docs/persistence.md) and the feature plugins'
// restore() behind it. Issue 16 asks of it: no crash, and every refusal names
// the file and, where one feature is concerned, the feature and its plugin.
//
// Every record carries two CRC-32s, so almost every mutation of a real file
// is refused by a checksum before any decoder sees it. Each input is therefore
// read twice: as it is (the framing and checksum checks), and with every CRC
// that can be located recomputed (the decoders, the consistency checks and the
// plugins' restore()). zlib's crc32 is the CRC the container uses (IEEE 802.3,
// as PNG).
#include <zlib.h>

#include <cstring>
#include <map>
#include <string>
#include <vector>

#include "fuzz_support.hpp"
#include "persistence.hpp"
#include "plugin_registry.hpp"
#include "slam.hpp"

namespace {

using mspace::kernel::PersistenceError;

// The container's layout (docs/persistence.md §2): 8 magic bytes and a u32
// format version, then records of a 24-byte frame (tag u32, key i64, aux i32,
// payload length u64), the frame's CRC, the payload and the payload's CRC;
// little-endian.
constexpr std::size_t kFileHeader = 8 + 4;
constexpr std::size_t kFrame = 4 + 8 + 4 + 8;

void put_crc(std::string& bytes, std::size_t at, std::size_t from, std::size_t size) {
  const auto crc = static_cast<std::uint32_t>(
      ::crc32(0L, reinterpret_cast<const Bytef*>(bytes.data() + from), static_cast<uInt>(size)));
  for (int i = 0; i < 4; ++i) bytes[at + static_cast<std::size_t>(i)] = static_cast<char>((crc >> (8 * i)) & 0xffu);
}

/// `bytes` with the CRC of every frame and payload that lies inside it recomputed.
std::string with_valid_crcs(std::string bytes) {
  std::size_t at = kFileHeader;
  while (bytes.size() >= at + kFrame + 4) {
    put_crc(bytes, at + kFrame, at, kFrame);
    std::uint64_t length = 0;
    for (int i = 7; i >= 0; --i)
      length = (length << 8) | static_cast<unsigned char>(bytes[at + 16 + static_cast<std::size_t>(i)]);
    const std::size_t payload = at + kFrame + 4;
    if (length > bytes.size() - payload || bytes.size() - payload - length < 4) break;
    put_crc(bytes, payload + static_cast<std::size_t>(length), payload, static_cast<std::size_t>(length));
    at = payload + static_cast<std::size_t>(length) + 4;
  }
  return bytes;
}

/// The in-tree feature types, created on demand under the instance names a
/// file uses (restore_features matches instance and plugin).
class FeatureTypes {
 public:
  FeatureTypes() { registry_.add_search_dir(MSPACE_PLUGIN_DIR); }

  std::vector<mspace::kernel::FeatureTypeSlot> for_map(const mspace::kernel::StoredMap& map) {
    std::vector<mspace::kernel::FeatureTypeSlot> slots;
    for (const mspace::kernel::StoredType& t : map.types) {
      if (!is_feature_plugin(t.plugin)) continue;  // restore_features must name it as not loaded
      auto& cached = types_[{t.instance, t.plugin}];
      if (!cached.type) {
        cached.instance = t.instance;
        cached.plugin = t.plugin;
        cached.library = registry_.load(t.plugin);
        const mspace::Params params = mspace::Params::defaults(cached.library->descriptor->params);
        cached.type = registry_.create<mspace::FeatureType>(t.plugin, mspace::PluginKind::Feature,
                                                             mspace::PluginArgs{t.instance, params, nullptr});
      }
      slots.push_back(cached);
    }
    return slots;
  }

 private:
  static bool is_feature_plugin(const std::string& name) {
    return name == "point" || name == "wall" || name == "hline" || name == "pole";
  }
  mspace::kernel::PluginRegistry registry_;
  std::map<std::pair<std::string, std::string>, mspace::kernel::FeatureTypeSlot> types_;
};

/// A refusal must be a PersistenceError naming this file; one that names a
/// feature also names its plugin. Anything else ends the run as a finding.
void read(const std::filesystem::path& file, FeatureTypes& types) {
  for (const char* kind : {"map", "checkpoint"}) {
    try {
      const mspace::kernel::StoredMap map = mspace::kernel::read_map_file(file, kind);
      mspace::kernel::restore_features(map, file, types.for_map(map));
    } catch (const PersistenceError& e) {
      const std::string what = e.what();
      if (e.file() != file || what.rfind("map file '" + file.string() + "'", 0) != 0 ||
          (e.feature_id() && e.plugin().empty())) {
        std::fprintf(stderr, "refusal without its file or plugin: %s\n", what.c_str());
        std::abort();
      }
    }
  }
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  static FeatureTypes types;
  const std::string raw(reinterpret_cast<const char*>(data), size);
  const std::filesystem::path file = mspace::fuzz::write_input("map.bin", data, size);
  read(file, types);
  const std::string fixed = with_valid_crcs(raw);
  if (fixed != raw) {
    const auto* bytes = reinterpret_cast<const std::uint8_t*>(fixed.data());
    read(mspace::fuzz::write_input("map.bin", bytes, fixed.size()), types);
  }
  return 0;
}
