// slam.hpp — the four phases of M-space SLAM (ICRA §IV), sequenced in one place.
//
//   1. predict  — motion model → estimator (eqs. 25–27); sensor poses (eq. 17);
//                 extract measurements; associate by Mahalanobis gating.
//   2. update   — innovations of matched features with M-space dim > 0,
//                 J_η,state = J_ηo (J_or  J_of B̃) (eq. 30) → estimator (28–32)
//                 → robot pose and features (eq. 24).
//   3. add dense information — matched features store their evidence;
//                 unmatched measurements start tentative features (dim 0).
//   4. extend   — features add M-space dimensions; the estimator adds rows.
//
// The kernel only talks to the SDK interfaces; it never names a feature type.
#pragma once

#include <cstdint>
#include <functional>
#include <filesystem>
#include <map>
#include <memory>
#include <optional>
#include <string>
#include <unordered_map>
#include <utility>
#include <vector>

#include <Eigen/Cholesky>
#include <Eigen/Core>

#include "association.hpp"
#include "config.hpp"
#include "covariance_health.hpp"
#include "evaluation.hpp"
#include "loop_closing.hpp"
#include "scan_evidence.hpp"
#include "feature_bookkeeping.hpp"
#include "mspace/estimator.hpp"
#include "mspace/extractor.hpp"
#include "mspace/feature.hpp"
#include "mspace/motion_model.hpp"
#include "mspace/source.hpp"
#include "plugin_registry.hpp"
#include "sensor_health.hpp"

namespace mspace::kernel {

class Problem;
class ConsideredMap;
struct StoredMap;

/// One feature in the map, as the kernel tracks it: the plugin's feature and
/// the kernel's bookkeeping (estimator rows, shared blocks, history).
struct MapFeature : FeatureBookkeeping {
  int id = 0;
  int type = 0;                      ///< index into Slam::feature_types()
  std::shared_ptr<Feature> feature;  ///< keeps its plugin library loaded
  /// With ground truth: the feature's coordinates taken into the true frame
  /// through the robot's pose after the update of its newest evidence (where
  /// the object the robot saw then truly is); empty without ground truth.
  /// Slam::check_matches_against_ground_truth compares later matches with it.
  Eigen::VectorXd truth_image;
};

/// A coordinate block common to several features (T-RO §VI), e.g. the corner
/// of two line features: one set of estimator rows that every member's B̃ maps with
/// the identity (eq. 33).
struct SharedCoordinate {
  int id = 0;
  BlockKind kind = BlockKind::Point2D;
  std::vector<int> state_idx;                ///< block_size(kind) estimator rows
  std::vector<std::pair<int, int>> members;  ///< (feature id, block)
};

/// A feature-type instance from the YAML (`features: {name: {plugin: …}}`).
struct FeatureTypeSlot {
  std::string instance;
  std::string plugin;
  std::shared_ptr<const LoadedPlugin> library;
  std::shared_ptr<FeatureType> type;
  std::shared_ptr<Logger> log;  ///< the instance's logger, shared by its features

