#include "plugin_registry.hpp"

#include <dlfcn.h>

#include <cstdlib>
#include <cstring>
#include <sstream>
#include <string_view>

#include <boost/dll/runtime_symbol_info.hpp>
#include <boost/dll/shared_library.hpp>

#include "mspace/plugin_export.hpp"

namespace mspace::kernel {

namespace fs = std::filesystem;

namespace {

constexpr std::string_view kFilePrefix = "libmspace-plugin-";
constexpr std::string_view kFileSuffix = ".so";

/// "point" for "libmspace-plugin-point.so"; empty if the file name does not
/// follow the plugin naming scheme.
std::string plugin_name_from_file(const fs::path& file) {
  const std::string base = file.filename().string();
  const bool matches = base.size() > kFilePrefix.size() + kFileSuffix.size() && base.starts_with(kFilePrefix) &&
                       base.ends_with(kFileSuffix);
  if (!matches) return {};
  return base.substr(kFilePrefix.size(), base.size() - kFilePrefix.size() - kFileSuffix.size());
}

std::string join(const std::vector<std::string>& items, const char* separator) {
  std::string out;
  for (const std::string& item : items) out += (out.empty() ? "" : separator) + item;
  return out;
}

std::string quoted(const fs::path& path) {
  std::string out = "'";  // built by appending: "'" + std::string&& trips GCC 12's -Wrestrict
  out += path.string();
  out += '\'';
  return out;
}

fs::path absolute_path(const fs::path& path) {
  std::error_code ec;
  fs::path abs = fs::absolute(path, ec);
  return (ec ? path : abs).lexically_normal();
}

std::unique_ptr<boost::dll::shared_library> open_library(const fs::path& file) {
  auto lib = std::make_unique<boost::dll::shared_library>();
  boost::dll::fs::error_code ec;
  // rtld_now: unresolved symbols are reported here, not in the middle of a run.
  lib->load(file.string(), boost::dll::load_mode::rtld_now | boost::dll::load_mode::rtld_local, ec);
  if (ec) {
    const char* why = dlerror();  // Boost.DLL keeps only a generic error code
    throw PluginError("cannot load plugin library " + quoted(file) + ": " + (why != nullptr ? why : ec.message()));
  }
  return lib;
}

/// Reads the library's `mspace_abi_tag` data symbol and refuses a mismatch.
/// This runs before any function of the library is called.
void check_abi_symbol(const boost::dll::shared_library& lib, const fs::path& file) {
  if (!lib.has(MSPACE_ABI_SYMBOL))
    throw PluginError(quoted(file) + " is not an mspace plugin (no " MSPACE_ABI_SYMBOL " symbol)");
  const char* tag = &lib.get<const char>(MSPACE_ABI_SYMBOL);
  constexpr std::size_t kMaxTagLength = 256;  // a foreign symbol need not be terminated
  const std::string their_tag(tag, strnlen(tag, kMaxTagLength));
  if (their_tag != MSPACE_ABI_TAG)
    throw PluginError("plugin library " + quoted(file) + " was built for SDK ABI '" + their_tag +
                      "' but this mspace expects '" MSPACE_ABI_TAG "'; rebuild the plugin against this SDK");
}

const PluginDescriptor* read_descriptor(const boost::dll::shared_library& lib, const fs::path& file) {
  if (!lib.has(MSPACE_DESCRIPTOR_SYMBOL))
    throw PluginError(quoted(file) + " has an ABI tag but no " MSPACE_DESCRIPTOR_SYMBOL " entry point");
  using DescribeFn = const PluginDescriptor*();
  DescribeFn& describe = lib.get_alias<DescribeFn>(MSPACE_DESCRIPTOR_SYMBOL);
  const PluginDescriptor* descriptor = nullptr;
  try {
    descriptor = describe();
  } catch (const std::exception& e) {
    throw PluginError(quoted(file) + ": reading the plugin descriptor failed: " + e.what());
  }
  if (descriptor == nullptr) throw PluginError(quoted(file) + ": the plugin descriptor is null");
  if (descriptor->abi_tag != MSPACE_ABI_TAG)
    throw PluginError("plugin library " + quoted(file) + " describes itself with SDK ABI '" + descriptor->abi_tag +
                      "' but this mspace expects '" MSPACE_ABI_TAG "'; rebuild the plugin against this SDK");
  return descriptor;
}

/// Opens and checks one plugin library: ABI tag first, then the descriptor.
std::shared_ptr<const LoadedPlugin> open_plugin(const fs::path& file) {
  const fs::path path = absolute_path(file);
  std::unique_ptr<boost::dll::shared_library> lib = open_library(path);
  check_abi_symbol(*lib, path);
  const PluginDescriptor* descriptor = read_descriptor(*lib, path);
  return std::make_shared<const LoadedPlugin>(std::move(lib), descriptor, path);
}

/// A library found as libmspace-plugin-<name>.so must describe plugin <name>.
void check_name_matches_file(const LoadedPlugin& plugin) {
  const std::string file_name = plugin_name_from_file(plugin.path);
  if (!file_name.empty() && file_name != plugin.descriptor->name)
    throw PluginError(quoted(plugin.path) + " describes plugin '" + plugin.descriptor->name +
                      "' but its file name says '" + file_name + "'; name the file " + std::string(kFilePrefix) +
                      plugin.descriptor->name + std::string(kFileSuffix));
}

const char* with_article(PluginKind kind) {
  switch (kind) {
    case PluginKind::Extractor:
    case PluginKind::Estimator: return "an ";
    default: return "a ";
  }
}

}  // namespace

LoadedPlugin::LoadedPlugin(std::unique_ptr<boost::dll::shared_library> lib, const PluginDescriptor* desc, fs::path file)
    : library(std::move(lib)), descriptor(desc), path(std::move(file)) {}

LoadedPlugin::~LoadedPlugin() = default;

PluginError plugin_call_error(const std::string& instance, const LoadedPlugin& plugin, const char* what,
                              const std::string& message) {
  return PluginError(instance + " (plugin '" + plugin.descriptor->name + "', library " + quoted(plugin.path) +
                     "): " + what + " failed: " + message);
}

std::string kind_mismatch_message(const std::string& plugin, PluginKind actual, PluginKind expected) {
  return "plugin '" + plugin + "' is " + with_article(actual) + plugin_kind_name(actual) + ", but " +
         with_article(expected) + plugin_kind_name(expected) + " is needed here";
}

PluginRegistry::PluginRegistry() = default;
PluginRegistry::~PluginRegistry() = default;

std::vector<fs::path> PluginRegistry::default_search_dirs() {
  std::vector<fs::path> dirs;
  if (const char* env = std::getenv("MSPACE_PLUGIN_PATH")) {
    std::istringstream entries(env);
    for (std::string entry; std::getline(entries, entry, ':');)
      if (!entry.empty()) dirs.push_back(absolute_path(entry));
  }
  boost::dll::fs::error_code ec;
  const boost::dll::fs::path exe = boost::dll::program_location(ec);
  if (!ec) dirs.push_back((fs::path(exe.parent_path().string()) / ".." / MSPACE_PLUGIN_RELDIR).lexically_normal());
  return dirs;
}

void PluginRegistry::add_search_dir(const fs::path& dir) { dirs_.push_back(absolute_path(dir)); }

void PluginRegistry::add_plugin_file(const fs::path& file) {
  std::error_code ec;
  if (!fs::is_regular_file(file, ec)) throw PluginError("plugin file " + quoted(file) + " does not exist");
  std::shared_ptr<const LoadedPlugin> plugin = open_plugin(file);
  check_name_matches_file(*plugin);
  const std::string& name = plugin->descriptor->name;
  if (auto it = loaded_.find(name); it != loaded_.end() && it->second->path != plugin->path)
    throw PluginError("plugin '" + name + "' from " + quoted(plugin->path) +
                      " clashes with the one already loaded from " + quoted(it->second->path));
  explicit_files_[name] = plugin->path;
  loaded_[name] = std::move(plugin);
}

std::map<std::string, fs::path> PluginRegistry::discover() const {
  std::map<std::string, fs::path> found;
  for (const fs::path& dir : dirs_) {
    std::error_code ec;
    for (fs::directory_iterator it(dir, ec), end; !ec && it != end; it.increment(ec)) {
      const std::string name = plugin_name_from_file(it->path());
      if (!name.empty() && it->is_regular_file(ec)) found.emplace(name, it->path());  // first dir wins
    }
  }
  for (const auto& [name, file] : explicit_files_) found[name] = file;
  return found;
}

std::vector<std::string> PluginRegistry::known_names() const {
  std::vector<std::string> names;
  for (const auto& entry : discover()) names.push_back(entry.first);
  return names;
}

std::shared_ptr<const LoadedPlugin> PluginRegistry::load(const std::string& name) {
  if (auto it = loaded_.find(name); it != loaded_.end()) return it->second;
  const std::map<std::string, fs::path> files = discover();
  auto file = files.find(name);
  if (file == files.end()) {
    std::vector<std::string> names;
    for (const auto& entry : files) names.push_back(entry.first);
    std::vector<std::string> dirs;
    for (const fs::path& dir : dirs_) dirs.push_back(dir.string());
    throw PluginError("unknown plugin '" + name +
                      "'; known plugins: " + (names.empty() ? std::string("none") : join(names, ", ")) +
                      " (searched: " + (dirs.empty() ? std::string("no directories") : join(dirs, ", ")) + ")");
  }
  std::shared_ptr<const LoadedPlugin> plugin = open_plugin(file->second);
  check_name_matches_file(*plugin);
  loaded_[name] = plugin;
  return plugin;
}

std::vector<std::shared_ptr<const LoadedPlugin>> PluginRegistry::load_all(std::vector<std::string>* errors) {
  std::vector<std::shared_ptr<const LoadedPlugin>> plugins;
  for (const std::string& name : known_names()) {
    try {
      plugins.push_back(load(name));
    } catch (const PluginError& e) {
      if (errors == nullptr) throw;
      errors->push_back(e.what());
    }
  }
  return plugins;
}

PluginObject* PluginRegistry::create_object(const LoadedPlugin& plugin, PluginKind expected, const PluginArgs& args) {
  const PluginDescriptor& d = *plugin.descriptor;
  if (d.kind != expected)
    throw PluginError(args.instance_name + ": " + kind_mismatch_message(d.name, d.kind, expected));
  if (d.factory == nullptr) throw plugin_call_error(args.instance_name, plugin, "factory", "the plugin has no factory");
  std::unique_ptr<PluginObject> object =
      guarded(args.instance_name, plugin, "factory", [&] { return d.factory(args); });
  if (object == nullptr) throw plugin_call_error(args.instance_name, plugin, "factory", "it returned no object");
  return object.release();
}

}  // namespace mspace::kernel
