// conformance_internal.hpp — helpers shared by the conformance checks
// (sdk/src/conformance*.cpp); not installed.
#pragma once

#include <cstdint>
#include <exception>
#include <functional>
#include <random>
#include <string>
#include <vector>

#include <Eigen/Core>

#include "mspace/conformance.hpp"
#include "mspace/plugin.hpp"

namespace mspace::conformance::detail {

/// Collects the results of the named checks; each name keeps its worst value.
class Recorder {
 public:
  /// A value that must stay ≤ tolerance (an error, a count of violations).
  /// With always_show_note the note is kept (and printed) on a pass too.
  void at_most(const std::string& name, double value, double tolerance, const std::string& note = {},
               bool always_show_note = false);
  /// A value that must stay ≥ tolerance (e.g. an eigenvalue ratio).
  void at_least(const std::string& name, double value, double tolerance, const std::string& note = {});
  /// A check that failed outright (an exception, a missing result).
  void fail(const std::string& name, const std::string& note);
  /// Marks a check as skipped unless it already has a result.
  void skip(const std::string& name, const std::string& note);
  std::vector<CheckResult> take() { return std::move(checks_); }

  /// Adds `calls` timed calls of c.function (micros and evaluations are per
  /// call); the Jacobian lists are merged.
  void cost(const Cost& c);
  std::vector<Cost> take_costs() { return std::move(costs_); }

 private:
  void add(const std::string& name, double value, double tolerance, bool lower_is_better,
           const std::string& note);
  CheckResult* find(const std::string& name);
  std::vector<CheckResult> checks_;
  std::vector<Cost> costs_;
};

/// Runs `f`, turning an exception into a failure of check `name`.
template <class F>
void guarded(Recorder& r, const std::string& name, F&& f) {
  try {
    f();
  } catch (const std::exception& e) {
    r.fail(name, std::string("threw: ") + e.what());
  } catch (...) {
    r.fail(name, "threw a non-standard exception");
  }
}

using Rng = std::mt19937_64;
double uniform(Rng& rng, double lo, double hi);
/// A random symmetric positive-definite n × n matrix with eigenvalues in [lo, hi].
Eigen::MatrixXd random_spd(Rng& rng, int n, double lo, double hi);

/// Step of the central differences.
inline constexpr double kStep = 1e-6;

/// Central-difference Jacobian of f at x (columns: ∂f/∂x_j).
Eigen::MatrixXd numeric_jacobian(const std::function<Eigen::VectorXd(const Eigen::VectorXd&)>& f,
                                 const Eigen::VectorXd& x, double h = kStep);

/// Rows whose entries are all below this are compared as if their largest
/// entry were this (absolute error ≤ tolerance × kRowFloor).
inline constexpr double kRowFloor = 1e-3;

/// The worst row of max_j|A_ij − N_ij| / max(max_j|A_ij|, max_j|N_ij|, kRowFloor):
/// each row (one component of η or of the new coordinates, with its own unit)
/// is compared relative to its own size, so small Jacobians are not waved
/// through at an absolute tolerance. +inf on a size mismatch, NaN if anything
/// is NaN.
double relative_error(const Eigen::MatrixXd& analytic, const Eigen::MatrixXd& numeric);

/// How far a covariance C is from the expected one E: the largest |λ − 1|
/// and |1/λ − 1| over the generalised eigenvalues λ of (C, E) (0 when equal,
/// 49 for C = 50·E or E/50). When E is singular, the relative difference
/// max|C − E| / max|E|. +inf on a size mismatch or non-finite values.
double covariance_mismatch(const Eigen::MatrixXd& C, const Eigen::MatrixXd& E);

/// λ_min / λ_max of the symmetric part, or −inf if the matrix is not square,
/// not symmetric (relative 1e-9) or not finite.
double spd_ratio(const Eigen::MatrixXd& m);

// The checks per plugin kind (each in its own source file).
void check_feature_type(PluginObject& object, const Options& options, Recorder& r);
void check_motion_model(PluginObject& object, const Options& options, Recorder& r);
void check_estimator(PluginObject& object, const Options& options, Recorder& r);
void check_extractor(PluginObject& object, const Options& options, Recorder& r);
/// The parameters the suite creates instances with: the plugin's defaults
/// and Options::params over them. Throws std::invalid_argument for an unknown
/// parameter, a bad value, or a required parameter left unset.
Params instance_params(const PluginDescriptor& descriptor, const Options& options);

void check_source(const PluginDescriptor& descriptor, PluginObject& object, const Options& options,
                  Recorder& r);

}  // namespace mspace::conformance::detail
