// mspace/problem.hpp — the nonlinear SLAM problem the kernel keeps for a
// re-linearising estimator (e.g. the `smoother` plugin).
//
// An EKF linearises every measurement once, at the estimate of its step, and
// can never undo it (T-RO 2007 §V-B). A smoother keeps the nonlinear problem
// and re-evaluates it at better estimates, as the authors' Graphical SLAM did.
// The M-space representation is orthogonal to that choice: the variables are
// still the robot poses and the features' M-space perturbations δx_p, and the
// retraction of a feature is eq. 24, x_f ← x_f + B̃(x_f) δx_p, with B̃
// re-evaluated at the new x_f (the tangent space of a Ceres-style Manifold).
//
// Variables (all perturbations, one tangent vector δ of size tangent_dim()):
//   [0, k)             the current robot pose (the estimator's robot rows);
//   [k, state_dim())   the M-space rows in the estimator's own order (the
//                      same indices as Estimator::update/augment use; a shared
//                      coordinate, T-RO §VI, is one set of rows used by all its
//                      member features);
//   [state_dim(), tangent_dim())  the earlier robot pose nodes, k rows each,
//                      oldest first (pose_node_index()).
// So the marginal of [0, state_dim()) of the problem's information matrix is
// exactly what an EKF over the same rows would hold.
//
// Pose nodes: the kernel adds one node for every step with sensor readings
// (key poses); the odometry of the steps between two nodes is kept, so the
// motion factor re-runs the MotionModel plugin from the earlier node's value.
//
// Factors (each r = η(x) ≈ 0 with covariance C, linearised on request):
//   prior        on the first node: x_0 − x̂_0, C = the initial covariance;
//   motion       x_j − g(x_i, u_i+1, …, u_j) over the estimated pose
//                coordinates, g the motion model run step by step, J_i = −∏ J_rr,
//                C accumulated as J_rr C J_rrᵀ + J_rd C_d J_rdᵀ (eqs. 25–27);
//   observation  a feature's innovation η(x_o, v) for a stored measurement v,
//                x_o = T(x_f | x_node ⊕ x_rs) (eqs. 7–9, 17), J = J_ηo (J_os J_sr
//                J_of B̃) (eq. 30), C = J_ηv C_v J_ηvᵀ; re-evaluated in full
//                while its feature keeps the M-space rows it had when the
//                factor was recorded;
//   linear       a fixed linearisation r = η_0 + J (x ⊟ x_0): the prior of an
//                extension's new dimensions (δx_new = J_sensor δx_ms + J_own
//                δx_p,old + w, C_new), and every observation factor whose
//                feature has since extended or joined (frozen at its last
//                linearisation — see docs/writing-an-estimator.md);
//   coincidence  two features are one object (a loop closure by map
//                matching): the difference of their coordinates with their
//                symmetry directions projected out, re-evaluated in full; or
//                a pose relation (a closure the range scans placed): one
//                pose node seen from an older one, planar, re-evaluated in full.
#pragma once

#include <cstdint>
#include <vector>

#include <Eigen/Core>

namespace mspace {

enum class FactorKind : std::uint8_t { Prior, Motion, Observation, Linear, Coincidence };
/// Number of FactorKind values (for per-kind tables).
inline constexpr int kFactorKinds = 5;

/// One factor linearised at the problem's current values:
/// r ≈ eta + J · δ[idx], r ~ N(0, C).
struct FactorLinearization {
  FactorKind kind = FactorKind::Linear;
  Eigen::VectorXd eta;   ///< m (the residual at the current values)
  Eigen::MatrixXd C;     ///< m × m, symmetric positive definite
  std::vector<int> idx;  ///< tangent indices, distinct
  Eigen::MatrixXd J;     ///< m × idx.size()
  /// May be down-weighted by a robust loss (observations: a wrong
  /// association is possible); priors, motion and linear factors are not.
  bool robust = false;
};

/// The kernel's nonlinear problem, handed to Estimator::relinearize().
class NonlinearProblem {
 public:
  virtual ~NonlinearProblem() = default;
  /// k: rows of one robot pose.
  virtual int robot_dim() const = 0;
  /// The estimator's state dimension: current pose plus every M-space row.
  virtual int state_dim() const = 0;
  /// state_dim() + k × (pose nodes − 1).
  virtual int tangent_dim() const = 0;
  /// Pose nodes, the current one included (0 before the first reading).
  virtual int num_pose_nodes() const = 0;
  /// First tangent index of pose node `node` (0 = the oldest): 0 for the
  /// newest (the current pose), state_dim() + k·node for the others.
  virtual int pose_node_index(int node) const = 0;
  virtual int num_factors() const = 0;
  /// Linearises factor `i` at the current values; false when it has no rows
  /// now (e.g. a feature rejects the stored measurement at the current
  /// values), `out` is then left empty.
  virtual bool linearize(int i, FactorLinearization& out) = 0;
  /// Moves every variable: pose nodes by δ (angles wrapped), features by eq. 24
  /// with their rows of δ (shared coordinates through every member), and the
  /// kernel's current robot pose with the rows [0, k). δ has tangent_dim() rows.
  virtual void retract(const Eigen::VectorXd& delta) = 0;
  /// Loop closures the kernel has added so far (coincidence factors from map
  /// matching). The variables have been moved to a first guess; an estimator
  /// that sees the count grow should re-optimise now.
  virtual int loop_closures() const { return 0; }
};

}  // namespace mspace
