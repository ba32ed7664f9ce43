// problem.hpp — the nonlinear SLAM problem (pose nodes and factors) the
// kernel records for an estimator that re-linearises (mspace/problem.hpp).
//
// Recorded only when the estimator's wants_problem() is true: the EKF family
// pays nothing. Slam calls one method per phase:
//   predict   motion()      stores the step's odometry increment (and fixes
//                           the value of the newest node before it moves);
//             key_pose()    a step with readings: a new pose node, the motion
//                           factor from the previous node over the stored
//                           increments;
//   update    observed()    one observation factor per matched feature in the
//                           estimator, with the EKF's linearisation as its
//                           first one; moved() accumulates the update;
//   extend    extended()    the extension's prior as a linear factor; every
//                           live factor of the feature is frozen;
//   join      before_join() / joined(): the change of variables of T-RO §VI;
//             removed()     renumbers rows;
//   end       end_of_step() hands the problem to Estimator::relinearize().
//
// The frozen-factor rule. An observation factor is re-linearised in full only
// while its feature keeps the M-space rows (and dimension) it had when the
// factor was recorded. When the feature extends or joins, the factor is
// frozen at its last linearisation (η, J at the values of that moment) and
// from then on is the linear factor r = η + J (x ⊟ x_lin) on the accumulated
// perturbations of the rows it touched — as a marginalisation prior would be.
// It must not inform the new dimensions: the extension's prior (built from the
// dense information) already holds that evidence, and the innovation may even
// have other rows at the higher dimension (e.g. end-point rows once a
// segment's ends enter its M-space).
//
// With Context::freeze_in_sensor_frame (problem.freeze_in_sensor_frame) the
// frozen factor is linear in the feature's coordinates *seen from its
// sensor*: r = η + G (x_o − x_o,frozen), x_o the feature in the sensor frame
// of its pose node now (eqs. 7–9), G = J_f B_old J_of⁻¹ — what it measured of
// the old M-space (eq. 10). What it measures is relative, so moving node and
// feature rigidly together changes nothing, whereas the world-frame form sees
// a rigid turn through its second-order error (θ²/2 × the range) and resists
// it. The extension's prior is kept the same way in the robot's frame. A
// factor without a snapshot of its feature from before the change
// (before_extend, before_join) or without the robot keeps the world form.
#pragma once

#include <cstdint>
#include <functional>
#include <memory>
#include <optional>
#include <unordered_map>
#include <vector>

#include <Eigen/Core>

#include "mspace/estimator.hpp"
#include "mspace/feature.hpp"
#include "mspace/motion_model.hpp"
#include "mspace/problem.hpp"
#include "evaluation.hpp"
#include "loop_closing.hpp"
#include "plugin_registry.hpp"

namespace mspace {
class StateWriter;
class StateReader;
}  // namespace mspace

namespace mspace::kernel {

struct MapFeature;
struct FeatureTypeSlot;

/// A feature as map matching sees it (loop_closing.hpp): type, layout, x_f and
/// its symmetry directions; no covariance.
FeatureShape feature_shape(const MapFeature& mf);
/// The same with its covariance: B̃ P_p B̃ᵀ from P_p, the covariance of its
/// M-space rows (eq. 11: δx_f = B̃ δx_p).
FeatureShape feature_shape(const MapFeature& mf, const Eigen::MatrixXd& P_p);

/// The coincidence of features a and b (one object, a loop closure) at their
/// current coordinates: r = Nᵀ (x_a − x_b) and J = Nᵀ (B̃_a  −B̃_b) over
/// `idx`, the union of their estimator rows (coincidence_residual,
/// loop_closing.hpp). False when nothing is left to compare.
bool linearize_coincidence(const MapFeature& a, const MapFeature& b, Eigen::VectorXd& r, Eigen::MatrixXd& J,
                           std::vector<int>& idx);

/// One step's odometry as a motion factor keeps it: x_d over dt, and its
/// covariance from the data when the source gave one (else empty: the motion
/// model's C_d).
struct OdometryIncrement {
  Eigen::VectorXd x_d;
  double dt = 0.0;
  Eigen::MatrixXd C_d;
};

class Problem final : public NonlinearProblem {
 public:
  /// The kernel state the problem reads and moves: the features (by
  /// reference: Slam keeps them), the current robot pose, the estimated pose
  /// coordinates, the sensor mounts, and the plugins it calls.
  struct Context {
    std::vector<MapFeature>* features = nullptr;
    const std::vector<FeatureTypeSlot>* types = nullptr;
    Pose6* x_r = nullptr;
    std::vector<int> dofs;
    std::vector<Pose6> mounts;  ///< x_rs by sensor index
    MotionModel* motion = nullptr;
    const LoadedPlugin* motion_lib = nullptr;
    std::string motion_instance;
    Estimator* estimator = nullptr;
    const LoadedPlugin* estimator_lib = nullptr;
    std::string estimator_instance;
    /// problem.freeze_in_sensor_frame (config.hpp): the frozen-factor rule's frame.
    bool freeze_in_sensor_frame = false;
  };