  /// Takes a feature this type made (create() or restore()): the result keeps
  /// the plugin library loaded while it lives, and feature_log() of the
  /// feature (mspace/feature_log.hpp) writes through the instance's logger
  /// with "#<id>: " in front.
  std::shared_ptr<Feature> adopt(std::unique_ptr<Feature> feature, std::int64_t id) const;
};

struct SensorSlot {
  SensorConfig config;
  std::shared_ptr<const LoadedPlugin> library;
  std::shared_ptr<Extractor> extractor;
  std::vector<int> feeds;  ///< feature-type indices this sensor's measurements may match
};


/// Counters and timings of a run (summary and progress).
struct RunStats {
  std::int64_t steps = 0;
  std::int64_t readings = 0;
  std::int64_t measurements = 0;
  std::int64_t matched = 0;
  std::int64_t updates = 0;  ///< matched measurements used in an estimator update
  std::int64_t created = 0;
  std::int64_t extended = 0;
  std::int64_t joined = 0;  ///< shared coordinates created
  std::int64_t pruned = 0;
  std::int64_t unknown_channel_readings = 0;
  std::int64_t loop_attempts = 0;   ///< map-matching searches (loop_closing.hpp)
  std::int64_t loop_closures = 0;   ///< accepted
  std::int64_t loop_ambiguous = 0;  ///< refused: another placement fitted nearly as well
  std::int64_t loop_unconfirmed = 0;  ///< found, then not found again by the next search with new features
  std::int64_t loop_confirmed_by_repeats = 0;  ///< confirmed by association.loop_confirm_repeats searches in a row
  std::int64_t loop_wide_searches = 0;  ///< second searches in the wider window (association.loop_wide_drift_per_metre)
  std::int64_t loop_wide_closures = 0;  ///< closures placed by such a search
  std::int64_t loop_merged = 0;     ///< features found to duplicate older ones
  std::int64_t loop_scan_placed = 0;  ///< closures placed by the scans (association.loop_scans)
  /// With ground truth: every accepted closure checked — the robot's pose
  /// after it, relative to its poses when it last saw the old features it
  /// paired, against the true relative poses; a median disagreement of over
  /// 1 m or 5° is a false closure (slam_loop_closure.cpp).
  std::int64_t loop_checked = 0;
  std::int64_t loop_false = 0;
  double loop_worst_disagreement = 0.0;  ///< m
  /// With ground truth: closures with a pair that is not the same
  /// object (each feature taken to the true frame through a pose it is
  /// estimated with; pairs_against_ground_truth below). A false
  /// closure by the pose check above may still pair the right objects: the
  /// old map there was distorted; this counts wrong associations.
  std::int64_t loop_wrong_pairs = 0;
  /// association.relocalize_by_scans: steps whose odometry said too little
  /// (with older scans to place them on), placed in full, placed across a
  /// corridor and in heading only, not placed (no fit, or a rival as good);
  /// with ground truth, how many were checked and wrong (over 1 m or 5°; along a corridor, the heading only).
  std::int64_t relocalize_steps = 0;
  std::int64_t relocalized = 0;
  std::int64_t relocalized_along_a_line = 0;
  std::int64_t relocalize_refused = 0;
  std::int64_t relocalize_checked = 0;
  std::int64_t relocalize_wrong = 0;
  /// With ground truth: every match of a measurement with a feature in the
  /// estimator checked (check_matches_against_ground_truth); wrong: the
  /// measurement does not fit the feature from the pose that the truth and
  /// the feature's own neighbourhood of the map put the robot at; of them,
  /// to features last seen over association.loop_min_gap_path m of travel ago.
  std::int64_t matches_checked = 0;
  std::int64_t matches_wrong = 0;
  std::int64_t matches_wrong_long_unseen = 0;
  std::int64_t matches_long_unseen = 0;
  double seconds_predict = 0.0;
  double seconds_extract = 0.0;  ///< sensors' extractors (per sensor in the health reports)
  double seconds_associate = 0.0;  ///< gating, selection and keeping the spatial index in step
  double seconds_update = 0.0;
  double seconds_dense = 0.0;
  double seconds_extend = 0.0;
  double seconds_source = 0.0;
  double seconds_loops = 0.0;  ///< map matching for loop closure
  /// Robot NEES at every step with ground truth, over the estimated pose
  /// coordinates the ground truth knows (nees_dof of them).
  std::vector<double> nees;
  int nees_dof = 0;
};

struct Candidate;

class Slam {
 public:
  /// Creates every plugin instance of the configuration.
  Slam(const RunConfig& config, PluginRegistry& registry);
  ~Slam();
  Slam(const Slam&) = delete;
  Slam& operator=(const Slam&) = delete;

  /// Reads and processes the next data step; false at the end of the data or
  /// after run.max_steps steps.
  bool step();
  /// Data steps processed so far (restored ones included).
  std::int64_t steps_done() const { return step_; }

