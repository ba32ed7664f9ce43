// covariance_health.hpp — the numerical health of the estimator's covariance
// (issue 11 item 7, docs/reliability.md "Numerical health").
//
// Two checks, through nothing but Estimator::marginal():
//  * after every update, the block of the state rows the update touched (the
//    robot and the observed features) must be symmetric and have a Cholesky
//    factor — cheap, the size of one step's observations;
//  * every `full_every` steps (run.health_check_every; 0, the default: never)
//    and at the end of the run, the whole covariance: its asymmetry and its
//    extreme eigenvalues (O(n³), hence not every step; covariance_figures).
// What they find goes to the run summary (covariance_health); the first block
// that is not positive definite is a warning in the log. NaN, infinity or a
// block of the wrong size is not a health figure but a broken estimator: the
// kernel stops the run naming it (Slam::check_covariance_block).
#pragma once

#include <cstdint>
#include <limits>
#include <string>

#include <Eigen/Core>

#include "mspace/state.hpp"

namespace mspace::kernel {

/// What the checks found so far.
struct CovarianceHealthReport {
  std::int64_t block_checks = 0;       ///< touched blocks checked (one per update)
  std::int64_t blocks_not_pd = 0;      ///< of them without a Cholesky factor
  std::int64_t first_not_pd_step = -1; ///< step of the first such block (−1: none)
  std::int64_t full_checks = 0;        ///< whole-covariance checks
  /// Smallest eigenvalue seen in a whole-covariance check, relative to the
  /// largest of the same check (λ_min/λ_max), and its step; NaN before any.
  double min_eigenvalue = std::numeric_limits<double>::quiet_NaN();
  double min_relative_eigenvalue = std::numeric_limits<double>::quiet_NaN();
  std::int64_t min_eigenvalue_step = -1;
  /// Largest max|C − Cᵀ| / max|C| of any block or whole covariance checked.
  double max_asymmetry = 0.0;
};

/// The whole-covariance figures of one matrix.
struct CovarianceFigures {
  double min_eigenvalue = 0.0;
  double max_eigenvalue = 0.0;
  double asymmetry = 0.0;  ///< max|C − Cᵀ| / max|C| (0 for a zero matrix)
};

/// Extreme eigenvalues of the symmetric part of C, and C's asymmetry; C must
/// be square. Exact up to 300 rows and for a matrix that is not positive
/// definite; beyond, for a positive definite one (Cholesky), 60 steps of
/// power and inverse iteration (Rayleigh quotients: the smallest is an upper
/// bound, exact when converged), O(n³/3) for the factor instead of the
/// several times more of a full eigen-decomposition.
CovarianceFigures covariance_figures(const Eigen::MatrixXd& C);

class CovarianceHealth {
 public:
  /// `full_every`: steps between whole-covariance checks (0: none).
  explicit CovarianceHealth(std::int64_t full_every = 0) : full_every_(full_every) {}

  /// Checks a touched block after an update of step `step`; returns a warning
  /// for the log the first time a block is not positive definite, else "".
  std::string check_block(const Eigen::MatrixXd& block, std::int64_t step);
  /// Whether step `step` is due for a whole-covariance check.
  bool full_check_due(std::int64_t step) const { return full_every_ > 0 && step % full_every_ == 0; }
  /// Records the figures of a whole-covariance check at `step`.
  void record_full(const CovarianceFigures& f, std::int64_t step);

  const CovarianceHealthReport& report() const { return r_; }

  /// Checkpoints (kernel/src/checkpoint.cpp): under `prefix`.
  void save(StateWriter& out, const std::string& prefix) const;
  void restore(const StateReader& in, const std::string& prefix);

 private:
  std::int64_t full_every_;
  CovarianceHealthReport r_;
};

}  // namespace mspace::kernel
