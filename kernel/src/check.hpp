// check.hpp — the `mspace check` command: the plugin conformance suite
// (mspace/conformance.hpp) run on plugin files or registered plugin names.
#pragma once

#include <cstdint>
#include <iosfwd>
#include <stdexcept>
#include <string>
#include <vector>

namespace mspace::kernel {

class PluginRegistry;

struct CheckCommand {
  /// Plugin library files (libmspace-plugin-<name>.so) or registered names.
  std::vector<std::string> targets;
  std::string junit_file;  ///< also write JUnit XML here when not empty
  int samples = 8;         ///< random samples per check
  std::uint64_t seed = 1;
  std::vector<std::string> params;  ///< "NAME=VALUE" parameter values for the instances
};

/// The plugin name a library file must carry: "libmspace-plugin-<name>.so" → "<name>",
/// or "" for any other file name.
std::string plugin_name_of_file(const std::string& file);

/// A mistake in the command, not in a plugin: a parameter the plugin needs
/// (no default, e.g. a source's data file) given with no --param. `mspace
/// check` reports it as a usage error (exit code 2), before any check runs.
class CheckUsageError : public std::invalid_argument {
 public:
  using std::invalid_argument::invalid_argument;
};

/// Checks every target and prints one report per target to `out`. Targets
/// that cannot be loaded count as failures. Returns 0 when everything passed,
/// 1 otherwise (the process exit code). Throws CheckUsageError (see there)
/// before checking anything.
int run_check(const CheckCommand& command, PluginRegistry& registry, std::ostream& out);

}  // namespace mspace::kernel