  // ---- Checkpoints (checkpoint.cpp, docs/persistence.md §4) -----------------
  /// Throws a PluginError when the run cannot be checkpointed: an estimator
  /// that does not save its state (or that re-linearises: the kernel's
  /// nonlinear problem is not saved yet).
  void require_checkpointable() const;
  /// The whole state of the run: the map (every feature through its plugin's
  /// save()), the kernel's bookkeeping, every plugin object's run-time state
  /// and the resolved configuration. `file` is only for error messages.
  StoredMap snapshot_checkpoint(const std::filesystem::path& file) const;
  /// Continues from `checkpoint` (read from `file`): only on a Slam freshly
  /// made from the checkpoint's configuration, before any step(). The data
  /// source restores its position, or is replayed up to the checkpoint's step
  /// when it has no state. Throws PersistenceError naming the file (and the
  /// feature or plugin) on any mismatch; the caller then drops this Slam, so
  /// nothing half-loaded survives.
  void restore_checkpoint(const StoredMap& checkpoint, const std::filesystem::path& file);

  // ---- Saved maps (map_session.cpp, docs/maps.md) ---------------------------
  /// The map mode of the run (map.mode).
  MapConfig::Mode map_mode() const { return config_.map.mode; }
  /// What a run that loaded a map reports: features loaded, added and changed.
  struct MapSessionReport {
    std::string file;  ///< the map.bin loaded
    int loaded = 0;    ///< features taken from the file
    int tentative_dropped = 0;  ///< localize: tentative features of the file, not used
    int added = 0;     ///< features created in this run
    int changed = 0;   ///< loaded features whose coordinates or M-space dimension differ now
    /// Localize: the map covariance the consider update uses ("joint" or
    /// "feature blocks", considered_map.hpp) and how many rows left its working set.
    std::string covariance_model;
    std::int64_t working_set_evictions = 0;
    /// map.extend_when_unmapped: the step at which localize switched to
    /// mapping (0: it did not) and the path distance then.
    std::int64_t switched_to_mapping_at_step = 0;
    double switched_at_path = 0.0;
    /// initial_pose: search (slam_pose_search.cpp): the searches made, and
    /// when, where and on what evidence the robot was localized.
    struct Localization {
      std::int64_t step = 0;
      double t = 0.0, path = 0.0;          ///< data time and path distance (m) then
      double x = 0.0, y = 0.0, theta = 0.0; ///< the robot's pose in the map then (m, rad)
      int paired = 0, local = 0;           ///< local-map features paired with the map, of so many
      int rival = 0;                       ///< pairs of the best clearly different placement
      double sigma_translation = 0.0, sigma_rotation = 0.0;  ///< of the placement (m, rad, 1σ)
      int features_discarded = 0;          ///< the run's own features of before, dropped
    };
    bool searched = false;  ///< the run was told to search its pose
    int searches = 0;
    std::optional<Localization> localized;  ///< empty: not localized
    std::string last_search;                ///< what the last search found (not localized)
  };
  /// Empty unless the run loaded a map; `changed` is counted now.
  std::optional<MapSessionReport> map_session_report() const;

