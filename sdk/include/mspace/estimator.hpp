// mspace/estimator.hpp — estimators over robot pose and M-space perturbations.
//
// The state (eq. 23) is δx_state = (δx_r, δx_p): the robot's estimated pose
// coordinates first (indices 0..k−1), then the M-space perturbations of every
// feature, appended as features extend. The estimator never sees x_f; it
// returns perturbations that the kernel hands to the features (eq. 24).
#pragma once

#include <vector>

#include <Eigen/Core>

#include "mspace/plugin.hpp"
#include "mspace/problem.hpp"

namespace mspace {

/// One linearised measurement that touches only a few state indices:
/// η ≈ J · δx_state[idx] + noise with covariance C_eta (eqs. 29–30).
struct LinearizedObservation {
  Eigen::VectorXd eta;      ///< m
  Eigen::MatrixXd C_eta;    ///< m × m  (J_ηv C_v J_ηvᵀ)
  std::vector<int> idx;     ///< state indices, distinct
  Eigen::MatrixXd J;        ///< m × idx.size()
};

/// New state rows: δx_new = J · δx_state[idx] + w, w ~ N(0, C_new).
struct StateAugmentation {
  std::vector<int> idx;     ///< existing state indices the new rows depend on
  Eigen::MatrixXd J;        ///< new × idx.size() (may have zero columns)
  Eigen::MatrixXd C_new;    ///< new × new
};

class Estimator : public PluginObject {
 public:
  /// Starts over with a robot block of covariance P_rr (k × k) and no features.
  virtual void reset(const Eigen::MatrixXd& P_rr) = 0;
  /// Current state dimension.
  virtual int dim() const = 0;
  /// Robot block prediction, eqs. 26–27: C_rr ← J_rr C_rr J_rrᵀ + Q,
  /// C_rp ← J_rr C_rp. Q = J_rd C_d J_rdᵀ.
  virtual void predict(const Eigen::MatrixXd& J_rr, const Eigen::MatrixXd& Q) = 0;
  /// Applies all observations of one step (eqs. 28–32) and returns the state
  /// perturbation δx_state (size dim()) to be applied by the caller.
  virtual Eigen::VectorXd update(const std::vector<LinearizedObservation>& obs) = 0;
  /// Appends rows; returns the index of the first new one.
  virtual int augment(const StateAugmentation& aug) = 0;
  /// Covariance of the given indices (|idx| × |idx|).
  virtual Eigen::MatrixXd marginal(const std::vector<int>& idx) const = 0;
  /// Cross-covariance C[rows, cols].
  virtual Eigen::MatrixXd cross(const std::vector<int>& rows, const std::vector<int>& cols) const = 0;
  /// Removes the given indices (features dropped from the map); later indices shift down.
  virtual void remove(std::vector<int> idx) = 0;
  /// The directions of the robot block (k × u, one column each) along which
  /// the state is unobservable: a global rigid motion of robot and map, e.g.
  /// translation along x and y and rotation about the map's z axis, evaluated
  /// at the current pose. The kernel calls it right after reset(). Estimators
  /// that constrain their updates to leave these directions uninformed (the
  /// observability-constrained EKF of Huang, Mourikis & Roumeliotis,
  /// "Observability-based rules for designing consistent EKF SLAM
  /// estimators", IJRR 2010) carry them through predict, augment and remove;
  /// the others ignore them. For an estimator that re-linearises
  /// (wants_problem()), the kernel calls it again after every relinearize()
  /// that moved the estimate, with every row (dim() × u): the directions at
  /// the new values (each feature's rows: B(x_f) times the motion of its
  /// point blocks), which replace those carried from the first estimates
  /// (SDK 6.1).
  virtual void set_unobservable(const Eigen::MatrixXd& /*U_r*/) {}

  // ---- Re-linearisation (mspace/problem.hpp) --------------------------------
  //
  // An estimator that re-linearises (a smoother) says so here; the kernel then
  // records the nonlinear problem — pose nodes, motion, observation and
  // linear factors — alongside the calls above. Filters keep the default and
  // the kernel records nothing, so they pay nothing for it.
  virtual bool wants_problem() const { return false; }
  /// Called when wants_problem(): after phase 4 (extend and shared
  /// coordinates) of every step that added a pose node, and once more with
  /// end_of_data when the data ends (the last chance to optimise). The
  /// estimator may linearise any factor at the current values and move every
  /// variable with problem.retract() (as often as it iterates); it must leave
  /// its own covariance over [0, dim()) consistent with the values it leaves
  /// behind. Returns true when it moved anything: the kernel then takes the
  /// current robot pose and the pose nodes (the smoothed trajectory) from the
  /// problem.
  virtual bool relinearize(NonlinearProblem& /*problem*/, bool /*end_of_data*/) { return false; }
};

}  // namespace mspace