  explicit Problem(Context context);
  ~Problem() override;

  // ---- recording (Slam) ------------------------------------------------------
  /// The prior of the first pose node (the current pose) with covariance P0;
  /// called again before the first step (a loaded map moved the start), it
  /// starts afresh.
  void start(const Eigen::MatrixXd& P0);
  /// Before the robot moves by the odometry increment x_d over dt (empty: no
  /// motion); `record` is the index the step will have in the trajectory.
  /// C_d: the increment's covariance from the data (empty: the motion
  /// model's, see DataStep::odometry_covariance).
  void motion(const Eigen::VectorXd& x_d, double dt, std::size_t record, const Eigen::MatrixXd& C_d = {});
  /// The current pose becomes a pose node (no-op if it already is one);
  /// `record` is the index the step will have in the kernel's trajectory.
  void key_pose(std::size_t record);
  /// An observation factor: feature `mf` (dimension > 0) matched measurement
  /// `m` of sensor `sensor`; `in`, `C_eta`, `J_state` are the linearisation
  /// at the current values (J over robot rows then mf.state_idx, eq. 30).
  void observed(const MapFeature& mf, const Measurement& m, int sensor, const Innovation& in,
                const Eigen::MatrixXd& C_eta, const Eigen::MatrixXd& J_state);
  /// The estimator's update moved the robot and the M-space rows by dx.
  void moved(const Eigen::VectorXd& dx);
  /// `mf` extended: aug (over robot rows and the old rows) added rows
  /// [first, first + aug.C_new.rows()). Freezes mf's live factors.
  void extended(const MapFeature& mf, const StateAugmentation& aug, int first);
  /// Rows [first, first + aug.C_new.rows()) entered the estimator by `aug`
  /// (δx_new = J δx_old + w, w ~ N(0, C_new)): that relation as a linear
  /// factor. A loaded map enters this way (extend): the old session's poses
  /// are marginalised, its map is a Gaussian prior with the map's joint covariance.
  void added(const StateAugmentation& aug, int first);
  /// Before the feature's extend(): keeps its B(x_f) and x_f, with which its
  /// live factors are frozen in their sensor's frame (the frozen-factor rule).
  void before_extend(const MapFeature& mf);
  /// Before share_block: keeps B(x_f) (and x_f) of both features.
  void before_join(const MapFeature& a, const MapFeature& b);
  /// After the join's rows were added (a, b with their new state_idx) and
  /// before the rows `obsolete` are removed: freezes both features' live
  /// factors and rewrites every factor on an obsolete row through
  /// δp_old = B_old B̃_new δp_new.
  void joined(const MapFeature& a, const MapFeature& b, std::vector<int> obsolete);
  /// Estimator rows `rows` (sorted) were removed; later rows shift down.
  void removed(const std::vector<int>& rows);
  // ---- loop closure (Slam::close_loops, loop_closing.hpp) ---------------------
  /// A first guess after a loop closure: pose node i moves by
  /// node_motion(record of node i) (none: stays), the current pose by
  /// `current`, and every listed feature (index into the map) rigidly by its
  /// motion — through the retraction (eq. 24) with δx_p = B (x_target − x_f),
  /// repeated so that large rotations land (B is re-evaluated each time).
  void warp(const std::function<std::optional<PlanarMotion>(std::size_t record)>& node_motion,
            const PlanarMotion& current, const std::vector<std::pair<int, PlanarMotion>>& features);
  /// A coincidence factor: features `a` and `b` (ids) are one object,
  /// r = Nᵀ (x_a − x_b) ~ N(0, σ² I) with N the directions no symmetry of
  /// theirs leaves free (coincidence_residual), re-evaluated at every
  /// linearisation: J = Nᵀ (B̃_a  −B̃_b).
  void coincide(int a, int b, double sigma);
  /// A pose relation (a loop closure placed by the scans, where the features
  /// paired leave a direction free): pose node `to` seen from pose node
  /// `from`, planar, r = (x_from⁻¹ ⊕ x_to) − z over (x, y, θ) ~ N(0, C).
  /// Reported as a coincidence (FactorKind::Coincidence: a loop closure).
  void relate(int from, int to, const Eigen::Vector3d& z, const Eigen::Matrix3d& C);
  /// Loop closures recorded (NonlinearProblem::loop_closures).
  int loop_closures() const override { return loop_closures_; }
  /// Trajectory index of pose node `node`.
  std::size_t node_record(int node) const { return records_[static_cast<std::size_t>(node)]; }