  const RunConfig& config() const { return config_; }
  const Pose6& pose() const { return x_r_; }
  /// Rows of the estimator's state (robot and map).
  int estimator_dim() const { return estimator_->dim(); }
  /// Covariance of the robot's estimated pose coordinates.
  Eigen::MatrixXd robot_covariance() const;
  const std::vector<int>& robot_dofs() const { return dofs_; }
  const std::vector<StampedPose>& trajectory() const { return trajectory_; }
  const std::vector<StampedPose>& ground_truth() const { return ground_truth_; }
  /// The poses compared with the ground truth: the robot's, or those of
  /// evaluation.ground_truth_sensor.
  const std::vector<StampedPose>& evaluated_trajectory() const { return evaluated_; }
  /// The dead-reckoning baseline: the source's odometry increments integrated
  /// through the motion model from the same start, with no update (one pose
  /// per step, robot frame; steps without odometry keep the pose).
  const std::vector<StampedPose>& dead_reckoning() const { return dead_reckoning_; }
  /// Steps that carried an odometry increment (0: the source gives none, and
  /// there is no baseline).
  std::int64_t odometry_steps() const { return odometry_steps_; }
  /// The same poses in the frame the ground truth refers to (as
  /// evaluated_trajectory()).
  std::vector<StampedPose> dead_reckoning_evaluated() const;
  /// Which odometry the baseline integrates: the source's plugin, and the
  /// value of its `odometry` parameter when it has one (a source that offers
  /// several, e.g. wheel or scan_matched, names the choice there).
  std::string odometry_description() const;
  const std::vector<MapFeature>& features() const { return features_; }
  const std::vector<SharedCoordinate>& shared_coordinates() const { return shared_; }
  const std::vector<FeatureTypeSlot>& feature_types() const { return types_; }
  /// Covariance of a feature's M-space perturbations (dim × dim).
  Eigen::MatrixXd feature_covariance(const MapFeature& f) const;
  /// Covariance of the given state rows: the estimator's; in localize mode
  /// the robot's rows from the estimator and the map's from the loaded map
  /// (uncorrelated with the robot, map_session.cpp).
  Eigen::MatrixXd state_covariance(const std::vector<int>& idx) const;
  /// Current value of a shared coordinate (from its first member).
  Eigen::VectorXd shared_value(const SharedCoordinate& c) const;
  const RunStats& stats() const { return stats_; }
  /// With ground truth: the matches check_matches_against_ground_truth found
  /// pairing another object, in order.
  struct WrongMatch {
    std::int64_t step = 0;           ///< the step of the match
    int feature = 0;                 ///< the feature's id
    std::int64_t previous_step = 0;  ///< the step of the feature's newest evidence before it
  };
  const std::vector<WrongMatch>& wrong_matches() const { return wrong_matches_; }
  /// Elapsed time of loading the source in this process, before the first
  /// step: its plugin library and its construction (a log read whole, scan
  /// matching done at load time, …) and the steps run.skip_steps discards
  /// or a resumed run replays to reach its checkpoint. Not in RunStats: a
  /// resumed run loads its source again and reports that.
  double source_load_seconds() const { return source_load_seconds_; }
  const AssociationStats& association_stats() const { return associator_.stats(); }
  std::size_t size_hint() const;
  Eigen::MatrixXd true_landmarks() const;
  /// Malformed records the data source skipped.
  std::size_t skipped_records() const;
  /// Health report of every sensor (measurements, matches, NIS, warnings).
  std::vector<SensorHealthReport> sensor_health() const;
  /// The estimator covariance's health so far (covariance_health.hpp).
  const CovarianceHealthReport& covariance_health() const { return covariance_health_.report(); }
  /// Asymmetry and eigenvalues of the whole covariance now (O(n³)); throws a
  /// PluginError naming the estimator when marginal() is broken.
  CovarianceFigures covariance_figures_now() const;
  /// The nonlinear problem (problem.hpp), recorded only for an estimator
  /// that wants it; nullptr otherwise.
  const Problem* problem() const { return problem_.get(); }
  Problem* problem() { return problem_.get(); }

  /// Called after every step with the step's data and the index of its pose
  /// in trajectory() (the runner keeps the range scans for the occupancy
  /// grid this way); an empty function removes it.
  using StepObserver = std::function<void(const DataStep& data, std::size_t pose_index)>;
  void set_step_observer(StepObserver observer) { step_observer_ = std::move(observer); }

 private:
  struct Match;
  struct ReadingWork;

