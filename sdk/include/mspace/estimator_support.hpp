// mspace/estimator_support.hpp — input checks and observation stacking shared
// by the estimator plugins (ekf, cekf).
//
// Every check throws std::invalid_argument with a message that starts with the
// caller's `context` (e.g. "ekf update: observation 2") and names the matrix
// and the row, e.g. "ekf update: observation 2: J row 1 is not finite".
#pragma once

#include <Eigen/Core>
#include <string>
#include <vector>

#include "mspace/estimator.hpp"
#include "mspace/state.hpp"

namespace mspace::estimator_support {

/// "rows x cols".
std::string size_text(Eigen::Index rows, Eigen::Index cols);

/// Throws naming the first row of `m` that holds a NaN or an infinity:
/// "<context>: <name> row <r> is not finite".
void require_finite(const Eigen::Ref<const Eigen::MatrixXd>& m, const std::string& context, const char* name);

/// Throws unless `m` is rows × cols: "<context>: <name> is 2 x 3, expected 3 x 3".
void require_size(const Eigen::MatrixXd& m, Eigen::Index rows, Eigen::Index cols, const std::string& context,
                  const char* name);

/// Throws unless every index lies in [0, n) and, with `distinct`, none appears twice.
void require_indices(const std::vector<int>& idx, int n, const std::string& context, bool distinct);

/// P_rr of a reset: square and finite.
void validate_reset(const Eigen::MatrixXd& P_rr, const std::string& context);

/// Sizes, indices (in [0, n), distinct) and finiteness of one observation.
void validate_observation(const LinearizedObservation& o, int n, const std::string& context);

/// Sizes, indices (in [0, n), repeats allowed) and finiteness of an augmentation.
void validate_augmentation(const StateAugmentation& aug, int n, const std::string& context);

/// J_rr and Q of a robot prediction: both k × k and finite.
void validate_prediction(const Eigen::MatrixXd& J_rr, const Eigen::MatrixXd& Q, int k, const std::string& context);

/// Indices of a removal: in [0, n), distinct, none of them a robot row (< k).
void validate_removal(const std::vector<int>& idx, int n, int k, const std::string& context);

/// The unobservable directions U (dim × u, one column per direction) of an
/// observability-constrained filter (Huang, Mourikis & Roumeliotis,
/// "Observability-based rules for designing consistent EKF SLAM estimators",
/// IJRR 2010), carried row for row with the state perturbation (T-RO 2007
/// eq. 23): the robot rows move with the prediction, new rows come with an
/// augmentation, removed rows go. constrain() then makes every observation's
/// Jacobian annihilate U, so no update informs the unobservable directions.
/// Shared by the ekf and cekf plugins; U does not depend on how a filter
/// stores its covariance.
class UnobservableDirections {
 public:
  /// k robot rows and no direction (u = 0): constrain() changes nothing.
  void reset(int k);
  /// Replaces the robot rows by U_r (k × u, finite; throws naming `context`
  /// as the checks above do). The other rows keep their values when u is
  /// unchanged and start at zero otherwise.
  void set_robot_rows(const Eigen::MatrixXd& U_r, const std::string& context);
  /// Estimator::set_unobservable's two forms: U with the robot's k rows
  /// (set_robot_rows) or with every row (rows() × u, replacing all of U, e.g.
  /// the directions at re-linearised values).
  void set(const Eigen::MatrixXd& U, const std::string& context);
  /// U_r ← J_rr U_r (J_rr of eq. 26, already checked by the caller).
  void predict(const Eigen::MatrixXd& J_rr);
  /// Appends the rows aug.J U[aug.idx] of the new state rows (aug checked by the caller).
  void augment(const StateAugmentation& aug);
  /// Keeps the rows `keep` (ascending), in that order.
  void keep_rows(const std::vector<int>& keep);
  /// The observations with every J replaced by J − J U_i (U_iᵀ U_i)⁺ U_iᵀ,
  /// U_i = U[idx] (see annihilating()). Each observation is validated first
  /// against the state dimension (context "<context>: observation <i>").
  /// With u = 0 they come back unchanged.
  std::vector<LinearizedObservation> constrain(const std::vector<LinearizedObservation>& obs,
                                               const std::string& context) const;
  /// U (dim × u).
  const Eigen::MatrixXd& matrix() const { return U_; }
  /// u.
  Eigen::Index directions() const { return U_.cols(); }
  /// Checkpoints: writes k and U as "<prefix>k", "<prefix>U".
  void save(StateWriter& out, const std::string& prefix) const;
  /// Reads what save() wrote; U must have `rows` rows and be finite
  /// (std::invalid_argument naming `context` otherwise).
  void restore(const StateReader& in, const std::string& prefix, Eigen::Index rows, const std::string& context);

 private:
  int k_ = 0;
  Eigen::MatrixXd U_;
};

/// Checkpoints of a symmetric matrix kept as the lower triangle of a larger
/// store (ekf, cekf): the lower triangle of the top-left n × n block of
/// `store`, column by column, as one column of n(n+1)/2 numbers (half the
/// size of the square; the store's upper triangle is never written).
Eigen::MatrixXd pack_lower(const Eigen::MatrixXd& store, Eigen::Index n);
/// Writes what pack_lower() gave into the lower triangle of the top-left
/// n × n block of `store`; std::invalid_argument (naming `context`) when
/// `packed` is not n(n+1)/2 × 1 or not finite.
void unpack_lower(const Eigen::MatrixXd& packed, Eigen::Index n, Eigen::MatrixXd& store, const std::string& context);

/// The saved shape of a store: "<name>_capacity" (rows, cols). Restoring the
/// same capacity keeps every later operation on the same memory layout, so a
/// resumed filter computes bit for bit as the saved one would have.
void save_capacity(StateWriter& out, const std::string& name, const Eigen::MatrixXd& store);
/// A zero matrix of the saved capacity, which must hold at least rows × cols.
Eigen::MatrixXd restore_capacity(const StateReader& in, const std::string& name, Eigen::Index rows,
                                 Eigen::Index cols, const std::string& context);

/// The nearest J' to J (row by row) with J' U = 0: each row loses its
/// component in the column space of U, J' = J − J U (Uᵀ U)⁺ Uᵀ. The
/// pseudo-inverse copes with a U of deficient rank (e.g. a one-row U).
Eigen::MatrixXd annihilating(const Eigen::MatrixXd& J, const Eigen::MatrixXd& U);

/// All observations of one step as one measurement over the union I of their
/// state indices: η = J_I δx[I] + noise with block-diagonal C_eta.
struct StackedObservation {
  std::vector<int> union_idx;  ///< I, sorted ascending
  Eigen::VectorXd eta;         ///< m
  Eigen::MatrixXd J;           ///< m × |I|
  Eigen::MatrixXd C_eta;       ///< m × m
};

/// Validates every observation (context "<context>: observation <i>") against a
/// state of dimension n, then stacks them. No observations give m = 0.
StackedObservation stack_observations(const std::vector<LinearizedObservation>& obs, int n, const std::string& context);

}  // namespace mspace::estimator_support
