// association.hpp — data association of one sensor reading (phase 1, ICRA §IV
// "Prediction"): which measurement belongs to which feature, and which
// measurements may start new features.
//
//   gating        every (feature, measurement) pair within the sensor's range
//                 whose innovation passes the Mahalanobis gate is a Candidate;
//   selection     greedy nearest neighbour (`nearest_neighbour`), or joint
//                 compatibility branch and bound (`jcbb`, Neira & Tardós 2001)
//                 over the candidates of features in the estimator;
//   new features  an unmatched measurement starts a feature only when it lies
//                 beyond the new-feature threshold of every feature;
//   spatial index a uniform grid over the features' planar bounding boxes, so
//                 that a sensor with a max_range only looks at nearby features.
//
// The selection functions work on plain numbers and are tested on hand-built
// cases (tests/association); the Associator runs the whole of it on the map.
#pragma once

#include <array>
#include <cstdint>
#include <functional>
#include <memory>
#include <unordered_map>
#include <vector>

#include <Eigen/Cholesky>
#include <Eigen/Core>

#include "config.hpp"
#include "mspace/estimator.hpp"
#include "mspace/feature.hpp"
#include "mspace/log.hpp"
#include "mspace/measurement.hpp"
#include "mspace/pose.hpp"

namespace mspace::kernel {

struct MapFeature;       // slam.hpp
struct FeatureTypeSlot;  // slam.hpp
struct SensorSlot;       // slam.hpp

/// One measurement of one reading that passed the gate of one feature.
struct Candidate {
  int measurement = 0;
  int feature = 0;  ///< index into the map's features
  double d2 = 0.0;  ///< squared Mahalanobis distance of the innovation
  bool tentative = false;  ///< the feature has M-space dimension 0 (not in the estimator)
  Innovation innovation;
  Eigen::MatrixXd C_eta;    ///< J_ηv C_v J_ηvᵀ
  /// J_ηo J_of Σ_gate J_ofᵀ J_ηoᵀ from the feature's gating_covariance (empty
  /// when it has none): added to the innovation covariance of the gate only.
  Eigen::MatrixXd C_gate;
  Eigen::MatrixXd J_state;  ///< m × (k + dim): J_ηo (J_os J_sr  J_of B̃), eq. 30
  std::vector<int> idx;     ///< estimator indices of J_state's columns (robot, then the feature's)
};

// ---- Selection --------------------------------------------------------------

/// Greedy nearest neighbour, each measurement and each feature used at most
/// once: features in the estimator first, then tentative ones (which are
/// often clutter and must not take a measurement from a feature they happen
/// to lie close to), smallest d² first within each group. Sorts `candidates`
/// in that order and returns the positions (in the sorted vector) chosen.
std::vector<int> nearest_neighbour(std::vector<Candidate>& candidates, int num_measurements, int num_features);

struct JcbbOptions {
  double probability = 0.99;       ///< joint compatibility: D² ≤ χ²(probability, dim of the joint innovation)
  std::int64_t max_nodes = 100000;  ///< interpretation-tree nodes before giving up
  /// χ² quantiles of `probability` by dimension (< 0: not computed yet),
  /// kept from reading to reading by the caller; null: a fresh cache.
  std::vector<double>* chi2_cache = nullptr;
  /// After the best hypothesis, look for rivals: other jointly compatible
  /// hypotheses with as many pairings. A pairing of the best that a rival
  /// does not make is disputed (JcbbResult::disputed) — the data cannot tell
  /// which of the two is right (a corridor's two walls under a large lateral
  /// uncertainty, a symmetric building).
  bool find_rivals = false;
  std::int64_t max_rival_nodes = -1;  ///< nodes for the rivals' search; < 0: max_nodes
};

struct JcbbResult {
  std::vector<int> chosen;  ///< positions in the candidate vector, at most one per measurement and feature
  double d2 = 0.0;          ///< joint squared Mahalanobis distance of the chosen pairings
  std::int64_t nodes = 0;   ///< interpretation-tree nodes visited
  bool bounded = false;     ///< the search hit max_nodes: `chosen` is not the optimum (empty)
  /// With find_rivals: the positions in `chosen` (candidate positions) that a
  /// rival hypothesis contradicts, ascending; `chosen` still holds them.
  std::vector<int> disputed;
  std::int64_t rival_nodes = 0;  ///< nodes visited looking for rivals
  bool rivals_bounded = false;   ///< that search hit max_nodes: every pairing counts as disputed
};

/// Covariance of the given estimator rows (Estimator::marginal).
using MarginalFn = std::function<Eigen::MatrixXd(const std::vector<int>&)>;

/// Joint compatibility branch and bound (Neira & Tardós 2001) over the
/// non-tentative candidates: the hypothesis with the most pairings, then the
/// smallest joint distance, whose stacked innovation passes
///   D² = νᵀ (J P Jᵀ + C)⁻¹ ν ≤ χ²(p, dim ν),
/// where J stacks the candidates' J_state over the union of their indices,
/// so that the shared robot pose correlates every pairing. S grows by one
/// block per pairing (a Cholesky block update); null pairings are allowed.
/// With options.find_rivals a second pass enumerates the jointly compatible
/// hypotheses with as many pairings as the best and marks the best's
/// pairings that any of them leaves out (JcbbResult::disputed).
JcbbResult joint_compatibility(const std::vector<Candidate>& candidates, const MarginalFn& marginal,
                               const JcbbOptions& options);

// ---- Re-entries (association.reentry_joint_test) ----------------------------

/// `marginal` with `extra` (robot rows × robot rows) added at the rows
/// `robot_idx` (wherever they fall in the rows asked for): the robot's
/// covariance widened, every other entry as it was.
MarginalFn widen_robot(MarginalFn marginal, std::vector<int> robot_idx, Eigen::MatrixXd extra);

struct ReentryVerdict {
  std::vector<bool> confirmed;  ///< per pairing asked about
  JcbbResult search;            ///< the widened search, its rivals included
};

/// The re-entry test. A pairing with a feature the robot last saw long ago
/// closes a loop; if the filter's covariance then understates the drift of
/// the odometry since, its gate may admit another object while the true one
/// lies outside. `wide` are the reading's candidates with such features gated
/// with the robot's covariance widened (association.reentry_covariance_scale²
/// Σ_r; their d² computed so), and `widened` gives that covariance: the error
/// is one shared error of the robot pose, so the joint test asks for one pose
/// correction that explains every pairing of a hypothesis. A pairing (measurement, feature position)
/// of `asked` is confirmed when the best jointly compatible hypothesis over
/// `wide` makes it and no rival hypothesis with as many pairings leaves it
/// out (JcbbOptions::find_rivals; a search that gives up confirms nothing).
ReentryVerdict confirm_reentries(const std::vector<Candidate>& wide, const std::vector<std::pair<int, int>>& asked,
                                 const MarginalFn& widened, JcbbOptions options);

// ---- Spatial index ----------------------------------------------------------

/// An axis-aligned planar box; `everywhere` for features without a position
/// (only scalar blocks), which every query returns.
struct PlanarBox {
  double min_x = 0.0, min_y = 0.0, max_x = 0.0, max_y = 0.0;
  bool everywhere = false;
};

/// The bounding box of the polyline through a feature's point blocks.
PlanarBox planar_box(const Feature& f);
/// Horizontal distance from p to the nearest point of that polyline (a point,
/// a segment, …); 0 without any point block.
double planar_distance(const Feature& f, const Eigen::Vector2d& p);

/// A uniform grid of square cells hashed by cell, each holding the keys of
/// the boxes that overlap it. Boxes spanning more than a few hundred cells
/// are kept in a list that every query scans.
class PlanarGrid {
 public:
  explicit PlanarGrid(double cell_size);
  double cell_size() const { return cell_; }
  /// Inserts the box of `key` or moves it.
  void set(int key, const PlanarBox& box);
  void erase(int key);
  bool contains(int key) const { return boxes_.count(key) != 0; }
  std::size_t size() const { return boxes_.size(); }
  /// Appends the keys (each once, in no particular order) of the boxes that
  /// come within `range` of p — every box whose points may.
  void query(const Eigen::Vector2d& p, double range, std::vector<int>& keys) const;