  void predict(const DataStep& data);
  void check_recorded_mounts() const;
  void process_reading(const SensorReading& reading, std::vector<ReadingWork>& work);
  void process_sensor_reading(const SensorReading& reading, int sensor_index, std::vector<ReadingWork>& work);
  void associate(const SensorSlot& sensor, int sensor_index, const std::vector<Measurement>& meas,
                 ReadingWork& work);
  void record_health(int sensor_index, const ReadingWork& w, double extract_seconds);
  void check_matches_against_ground_truth(const ReadingWork& w);
  void remember_truth_images();
  bool planar_robot() const;  ///< only x, y and heading estimated
  void update(std::vector<Match>& matches);
  void add_dense_information(std::vector<ReadingWork>& work);
  void extend(const std::vector<int>& touched);
  void join_shared_coordinates(const std::vector<int>& touched);
  bool try_join(int a, int block_a, int b, int block_b);
  void remove_state_rows(std::vector<int> rows);
  void rebuild_state_idx(MapFeature& mf) const;
  void prune_tentative();
  void record(const DataStep& data);
  /// Estimator::update with the checks every update gets: the perturbation
  /// must be finite and of size dim(), and the covariance of the touched rows
  /// is checked (covariance_health.hpp). `what` says which update, for errors.
  Eigen::VectorXd estimator_update(const std::vector<LinearizedObservation>& obs, const char* what);
  /// The estimator's marginal(idx), checked: square of size |idx| and finite,
  /// else a PluginError naming the estimator.
  Eigen::MatrixXd checked_marginal(const std::vector<int>& idx) const;
  /// Applies an estimator correction dx: the robot pose and every feature (eq. 24).
  void apply_correction(const Eigen::VectorXd& dx);
  /// Map matching of the local map against the old map (slam_loop_closure.cpp).
  void close_loops(const DataStep& data);
  /// Whether this step's matches with old-map features pin the robot to the
  /// old map in every planar direction (slam_loop_closure.cpp); called by
  /// update() before it corrects, when loop closing is on.
  /// `matched`: (feature index, its candidate) of each match.
  void note_anchor(const std::vector<std::pair<int, const Candidate*>>& matched);
  void check_against_ground_truth(const PlanarMotion& T, const std::vector<double>& seen_paths, const DataStep& data);
  /// How far placement T puts the robot from where the ground truth says it is relative to the poses at which it
  /// first saw the old features (median over `seen_paths`): metres, radians; nothing without ground truth.
  std::optional<std::pair<double, double>> disagreement_with_ground_truth(const PlanarMotion& T,
                                                                         const std::vector<double>& seen_paths,
                                                                         const DataStep& data) const;
  /// How many pairs of a closure are not the same object by the ground truth
  /// (and how many could be checked): every feature is taken to the true
  /// frame through a pose it is estimated with, G = gt ∘ est⁻¹ there — a
  /// local feature through the current pose, an old one through the pose
  /// that last saw it or the one that created it (the closer of the two) —
  /// so the map's global distortion cancels; a pair whose coincidence
  /// residual (symmetry directions projected out) exceeds 0.5 m is wrong.
  std::optional<std::pair<int, int>> pairs_against_ground_truth(const MapMatchHypothesis& h,
                                                                const std::vector<FeatureShape>& local,
                                                                const std::vector<FeatureShape>& old,
                                                                const DataStep& data) const;
  /// The planar motion that takes the estimated frame at the record where `path` (m of travel) was reached to
  /// the true one, G = gt ∘ est⁻¹ there; nothing without ground truth at that record.
  std::optional<PlanarMotion> estimate_to_truth_at(double path) const;
  /// How many of the local features are, by the ground truth, an old feature of the search's window (the same
  /// object: residual ≤ 0.3 m in the true frame and footprints overlapping there, so that a segment far along
  /// the same line is not one — a local feature taken there through the current pose, an old one through the
  /// pose that last saw it), and how many could be checked: whether a failed search had
  /// anything to find (the debug log).
  /// With each counterpart found, the motion about the robot that would lay that local feature onto its old
  /// one in the estimate (θ, Δx, Δy of the robot): what a right placement must be, and — where the counterparts
  /// need different motions — how far the old map's passes disagree with each other there.
  struct TrueCounterparts {
    int found = 0, checked = 0;
    std::vector<Eigen::Vector3d> needed;
    std::vector<std::pair<int, int>> pairs;  ///< (position in local, in old), in the order of `needed`
    /// For each local feature without one: where it lies in the true frame and the nearest old one there.
    std::string unmatched;
  };
  std::optional<TrueCounterparts> true_counterparts(const std::vector<FeatureShape>& local,
                                                    const std::vector<FeatureShape>& old, const DataStep& data) const;
  /// For the debug log of a refused search: how far its best placement and the estimate are from the truth, and
  /// how many local features had a true counterpart to pair with.
  std::string ground_truth_verdict(const MapMatch& match, const std::vector<FeatureShape>& local,
                                   const std::vector<FeatureShape>& old, const DataStep& data) const;
  /// A number that changes when the set of features `idx` does: a search
  /// with the same local map gives the same answer (slam_loop_closure.cpp).
  std::int64_t local_map_signature(const std::vector<int>& idx) const;
  /// The robot's median speed over the recorded steps that moved (m/s; 0 before it moved).
  double typical_speed() const;
  /// features_[i] as map matching sees it, with its estimator covariance.
  FeatureShape estimated_shape(int i) const;
  /// The map-matching settings loop closing and the pose search share
  /// (association.loop_*, the gate's probability, the placement's σ bound).
  MapMatchOptions map_match_options() const;
  /// A seeded closure's pose relation (problem.hpp, relate) from the old pose
  /// node nearest to where T puts the robot to the current one.
  void relate_to_old_pose(const PlanarMotion& T, const MapMatchHypothesis& h);
  /// The pose relation (problem.hpp, relate) from the pose node nearest to `placed` (x, y, θ in the map frame)
  /// among those reached by `newest_path` m of travel, to the current one; `C_placed`: the placed pose's
  /// covariance in the map frame.
  void relate_to_nearest_node(const Eigen::Vector3d& placed, const Eigen::Matrix3d& C_placed, double newest_path);
  /// Keeps this step's range scans when association.loop_scans is on.
  void keep_scans(const DataStep& data);
  /// The debug line of a scans' placement, with the ground truth's verdict when it is known.
  void log_scan_placement(const ScanPlacement& scans, std::size_t points, const std::vector<FeatureShape>& old,
                          const Eigen::Vector2d& here, const DataStep& data) const;
  /// A kept scan's pose in the map frame (its record's estimate): rotation, position.
  std::pair<Eigen::Matrix2d, Eigen::Vector2d> scan_pose(const KeptScan& s) const;
  /// The end points of the kept scans `take` accepts, in the map frame, one per
  /// 25 cm cell and at most 300; `radius` receives the farthest one's distance from `here`.
  std::vector<Eigen::Vector2d> scan_points(const std::function<bool(const KeptScan&)>& take, const Eigen::Vector2d& here,
                                           double& radius) const;
  /// The likelihood field (scan_evidence.hpp) of the kept scans from the
  /// first while `old_enough` holds (they are kept in the order of travel)
  /// whose end points lie within `reach` of `here`.
  std::unique_ptr<ScanField> old_scan_field(const Eigen::Vector2d& here, double reach,
                                            const std::function<bool(const KeptScan&)>& old_enough) const;
  /// After a step whose odometry says little (association.relocalize_by_scans):
  /// the scans from that step on, once they hold enough end points, placed on
  /// every older one within 3σ of the prediction there, and the pose set to
  /// where they fit uniquely (slam_loop_closure.cpp).
  void relocalize(const DataStep& data);
  /// The recent scans (the last loop_local_path m) placed on the old ones
  /// (over loop_min_gap_path m ago) within the window `o` about `here`
  /// (scan_evidence.hpp); `field` receives the old scans' field.
  ScanPlacement place_scans(const Eigen::Vector2d& here, const MapMatchOptions& o,
                            std::unique_ptr<ScanField>& field, std::vector<Eigen::Vector2d>& local) const;
  /// A re-linearising estimator's turn (problem.cpp); false, for step(), at the end of the data.
  bool relinearize(bool end_of_data);
  /// After a re-linearisation moved the estimate: the unobservable directions
  /// of every estimator row at the new values (Estimator::set_unobservable).
  void refresh_unobservable();
  SensorView sensor_view(int sensor_index, double t) const;
  /// The features of a map file rebuilt through their plugins, with the
  /// kernel's bookkeeping (all or nothing; checkpoint.cpp and map_session.cpp).
  std::vector<MapFeature> restored_features(const StoredMap& map, const std::filesystem::path& file) const;
  /// Loads config_.map.load for localize / extend (map_session.cpp): the
  /// constructor's last act, so a Slam is never half-loaded.
  void load_map();
  /// The robot's covariance at the start: initial_pose.sigma² on the diagonal.
  Eigen::MatrixXd initial_covariance() const;
  /// Resets the estimator to the robot alone at x_r_ with covariance P0 (and
  /// its unobservable directions there).
  void reset_estimator(const Eigen::MatrixXd& P0);
  /// Discards config_.skip_steps data steps.
  void skip_data_steps();
  /// Localize mode with the robot placed in the map (while initial_pose:
  /// search is still searching, the run maps in a frame of its own).
  bool localizing() const { return config_.map.mode == MapConfig::Mode::Localize && !pose_search_; }
  /// initial_pose: search (slam_pose_search.cpp): looks for the local map in
  /// the whole loaded map; places the robot when a placement is confirmed.
  void search_pose();
  /// Moves the run into the map's frame by `T` (or leaves it where it is:
  /// null), drops the run's own features and puts the loaded map in place.
  void install_searched_map(const PlanarMotion* T, double sigma_translation, double sigma_rotation);
  /// Localize mode: one step's observations (robot and map rows) applied as
  /// Schmidt's consider update (considered_map.hpp): the robot is corrected,
  /// the map is not, the robot–map cross-covariance is kept. Returns δx_r.
  Eigen::VectorXd consider_update(const std::vector<LinearizedObservation>& obs);
  /// map.extend_when_unmapped: after this step's association (`matched`: a
  /// measurement matched the map), switches a localize run to mapping when
  /// none has for that many metres of path.
  void watch_for_unmapped(bool matched);

