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
//     extension (reached from every non-final dimension, sizes, J_sensor and
//     J_own against differences of the extended coordinates, C_new against
//     Σ_k J_v,k C_v J_v,kᵀ from differences in the measurements), the gating
//     covariance of a new feature against differences of create() in v and
//     x_ms, save/restore round trip, determinism, finite values and clear
//     errors for wrong-sized inputs; the cost per call of innovation() and
//     extend() and which of their Jacobians are numeric (mspace/numeric.hpp);
//   * motion models: J_rr and J_rd (eq. 26) against central differences, C_d;
//   * estimators: a small linear-Gaussian problem against the closed-form
//     Kalman prediction, augmentation, update (eqs. 26–32) and removal;
//   * extractors and sources: finite, well-formed, deterministic output;
//   * an extractor with a feature type (check_pair): the measurements of the
//     extractor's sample scenes against the feature type's true features.
// Each check keeps the worst number it saw and compares it with a tolerance.
#pragma once

#include <cstdint>
#include <map>
#include <iosfwd>
#include <limits>
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
  bool show_note = false;   ///< the note says something on a pass too (e.g. how often)
};

/// What one function of a feature type costs per call, and which of its
/// Jacobians come from the SDK's numeric helpers (mspace/numeric.hpp).
struct Cost {
  std::string function;             ///< "innovation" or "extend from dim D"
  std::vector<std::string> numeric;   ///< Jacobians filled by central differences (numeric_usage())
  std::vector<std::string> analytic;  ///< the others the function returns
  double micros = 0.0;              ///< measured time per call (µs), mean over the samples
  double evaluations = 0.0;         ///< function evaluations of the numeric helpers per call (J_measurement included)
  /// innovation only: the time per call of J_ηo and J_ηv by central
  /// differences through innovation() itself (2(n + m) + 1 calls) — what
  /// switching every Jacobian to numeric would cost at most; NaN if not measured.
  double micros_by_differences = std::numeric_limits<double>::quiet_NaN();
  int calls = 0;                    ///< calls timed
};

struct Report {
  std::string plugin;  ///< descriptor name
  std::string kind;    ///< plugin_kind_name()
  std::vector<CheckResult> checks;
  std::vector<Cost> costs;  ///< feature types only

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

/// The extractor ↔ feature contract (`mspace check EXTRACTOR.so FEATURE.so`,
/// mspace/scene.hpp): for each Extractor::sample_scene, the extractor's
/// measurements against the true features of FeatureType::from_true_shape
/// (|η_i|/σ_i ≤ 3 on noise-free readings, every true shape explained), and
/// create → add_dense_information → extend → innovation ≈ 0 for each of them.
/// SKIPs, saying why, when either plugin lacks its half. Options::params go to
/// whichever of the two declares them.
Report check_pair(const PluginDescriptor& extractor, const PluginDescriptor& feature, const Options& options = {});

/// One line per check: "PASS  name  worst 1.2e-09  (tol ≤ 1e-06)  note",
/// then one line per Cost.
void print_report(const Report& report, std::ostream& out);

/// JUnit XML (one <testsuite> per report, one <testcase> per check).
void write_junit(const std::vector<Report>& reports, std::ostream& out);

}  // namespace mspace::conformance
