// plugin_registry.hpp — finding, loading and instantiating plugin libraries.
//
// A plugin is a shared library `libmspace-plugin-<name>.so` exporting the two
// symbols of MSPACE_EXPORT_PLUGIN (sdk/include/mspace/plugin_export.hpp).
// The registry
//   * discovers plugins by file name in its search directories, without
//     loading them (first directory wins);
//   * loads a library only when it is asked for by name, checks its ABI tag
//     before calling anything in it, then reads its descriptor;
//   * creates objects through the descriptor's factory. Every object holds a
//     reference to its library, so the library stays loaded while the object
//     lives, even after the registry is gone.
// Exceptions thrown by plugin code are reported as PluginError with the
// instance name, the plugin name and the library path (see guarded()).
#pragma once

#include <filesystem>
#include <map>
#include <memory>
#include <stdexcept>
#include <string>
#include <type_traits>
#include <utility>
#include <vector>

#include "mspace/plugin.hpp"

namespace boost::dll {
class shared_library;
}

namespace mspace::kernel {

/// Any failure to find, load, check or call a plugin.
class PluginError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

/// One loaded plugin library and the descriptor it exports.
struct LoadedPlugin {
  LoadedPlugin(std::unique_ptr<boost::dll::shared_library> lib, const PluginDescriptor* desc,
               std::filesystem::path file);
  ~LoadedPlugin();
  LoadedPlugin(const LoadedPlugin&) = delete;
  LoadedPlugin& operator=(const LoadedPlugin&) = delete;

  /// The open library (declared first, so it is unloaded last).
  std::unique_ptr<boost::dll::shared_library> library;
  /// Lives inside the library.
  const PluginDescriptor* descriptor = nullptr;
  /// Absolute path of the library file.
  std::filesystem::path path;
};

/// "plugin '<plugin>' is an extractor, but a feature is needed here".
std::string kind_mismatch_message(const std::string& plugin, PluginKind actual, PluginKind expected);

/// "<instance> (plugin '<name>', library '<path>'): <what> failed: <message>".
PluginError plugin_call_error(const std::string& instance, const LoadedPlugin& plugin, const char* what,
                              const std::string& message);

/// Runs `f()` — a call into plugin code — and turns any exception it throws
/// into a PluginError naming the instance, the plugin and its library.
template <class F>
auto guarded(const std::string& instance, const LoadedPlugin& plugin, const char* what, F&& f)
    -> decltype(std::forward<F>(f)()) {
  try {
    return std::forward<F>(f)();
  } catch (const std::exception& e) {
    throw plugin_call_error(instance, plugin, what, e.what());
  } catch (...) {
    throw plugin_call_error(instance, plugin, what, "unknown exception");
  }
}

class PluginRegistry {
 public:
  PluginRegistry();
  ~PluginRegistry();
  PluginRegistry(const PluginRegistry&) = delete;
  PluginRegistry& operator=(const PluginRegistry&) = delete;

  /// The standard search directories, highest priority first: each entry of
  /// MSPACE_PLUGIN_PATH (colon-separated), then
  /// <directory of the running executable>/../lib/mspace/plugins.
  static std::vector<std::filesystem::path> default_search_dirs();

  /// Adds a directory after the ones added before (lower priority).
  /// Directories that do not exist are remembered but contribute nothing.
  void add_search_dir(const std::filesystem::path& dir);
  const std::vector<std::filesystem::path>& search_dirs() const { return dirs_; }

  /// Loads one library file given explicitly (the CLI's --plugin FILE). Its
  /// name comes from its descriptor and takes precedence over the search
  /// directories. Throws PluginError at once if the file is not a usable plugin.
  void add_plugin_file(const std::filesystem::path& file);

  /// Names of all plugins that can be loaded, sorted (no library is loaded).
  std::vector<std::string> known_names() const;

  /// Loads (once; later calls return the cached library) the plugin `name`.
  std::shared_ptr<const LoadedPlugin> load(const std::string& name);

  /// Loads every known plugin, for listing. Libraries that fail to load are
  /// skipped and their error messages appended to `*errors`; with
  /// errors == nullptr the first failure is thrown instead.
  std::vector<std::shared_ptr<const LoadedPlugin>> load_all(std::vector<std::string>* errors);

  /// Creates the instance `args.instance_name` of `plugin`, which must be of
  /// kind `expected` (T is the matching interface: Extractor for
  /// PluginKind::Extractor, ...). The object keeps the library loaded.
  template <class T>
  std::shared_ptr<T> create(const std::string& plugin, PluginKind expected, const PluginArgs& args) {
    static_assert(std::is_base_of_v<PluginObject, T>, "T must be a plugin interface");
    std::shared_ptr<const LoadedPlugin> lib = load(plugin);
    PluginObject* object = create_object(*lib, expected, args);
    // The deleter owns a reference to the library: the object's destructor
    // (plugin code) runs before the library can be unloaded.
    return std::shared_ptr<T>(static_cast<T*>(object), [lib](T* p) { delete p; });
  }

 private:
  /// Kind check, factory call (guarded) and null check; returns an owning raw pointer.
  static PluginObject* create_object(const LoadedPlugin& plugin, PluginKind expected, const PluginArgs& args);
  /// Name → file for every plugin in the search directories (first dir wins),
  /// then the explicit files on top.
  std::map<std::string, std::filesystem::path> discover() const;

  std::vector<std::filesystem::path> dirs_;
  std::map<std::string, std::filesystem::path> explicit_files_;
  std::map<std::string, std::shared_ptr<const LoadedPlugin>> loaded_;
};

}  // namespace mspace::kernel