  RunConfig config_;
  std::shared_ptr<Logger> log_;
  std::shared_ptr<const LoadedPlugin> source_lib_, motion_lib_, estimator_lib_;
  std::shared_ptr<DataSource> source_;
  std::shared_ptr<MotionModel> motion_;
  std::shared_ptr<Estimator> estimator_;
  std::unique_ptr<Problem> problem_;  ///< only when estimator_->wants_problem()
  bool finished_ = false;             ///< the end-of-data relinearize() ran
  std::vector<std::shared_ptr<Logger>> plugin_loggers_;
  std::vector<FeatureTypeSlot> types_;
  std::vector<SensorSlot> sensors_;
  std::vector<SensorHealth> health_;  ///< one per sensor
  CovarianceHealth covariance_health_;
  std::vector<MapFeature> features_;
  std::vector<SharedCoordinate> shared_;
  int next_shared_id_ = 1;

  std::vector<int> dofs_;     ///< robot pose coordinates in the state
  std::vector<int> robot_idx_;  ///< 0..k−1
  Eigen::MatrixXd step_motion_Q_;  ///< this step's prediction noise Q (eq. 26; empty before the first increment)
  /// association.relocalize_by_scans: gathering the scans from an uncertain step on (Slam::relocalize).
  struct Relocalizing {
    bool active = false;
    std::size_t from_record = 0;  ///< the uncertain step's trajectory index
    double from_path = 0.0;       ///< m of travel there
    double step_sigma_xy = 0.0, step_sigma_theta = 0.0;  ///< the uncertain step's own odometry σ (m, rad)
    double sigma_xy = 0.0, sigma_theta = 0.0;  ///< the robot's σ predicted there (m, rad)
  };
  Relocalizing relocalizing_;
  Pose6 x_r_ = Pose6::Zero();
  double t_ = 0.0;
  bool started_ = false;
  double path_distance_ = 0.0;
  std::int64_t step_ = 0;
  int next_feature_id_ = 1;
  Associator associator_;  ///< gating, nearest neighbour / JCBB, the spatial index
  std::vector<StampedPose> trajectory_;
  std::vector<StampedPose> ground_truth_;
  std::vector<StampedPose> evaluated_;
  Pose6 dead_reckoning_pose_ = Pose6::Zero();  ///< odometry only (predict(), without updates)
  std::vector<StampedPose> dead_reckoning_;
  std::int64_t odometry_steps_ = 0;
  int ground_truth_sensor_ = -1;
  /// The robot's true pose at this step, when the ground truth gives all of
  /// its estimated coordinates (for the noise statistics of sensor_health.hpp).
  std::optional<Pose6> robot_truth_;
  std::vector<WrongMatch> wrong_matches_;
  std::vector<int> matched_this_step_;  ///< ids of the features updated this step (with ground truth: remember_truth_images)
  RunStats stats_;
  std::vector<double> record_path_;  ///< path distance of every trajectory record
  double last_loop_attempt_path_ = -1e300;
  std::int64_t last_loop_local_signature_ = 0;  ///< the local map of the last search
  /// Path distance of the last step whose matches with features created
  /// over loop_min_gap_path metres earlier fixed the robot's position and
  /// heading against them (note_anchor): since then its drift against the
  /// old map may have grown, at least along the directions they left free.
  double last_anchor_path_ = 0.0;
  double last_revisit_path_ = 0.0;  ///< path of the last step a revisit fixed the robot (note_anchor)
  /// A placement map matching found and has not yet confirmed: a closure is
  /// made only when a later search, with local features this one did not
  /// pair, finds the same placement (slam_loop_closure.cpp).
  struct PendingClosure {
    bool active = false;
    PlanarMotion motion;
    double sigma_translation = 0.0, sigma_rotation = 0.0;
    std::vector<int> local_ids;  ///< feature ids of the local features it paired
    /// Placed by the scans (MapMatchHypothesis::seeded): a later search whose
    /// scans place it again confirms it without new feature pairs.
    bool seeded = false;
    double path = 0.0;  ///< path_distance_ when it was found
    /// Later searches that found it again without new feature pairs
    /// (association.loop_confirm_repeats).
    int repeats = 0;
  };
  PendingClosure pending_closure_;
  std::vector<KeptScan> scans_;  ///< association.loop_scans: every range scan's end points
  StepObserver step_observer_;
  double source_load_seconds_ = 0.0;

