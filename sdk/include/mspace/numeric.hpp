// mspace/numeric.hpp — numeric Jacobians by central differences, so a new
// feature type can start without writing any derivative by hand and replace
// them with analytic ones one at a time (docs/writing-a-feature-plugin.md §8).
//
// Every helper differentiates a function the author writes anyway (the
// residual η(x_o, v), the new M-space coordinates of an extension as a
// function of the sensor pose, …):
//
//   J(:, j) = (f(x + h_j e_j) − f(x − h_j e_j)) / (2 h_j),
//   h_j = relative_step · max(|x_j|, scale_j)      (scale_j default 1),
//
// i.e. a step relative to the coordinate's own size, about ∛ε·|x_j| — the step
// that balances truncation against rounding, ~1e-10 relative error for smooth
// functions. Rows listed in NumericOptions::angle_rows are differenced with
// the result wrapped into (−π, π], so a bearing residual near ±π still gives
// the right slope.
//
// The helpers record, per thread, which Jacobian they produced, how many
// function evaluations it took and how long it took (numeric_usage()):
// `mspace check` reads this to report which of a plugin's Jacobians are
// numeric and what they cost per call. Nothing here changes the plugin ABI:
// the plugin calls the helpers from its own innovation()/extend().
#pragma once

#include <functional>
#include <vector>

#include <Eigen/Core>

#include "mspace/feature.hpp"

namespace mspace {

/// Which Jacobian a numeric helper computes (for the report of `mspace check`).
enum class NumericJacobian {
  eta_o = 0,    ///< Innovation::J_eta_o
  eta_v,        ///< Innovation::J_eta_v
  sensor,       ///< Extension::J_sensor
  own,          ///< Extension::J_own
  measurement,  ///< ∂(new coordinates)/∂v of an extension, for C_new = J_v C_v J_vᵀ
  other,        ///< anything else (a placement, a gating covariance, …)
};
inline constexpr int kNumericJacobianCount = 6;
/// "J_eta_o", "J_eta_v", "J_sensor", "J_own", "J_measurement", "other".
const char* numeric_jacobian_name(NumericJacobian which);

struct NumericOptions {
  /// h_j = relative_step · max(|x_j|, scale_j); ∛ε by default.
  double relative_step = 6.0554544523933395e-06;
  /// Per-coordinate scale (empty: 1 for every coordinate). Give the size a
  /// coordinate typically has when 1 is far off (e.g. 1e-3 for a radius in
  /// metres of a millimetre-sized object).
  Eigen::VectorXd scale{};
  /// Rows of f that are angles: their differences are wrapped into (−π, π].
  std::vector<int> angle_rows{};
};

/// A function of a vector; returns false when it cannot be evaluated there
/// (e.g. a point behind the sensor).
using NumericFunction = std::function<bool(const Eigen::VectorXd& x, Eigen::VectorXd& f)>;

/// Central-difference Jacobian of f at x (f(x) must be evaluable; where
/// f(x ± h e_j) is not, the one-sided difference on the other side is used).
/// Throws std::runtime_error when f fails at x or on both sides of a
/// coordinate, or changes its size. Recorded as `which`.
Eigen::MatrixXd numeric_jacobian(NumericJacobian which, const NumericFunction& f, const Eigen::VectorXd& x,
                                 const NumericOptions& options = {});

/// The residual of a feature type: η for the feature at x_o (sensor frame)
/// and the measurement vector v; false when v cannot belong to the feature.
using Residual = std::function<bool(const Eigen::VectorXd& x_o, const Eigen::VectorXd& v, Eigen::VectorXd& eta)>;

/// Which Jacobians numeric_innovation() fills by differences (a bit mask).
enum NumericInnovationParts : unsigned {
  kNumericEtaO = 1u,  ///< J_eta_o by differences of the residual in x_o
  kNumericEtaV = 2u,  ///< J_eta_v by differences of the residual in v
  kNumericBoth = 3u,
};

/// Feature::innovation() from a residual: out.eta = residual(x_o, v) and, for
/// the parts in `parts`, J_eta_o / J_eta_v by central differences (the other
/// Jacobian is left as it is, for the caller to fill analytically). Returns
/// false when the residual rejects (x_o, v) or cannot be differenced there.
/// options.scale, if given, is for x_o; v is differenced with scale 1.
bool numeric_innovation(const Residual& residual, const Eigen::VectorXd& x_o, const Eigen::VectorXd& v,
                        Innovation& out, unsigned parts = kNumericBoth, const NumericOptions& options = {});

/// What the numeric helpers did on the calling thread since the last
/// reset_numeric_usage(), per NumericJacobian.
struct NumericUsage {
  long calls = 0;        ///< Jacobians computed
  long evaluations = 0;  ///< function evaluations they took
  double seconds = 0.0;  ///< time spent in the helpers (wall clock)
};
NumericUsage numeric_usage(NumericJacobian which);
void reset_numeric_usage();

}  // namespace mspace
