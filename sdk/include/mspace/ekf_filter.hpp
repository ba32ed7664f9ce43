// mspace/ekf_filter.hpp — the M-space extended Kalman filter (T-RO 2007, §V-B),
// in the SDK library because two estimator plugins use it: `ekf` and the
// `smoother` (its running covariance for gating between re-optimisations).
//
// The filter estimates the covariance of the state perturbation (eq. 23)
//
//   δx_state = (δx_r, δx_p)
//
// robot pose coordinates first (indices 0..k−1, set by reset()), then the
// M-space perturbations of the features in the order augment() appended them.
// There is no state vector and no feature coordinate in here: update() returns
// δx_state and the caller moves the robot and hands δx_p to the features
// (eq. 24).
//
// Storage. The symmetric covariance C_state is kept as the lower triangle of
// the top-left dim()×dim() block of a square capacity×capacity matrix; the
// strict upper triangle is never read or written. The capacity doubles when
// augment() needs more room, so appending rows costs amortised O(N·new).
//
// Symmetric inputs (P_rr, Q, C_eta, C_new) are read from their lower triangle.
//
// Observability-constrained mode (optional; Huang, Mourikis & Roumeliotis,
// "Observability-based rules for designing consistent EKF SLAM estimators",
// IJRR 2010). The global rigid motion of robot and map is unobservable, but
// the plain EKF, which linearises each step at a different estimate, gains
// spurious information along it and becomes overconfident. In this mode the
// filter carries the unobservable directions U (dim() × u, one column per
// direction) exactly as the covariance carries the state: set_unobservable()
// gives the robot's rows, predict() maps them (U_r ← J_rr U_r, eq. 26's
// J_rr), augment() appends J U[idx] for the new rows, remove() drops rows. Each
// observation's Jacobian is replaced by the nearest one (row by row, within
// its own columns) that annihilates U[idx]: J ← J − J U_i (U_iᵀ U_i)⁺ U_iᵀ, so
// no update informs the unobservable directions. Without set_unobservable()
// (u = 0) it behaves as the plain filter.
//
// Errors (all thrown before anything is changed):
//   std::invalid_argument — wrong sizes, indices out of range or repeated, or a
//     non-finite entry; the message names the matrix and the row, e.g.
//     "ekf update: observation 2: J row 1 is not finite".
//   std::runtime_error — the innovation covariance is not positive definite:
//     "ekf update: S (6 x 6) is not positive definite".
#pragma once

#include <Eigen/Core>
#include <vector>

#include "mspace/estimator.hpp"
#include "mspace/estimator_support.hpp"

namespace mspace::ekf {

class EkfFilter final : public Estimator {
 public:
  /// `initial_capacity`: state rows to allocate room for at reset() (≥ 1);
  /// `observability_constrained`: the mode described above.
  explicit EkfFilter(int initial_capacity = 64, bool observability_constrained = false);

  void reset(const Eigen::MatrixXd& P_rr) override;
  int dim() const override { return n_; }
  void predict(const Eigen::MatrixXd& J_rr, const Eigen::MatrixXd& Q) override;
  Eigen::VectorXd update(const std::vector<LinearizedObservation>& obs) override;
  int augment(const StateAugmentation& aug) override;
  Eigen::MatrixXd marginal(const std::vector<int>& idx) const override;
  Eigen::MatrixXd cross(const std::vector<int>& rows, const std::vector<int>& cols) const override;
  void remove(std::vector<int> idx) override;
  /// Observability-constrained mode only (ignored otherwise): replaces the
  /// robot's rows of U by U_r (robot_dim() × u). Feature rows keep their
  /// propagated values when u is unchanged and start at zero otherwise.
  void set_unobservable(const Eigen::MatrixXd& U_r) override;

  /// Checkpoints: the covariance (lower triangle of the dim() × dim() block),
  /// the robot dimension, the storage capacity and U; restored exactly.
  bool has_state() const override { return true; }
  void save_state(StateWriter& out) const override;
  void restore_state(const StateReader& in, int version) override;

  /// Robot pose dimension k given to reset().
  int robot_dim() const { return k_; }
  /// State rows the storage holds before it has to grow.
  int capacity() const { return static_cast<int>(store_.rows()); }
  /// Grows the storage to hold at least `rows` state rows (never shrinks).
  void reserve(int rows);
  /// The whole covariance C_state (dim() × dim()), for tests and diagnostics.
  Eigen::MatrixXd covariance() const;
  /// Replaces the whole covariance by C (dim() × dim(), symmetric, read from
  /// its lower triangle), e.g. the marginal of an optimised information
  /// matrix (the smoother). The state dimension and U stay as they are.
  void assign(const Eigen::MatrixXd& C);
  bool observability_constrained() const { return constrained_; }
  /// The unobservable directions U (dim() × u) in observability-constrained
  /// mode; 0 × 0 otherwise.
  const Eigen::MatrixXd& unobservable() const { return U_.matrix(); }

 private:
  /// C_state(i, j) read from the lower triangle.
  double at(int i, int j) const { return i >= j ? store_(i, j) : store_(j, i); }
  /// C_state[:, cols] (dim() × cols.size()).
  Eigen::MatrixXd gather_columns(const std::vector<int>& cols) const;
  /// eqs. 28–32 for the given (possibly constrained) observations.
  Eigen::VectorXd apply_update(const std::vector<LinearizedObservation>& obs);

  int initial_capacity_;
  bool constrained_;       ///< observability-constrained mode
  estimator_support::UnobservableDirections U_;  ///< dim() × u (constrained mode only)
  int k_ = 0;              ///< robot pose dimension
  int n_ = 0;              ///< state dimension
  Eigen::MatrixXd store_;  ///< capacity × capacity; lower triangle of [0,n_)² is C_state
};

}  // namespace mspace::ekf