  // Saved maps (map_session.cpp).
  std::optional<MapSessionReport> map_session_;
  /// Loaded features' coordinates and dimensions, by id, to count changes.
  std::unordered_map<int, std::pair<Eigen::VectorXd, int>> loaded_state_;
  /// Localize: the loaded map's covariance and the robot's correlation with
  /// it (the Schmidt update's working set).
  std::unique_ptr<ConsideredMap> considered_;
  /// map.extend_when_unmapped: the map's joint covariance (the switch puts it
  /// in the estimator) and the path distance of the last step that matched.
  std::shared_ptr<const Eigen::MatrixXd> map_joint_;
  double last_matched_path_ = 0.0;
  /// initial_pose: search, until the robot is placed: the loaded map waits
  /// here while the run maps in the frame of its first pose.
  struct PoseSearch {
    std::vector<MapFeature> map_features;
    std::vector<SharedCoordinate> map_shared;
    std::unique_ptr<ConsideredMap> considered;
    std::vector<FeatureShape> map_shapes;  ///< the map as map matching sees it (made once)
    double last_search_path = -1e300;
    std::int64_t last_signature = -1;  ///< of the local map searched last
    PendingClosure waiting;            ///< a placement found once, to be confirmed
  };
  std::unique_ptr<PoseSearch> pose_search_;
  /// Features the run created while it searched its pose (discarded).
  std::int64_t created_while_searching_ = 0;
};

}  // namespace mspace::kernel
