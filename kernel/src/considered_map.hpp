// considered_map.hpp — localize mode's Schmidt ("consider") update (docs/maps.md §2).
//
// In localize mode the estimator holds the robot's k rows only; the loaded
// map's rows m are considered, never updated: their covariance P_mm stays the
// map's, but the robot–map cross-covariance P_rm that every update creates is
// kept, so that an error common to the map's features (and to every pass over
// them) is not taken for independent evidence again and again.
//
// The map's covariance P_mm is the joint one of map.bin when the file holds it
// and it has at most `capacity` rows: then every map row carries P_rm from the
// start (an update correlates the robot with every row correlated with what it
// observed) and the update is Schmidt's, exactly. Otherwise (a map saved with
// its marginals, or a joint one larger than the working set) P_mm is the block
// model: each feature's own block (shared rows included), no correlation
// between features; then only observed rows get correlated with the robot, and
// a bounded working set W holds them (the `capacity` most recently observed).
// A row leaving W forgets its own correlation with the robot — the one
// approximation (none while W holds every row observed); when it is observed
// again it re-enters with the correlation it has through the rows of its
// feature still in W, which keeps the joint covariance valid.
// Every step costs O(k·|W| + m·|W|), whatever the map's size.
#pragma once

#include <cstdint>
#include <memory>
#include <unordered_map>
#include <utility>
#include <vector>

#include <Eigen/Core>

#include "mspace/estimator.hpp"

namespace mspace::kernel {

class ConsideredMap {
 public:
  /// `k` robot rows; the map's rows are k … k+rows−1. `joint`: the map's
  /// joint covariance over those rows (may be null: then only each feature's
  /// own block, set with set_block, is known and features are uncorrelated).
  ConsideredMap(int k, int rows, std::shared_ptr<const Eigen::MatrixXd> joint, int capacity);

  /// A feature's own block (marginal) over its state rows (the block model).
  void set_block(const std::vector<int>& rows, const Eigen::MatrixXd& P);

  /// Covariance of state rows `idx` (robot and map rows mixed): the robot's
  /// block P_rr (k × k) from the estimator, P_rm from the working set (zero
  /// outside it), P_mm from the map.
  Eigen::MatrixXd covariance(const std::vector<int>& idx, const Eigen::MatrixXd& P_rr) const;

  /// Motion: P_rW ← J_rr P_rW (eq. 27's C_rp ← J_rr C_rp).
  void predict(const Eigen::MatrixXd& J_rr);

  /// One step's observations (each over the robot rows then map rows) as the
  /// one observation of the robot alone that a robot-only estimator must
  /// apply to make the Schmidt update (see the .cpp). Remembers the gain for
  /// commit(). `step` orders the working set (least recently observed leaves).
  LinearizedObservation condition(const std::vector<LinearizedObservation>& obs, const Eigen::MatrixXd& P_rr,
                                  std::int64_t step);
  /// After the estimator applied condition()'s observation: P_rW −= K_r (H P)_W.
  void commit();
  /// The map's rows as new estimator rows behind the robot's, correlated with
  /// it as now: δx_m = P_mr P_rr⁻¹ δx_r + w, w ~ N(0, P_mm − P_mr P_rr⁻¹ P_rm),
  /// with P_mm the map's joint covariance (rows × rows). For a switch to mapping.
  StateAugmentation as_augmentation(const Eigen::MatrixXd& P_rr, const Eigen::MatrixXd& P_mm) const;

  int working_rows() const { return static_cast<int>(rows_.size()); }
  int capacity() const { return capacity_; }
  std::int64_t evicted() const { return evicted_; }
  /// True when P_mm is the map's joint covariance, false for the block model.
  bool joint() const { return joint_ != nullptr; }

 private:
  /// The map's covariance between map rows a and b (state indices).
  Eigen::MatrixXd map_block(const std::vector<int>& a, const std::vector<int>& b) const;
  /// Column of row r in P_rW, entering it (zero cross-covariance) if absent.
  int enter(int row, std::int64_t step, const std::vector<int>& keep);

  int k_, rows_in_map_, capacity_;
  std::shared_ptr<const Eigen::MatrixXd> joint_;
  /// Block model (without joint_): row → (row, covariance) of its features' own blocks.
  std::unordered_map<int, std::vector<std::pair<int, double>>> neighbours_;
  Eigen::MatrixXd P_rW_;                             ///< k × capacity, the first |rows_| columns used
  std::vector<int> rows_;                            ///< state row of each column of P_rW_
  std::vector<std::int64_t> last_used_;              ///< step each column was last observed
  std::unordered_map<int, int> column_of_;           ///< state row → column
  std::int64_t evicted_ = 0;
  // Pending commit().
  Eigen::MatrixXd K_r_;  ///< k × m
  Eigen::MatrixXd G_;    ///< m × |W|: H_r P_rW + H_O P_OW
};

}  // namespace mspace::kernel
