// check.cpp — see check.hpp.
#include <algorithm>
#include "check.hpp"

#include <filesystem>
#include <fstream>
#include <ostream>
#include <sstream>
#include <stdexcept>

#include "mspace/conformance.hpp"
#include "plugin_registry.hpp"

namespace mspace::kernel {
namespace {

namespace fs = std::filesystem;

/// A report for a target the suite could not even load.
conformance::Report load_failure(const std::string& target, const std::string& message) {
  conformance::Report report;
  report.plugin = target;
  report.kind.assign(1, '?');  // (not = "?": GCC 12 -O3 warns -Wrestrict on that once inlined)
  conformance::CheckResult c;
  c.name = "load";
  c.worst = 1;
  c.passed = false;
  c.note = message;
  report.checks.push_back(c);
  return report;
}

/// The registered name of `target`, loading it first when it is a file.
std::string resolve(const std::string& target, PluginRegistry& registry) {
  std::error_code ec;
  if (!fs::is_regular_file(target, ec)) return target;
  const std::string name = plugin_name_of_file(target);
  if (name.empty()) throw PluginError("'" + target + "' is not named libmspace-plugin-<name>.so");
  registry.add_plugin_file(target);
  return name;
}

/// The plugin of `target`, or nullptr when it cannot be loaded (`error` says why).
std::shared_ptr<const LoadedPlugin> load_target(const std::string& target, PluginRegistry& registry,
                                                std::string& error) {
  try {
    return registry.load(resolve(target, registry));
  } catch (const std::exception& e) {
    error = e.what();
    return nullptr;
  }
}

/// Throws CheckUsageError when the plugin has a parameter without default
/// that the command gives no value for.
void require_values(const PluginDescriptor& descriptor, const conformance::Options& options) {
  for (const ParamSpec& spec : descriptor.params) {
    if (!spec.required || options.params.count(spec.name) != 0) continue;
    std::ostringstream message;
    message << "plugin '" << descriptor.name << "': parameter '" << spec.name << "' (" << spec.description
            << ") has no default; give it with --param " << spec.name << "=VALUE";
    throw CheckUsageError(message.str());
  }
}

conformance::Report check_target(const PluginDescriptor& descriptor, const std::string& target,
                                 const conformance::Options& options) {
  try {
    return conformance::check_plugin(descriptor, options);
  } catch (const std::exception& e) {
    return load_failure(target, e.what());
  }
}

}  // namespace

std::string plugin_name_of_file(const std::string& file) {
  const std::string base = fs::path(file).filename().string();
  const std::string prefix = "libmspace-plugin-", suffix = ".so";
  if (base.size() <= prefix.size() + suffix.size() || base.compare(0, prefix.size(), prefix) != 0 ||
      base.compare(base.size() - suffix.size(), suffix.size(), suffix) != 0) {
    return {};
  }
  return base.substr(prefix.size(), base.size() - prefix.size() - suffix.size());
}

int run_check(const CheckCommand& command, PluginRegistry& registry, std::ostream& out) {
  conformance::Options options;
  options.samples = command.samples;
  options.seed = command.seed;
  for (const std::string& assignment : command.params) {
    const auto eq = assignment.find('=');
    if (eq == std::string::npos || eq == 0)
      throw std::invalid_argument("--param '" + assignment + "': expected NAME=VALUE");
    options.params[assignment.substr(0, eq)] = assignment.substr(eq + 1);
  }
  // Load every target first (`plugins` keep the libraries loaded until every
  // object of the checks is gone), so that a usage error stops before any check.
  std::vector<std::shared_ptr<const LoadedPlugin>> plugins;
  std::vector<std::string> load_errors;
  for (const std::string& target : command.targets)
    plugins.push_back(load_target(target, registry, load_errors.emplace_back()));
  // Each --param goes to the targets that declare it (an extractor's
  // parameter is no business of the feature type checked beside it); one
  // that no loaded target declares is a usage error.
  std::vector<conformance::Options> own(plugins.size(), options);
  for (const auto& [name, value] : options.params) {
    bool declared = false;
    std::string known;
    for (std::size_t i = 0; i < plugins.size(); ++i) {
      if (!plugins[i]) continue;
      const auto& specs = plugins[i]->descriptor->params;
      const bool has = std::any_of(specs.begin(), specs.end(), [&](const ParamSpec& s) { return s.name == name; });
      declared = declared || has;
      if (!has) own[i].params.erase(name);
      known += (known.empty() ? "" : "; ") + plugins[i]->descriptor->name + ":";
      for (const ParamSpec& s : specs) known += " " + s.name;
    }
    if (!declared && std::any_of(plugins.begin(), plugins.end(), [](const auto& p) { return p != nullptr; }))
      throw CheckUsageError("--param " + name + ": no plugin checked declares it (" + known + ")");
  }
  for (std::size_t i = 0; i < plugins.size(); ++i)
    if (plugins[i]) require_values(*plugins[i]->descriptor, own[i]);
  std::vector<conformance::Report> reports;
  int failed = 0;
  for (std::size_t i = 0; i < command.targets.size(); ++i) {
    const std::string& target = command.targets[i];
    reports.push_back(plugins[i] ? check_target(*plugins[i]->descriptor, target, own[i])
                                 : load_failure(target, load_errors[i]));
    conformance::print_report(reports.back(), out);
    failed += reports.back().passed() ? 0 : 1;
  }
  // The extractor ↔ feature contract of every extractor with every feature
  // type among the targets (`mspace check EXTRACTOR.so FEATURE.so`).
  for (std::size_t e = 0; e < plugins.size(); ++e) {
    if (!plugins[e] || plugins[e]->descriptor->kind != PluginKind::Extractor) continue;
    for (std::size_t f = 0; f < plugins.size(); ++f) {
      if (!plugins[f] || plugins[f]->descriptor->kind != PluginKind::Feature) continue;
      reports.push_back(conformance::check_pair(*plugins[e]->descriptor, *plugins[f]->descriptor, options));
      conformance::print_report(reports.back(), out);
      failed += reports.back().passed() ? 0 : 1;
    }
  }
  if (!command.junit_file.empty()) {
    std::ofstream junit(command.junit_file);
    if (!junit) throw std::runtime_error("cannot write " + command.junit_file);
    conformance::write_junit(reports, junit);
  }
  out << (failed == 0 ? "all " + std::to_string(reports.size()) + " report(s) passed\n"
                      : std::to_string(failed) + " of " + std::to_string(reports.size()) + " report(s) FAILED\n");
  return failed == 0 ? 0 : 1;
}

}  // namespace mspace::kernel