 private:
  struct Cells {
    std::int64_t x0 = 0, y0 = 0, x1 = -1, y1 = -1;  ///< inclusive cell range; empty when x1 < x0
    bool wide = false;                             ///< kept in wide_ instead of cells
  };
  struct Entry {
    PlanarBox box;
    Cells cells;
  };
  Cells cells_of(const PlanarBox& box) const;
  void insert_cells(int key, const Cells& c);
  void erase_cells(int key, const Cells& c);
  static std::int64_t hash(std::int64_t x, std::int64_t y) { return (x << 32) ^ (y & 0xffffffffLL); }

  double cell_;
  std::unordered_map<int, Entry> boxes_;
  std::unordered_map<std::int64_t, std::vector<int>> grid_;
  std::vector<int> wide_;  ///< keys of everywhere-boxes and very large ones
};

// ---- The associator ---------------------------------------------------------

/// What the associator reads of the map for one reading.
struct AssociationView {
  const std::vector<MapFeature>& features;
  const std::vector<FeatureTypeSlot>& types;
  /// Covariance of state rows: the estimator's (Estimator::marginal), or in
  /// localize mode the robot's with the loaded map's (Slam::state_covariance).
  MarginalFn marginal;
  const std::vector<int>& robot_idx;  ///< estimator rows of the robot pose
  std::int64_t step = 0;
  /// With association.reentry_joint_test: the travel since the robot last saw
  /// a feature (metres; a re-entry beyond config.loop_min_gap_path). Null: no
  /// re-entry test.
  std::function<double(const MapFeature&)> travel_unseen;
};

struct AssociationResult {
  std::vector<Candidate> matches;  ///< chosen pairings, at most one per measurement and feature
  std::vector<bool> may_create;    ///< per measurement: far from every feature
};

/// Counters of association (in the run summary).
struct AssociationStats {
  std::int64_t jcbb_readings = 0;   ///< readings searched by joint compatibility
  std::int64_t jcbb_nodes = 0;      ///< interpretation-tree nodes visited in all
  std::int64_t jcbb_bounded = 0;    ///< readings whose search hit max_nodes (greedy result used)
  std::int64_t index_queries = 0;   ///< readings whose features came from the spatial index
  /// With association.refuse_ambiguous: readings where a rival hypothesis
  /// disputed some of the best one's pairings, and the pairings so dropped.
  std::int64_t ambiguous_readings = 0;
  std::int64_t disputed_pairings = 0;
  /// With association.reentry_joint_test: readings with a re-entry pairing
  /// (a feature unseen over loop_min_gap_path), and the pairings it
  /// confirmed and refused.
  std::int64_t reentry_readings = 0;
  std::int64_t reentry_confirmed = 0;
  std::int64_t reentry_refused = 0;
};

class Associator {
 public:
  /// `sensors` give the grid's cell size when config.index_cell_size is 0.
  Associator(const AssociationConfig& config, const std::vector<SensorConfig>& sensors, std::shared_ptr<Logger> log);
  ~Associator();
  Associator(const Associator&) = delete;
  Associator& operator=(const Associator&) = delete;