  /// End of a step: when it added a pose node (or at the end of the data,
  /// `end_of_data`), Estimator::relinearize(). Returns true when the
  /// estimator moved the variables.
  bool end_of_step(bool end_of_data);
  /// Writes the pose nodes' current values into the recorded trajectory (and
  /// the evaluated one, x_r ⊕ x_rs with `eval_mount` when given): what a
  /// smoother reports is its smoothed trajectory. A step between two nodes
  /// gets the motion model run from the earlier node over the stored
  /// increments, with the mismatch at the later node spread linearly over the
  /// increments; steps after the newest node keep what they recorded.
  void smoothed(std::vector<StampedPose>& trajectory, std::vector<StampedPose>& evaluated,
                const Pose6* eval_mount) const;

  // ---- NonlinearProblem ------------------------------------------------------
  int robot_dim() const override { return k_; }
  int state_dim() const override;
  int tangent_dim() const override;
  int num_pose_nodes() const override { return static_cast<int>(nodes_.size()); }
  int pose_node_index(int node) const override;
  int num_factors() const override { return static_cast<int>(factors_.size()); }
  bool linearize(int i, FactorLinearization& out) override;
  void retract(const Eigen::VectorXd& delta) override;

  // ---- checkpoints (problem_state.cpp) ----------------------------------------
  /// Writes everything that decides the problem's future (nodes, pending
  /// odometry, accumulated perturbations, every factor with its last
  /// linearisation), exactly.
  void save_state(StateWriter& out) const;
  /// Replaces the problem by a saved one, after the estimator's state was
  /// restored (its dim() is checked against) and with the restored
  /// `features` (live observation factors are bound to them by id). Checks
  /// everything before changing anything; std::invalid_argument otherwise.
  void restore_state(const StateReader& in, const std::vector<MapFeature>& features);

  /// Counters for tests and the log.
  int frozen_factors() const { return frozen_; }
  /// Factor i is linear in its pose node's frame (the frozen-factor rule).
  bool in_frame(int i) const;
  int live_observation_factors() const;
  /// The frozen-factor rule holds: every live observation factor's feature
  /// has the M-space dimension and estimator rows it had when recorded.
  bool live_factors_match_features() const;
  /// Value of pose node `node`.
  Pose6 node_value(int node) const;

 private:
  struct Factor;
  void sync_rows();
  void freeze_feature(int feature_id);
  void freeze(Factor& f);
  /// A feature before a change of its M-space (before_extend, before_join).
  struct Snapshot {
    Eigen::MatrixXd B;
    Eigen::VectorXd x;
  };
  /// A live observation factor's linearisation, at the current values, moved
  /// into its sensor's frame (the frozen-factor rule); false (nothing
  /// changed) when it cannot be.
  bool freeze_in_frame(Factor& f, const Snapshot& before);
  /// Keeps B and x_f of `mf` and re-linearises its live factors (before_extend, before_join).
  void snapshot(const MapFeature& mf, const Eigen::MatrixXd& B);
  /// Makes f the in-frame factor r = η + G_f J_of⁻¹ (x_o − x_o(x_f)) of
  /// `f.feature` seen from `sensor` (−1: the robot) at pose node `node`.
  bool move_into_frame(Factor& f, const Eigen::VectorXd& eta, const Eigen::MatrixXd& G_f, const Eigen::VectorXd& x_f,
                       int node, int sensor);
  bool evaluate_in_frame(const Factor& f, FactorLinearization& out) const;
  const MapFeature* map_feature(int id) const;
  void rebase(Factor& f);
  void store_linearisation(Factor& f, const FactorLinearization& lin);
  bool evaluate_observation(Factor& f, FactorLinearization& out);
  bool evaluate_motion(const Factor& f, FactorLinearization& out);
  void evaluate_linear(const Factor& f, FactorLinearization& out) const;
  bool evaluate_coincidence(const Factor& f, FactorLinearization& out) const;
  bool evaluate_relation(const Factor& f, FactorLinearization& out) const;

  Context c_;
  int k_ = 0;
  std::vector<Pose6> nodes_;  ///< values; the newest is *x_r while current_ is true
  std::vector<std::size_t> records_;  ///< trajectory index of each node
  bool current_ = false;      ///< the newest node is the current pose
  bool node_this_step_ = false;
  std::vector<OdometryIncrement> pending_;  ///< odometry since the newest node
  std::vector<std::size_t> pending_records_;                 ///< their trajectory indices
  Eigen::VectorXd acc_;  ///< accumulated perturbation of every estimator row (robot rows unused)
  std::vector<std::unique_ptr<Factor>> factors_;
  int frozen_ = 0;
  int loop_closures_ = 0;
  std::unordered_map<int, Snapshot> snapshots_;  ///< by feature id, until the change is recorded
  // before_join()
  int join_a_ = 0, join_b_ = 0;
  Eigen::MatrixXd B_a_, B_b_;
  std::vector<int> old_idx_a_, old_idx_b_;
  Eigen::VectorXd x_a_, x_b_;
};

}  // namespace mspace::kernel
