// mspace/conformance.hpp — the plugin conformance suite behind `mspace check`.
//
// check_plugin() takes a plugin's descriptor, creates an instance with the
// declared defaults and runs every check that applies to its kind, knowing
// nothing about the concrete type:
//   * every kind: descriptor sanity (name, kind, ABI tag, parameters with
//     defaults inside their ranges) and construction with the defaults;
//   * feature types, for random samples at every reachable M-space dimension
//     (FeatureType::sample): B·B̃ = I (eq. 12), B̃ of full column rank, J_ηo
//     and J_ηv (eq. 16) and the chain J_ηo·J_of·B̃ (eq. 30) against central
//     differences, invariance along declared symmetry directions, the
//     extension (sizes, C_new symmetric positive definite, J_sensor and J_own
//     against differences), save/restore round trip, determinism, finite
//     values and clear errors for wrong-sized inputs;
//   * motion models: J_rr and J_rd (eq. 26) against central differences, C_d;
//   * estimators: a small linear-Gaussian problem against the closed-form
//     Kalman prediction, augmentation, update (eqs. 26–32) and removal;
//   * extractors and sources: finite, well-formed, deterministic output.
// Each check keeps the worst number it saw and compares it with a tolerance.
#pragma once

#include <cstdint>
#include <map>
#include <iosfwd>
#include <string>
#include <vector>

#include "mspace/plugin.hpp"

namespace mspace::conformance {

/// The outcome of one named check over all samples.
struct CheckResult {
  std::string name;
  double worst = 0.0;       ///< the worst number seen (error, condition number, …)
  double tolerance = 0.0;
  bool lower_is_better = true;  ///< pass when worst ≤ tolerance (else worst ≥ tolerance)
  bool passed = true;
  bool skipped = false;     ///< nothing to check (e.g. no symmetry declared)
  std::string note;         ///< first failure message, or why it was skipped
};

struct Report {
  std::string plugin;  ///< descriptor name
  std::string kind;    ///< plugin_kind_name()
  std::vector<CheckResult> checks;

  int failures() const;
  bool passed() const { return failures() == 0; }
  /// The check called `name`, or nullptr.
  const CheckResult* find(const std::string& name) const;
};

struct Options {
  int samples = 8;          ///< random samples per M-space dimension / per check
  std::uint64_t seed = 1;   ///< base seed; every sample seed derives from it
  /// Parameter values as text, NAME → VALUE, over the plugin's defaults (e.g.
  /// the data file of a source that has no default for it).
  std::map<std::string, std::string> params;
};

/// Runs every check that applies to the plugin's kind. Never throws for a
/// misbehaving plugin: exceptions become failed checks.
Report check_plugin(const PluginDescriptor& descriptor, const Options& options = {});

/// One line per check: "PASS  name  worst 1.2e-09  (tol ≤ 1e-06)  note".
void print_report(const Report& report, std::ostream& out);

/// JUnit XML (one <testsuite> per report, one <testcase> per check).
void write_junit(const std::vector<Report>& reports, std::ostream& out);

}  // namespace mspace::conformance