  /// Tells the associator that features moved, were created or removed
  /// (an update, dense information, extension, joins, pruning): the next
  /// associate() that uses the spatial index brings it up to date first.
  /// A change in the number of features is noticed without it.
  void map_changed() { dirty_ = true; }

  /// Brings the spatial index up to date with the map now. Features are
  /// keyed by id; a feature whose box has not left its indexed box (grown by
  /// 5% of a cell) costs one planar_box().
  void sync(const std::vector<MapFeature>& features);

  /// Associates the measurements of one reading of `sensor` at sensor pose
  /// x_ms; J_sr = ∂x_ms/∂(estimated robot pose) (6 × k, eq. 17).
  AssociationResult associate(const AssociationView& map, const SensorSlot& sensor, const Pose6& x_ms,
                              const Eigen::MatrixXd& J_sr, const std::vector<Measurement>& meas);

  const AssociationStats& stats() const { return stats_; }
  /// Checkpoints: the counters go on from the saved ones. Nothing else needs
  /// saving: the χ² caches are recomputed alike and the spatial index is
  /// rebuilt from the map (queries return features in ascending order, so the
  /// result does not depend on the grid's history).
  void restore_stats(const AssociationStats& stats) {
    stats_ = stats;
    dirty_ = true;
  }

 private:
  /// Indices (ascending) of the features the sensor feeds within its range.
  void features_in_range(const AssociationView& map, const SensorSlot& sensor, const Eigen::Vector2d& p,
                         std::vector<int>& out);
  double threshold(std::vector<double>& cache, double p, int dim);
  /// Drops the re-entry pairings the test does not confirm from `chosen`.
  void confirm_reentry_pairings(const AssociationView& map, const std::vector<Candidate>& candidates,
                                const std::vector<Candidate>& wide, const std::vector<bool>& is_reentry,
                                const Eigen::MatrixXd& widening, std::vector<int>& chosen);

  AssociationConfig config_;
  std::shared_ptr<Logger> log_;
  AssociationStats stats_;
  std::vector<double> gate_chi2_;  ///< by innovation dimension
  std::vector<double> new_feature_chi2_;
  std::vector<double> joint_chi2_;  ///< by joint innovation dimension
  /// What the index holds of the feature at one position of the map: its
  /// box grown by a margin, so that the small moves of an update leave the
  /// grid alone (a query returns a superset; planar_distance decides).
  struct Slot {
    int id = 0;
    PlanarBox loose;
    /// Offsets of the feature's point blocks in its coordinates (its
    /// layout's, read once); points < 0: more than fit, ask planar_box().
    std::array<int, 4> point_offsets{};
    int points = -1;
    Eigen::Index coords_size = -1;
  };
  /// The feature's planar box, from the slot's cached point offsets.
  static PlanarBox box_of(Slot& slot, const Feature& f);
  PlanarGrid grid_;
  std::vector<Slot> slots_;               ///< by position in the map, as of the last sync
  std::unordered_map<int, int> position_;  ///< feature id → position, as of the last sync
  bool dirty_ = true;
  std::vector<int> in_range_, keys_;
  // Reused for every feature in range (J_of, J_os, A, A P, M and the
  // estimator rows) and every (feature, measurement) pair (the rest).
  Eigen::MatrixXd scratch_J_of_, scratch_J_os_, scratch_A_, scratch_AP_, scratch_M_, scratch_M_wide_;
  std::vector<int> scratch_idx_;
  std::vector<double> scratch_far_;  ///< per measurement dimension: max(gate, new-feature threshold), this reading
  Innovation scratch_innovation_;
  Eigen::MatrixXd scratch_T_, scratch_S_;
  /// J X Jᵀ for the J it was last computed with (`of` recomputes it when J's
  /// bits differ; X is the caller's to keep fixed while `valid`).
  struct KeptProduct {
    Eigen::MatrixXd factor, product;
    bool valid = false;
    const Eigen::MatrixXd& of(const Eigen::MatrixXd& J, const Eigen::MatrixXd& X, Eigen::MatrixXd& scratch);
  };
  std::vector<KeptProduct> measurement_products_;  ///< J_ηv C_v J_ηvᵀ, per measurement of the reading
  KeptProduct feature_product_;                    ///< J_ηo M J_ηoᵀ of the feature in hand
  Eigen::LDLT<Eigen::MatrixXd> scratch_ldlt_;
};

}  // namespace mspace::kernel
