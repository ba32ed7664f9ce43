// checkpoint.cpp — see checkpoint.hpp and docs/persistence.md §4.
#include "checkpoint.hpp"

#include <chrono>
#include <cmath>
#include <string>
#include <unordered_map>
#include <utility>
#include <vector>

#include "config.hpp"
#include "persistence.hpp"
#include "plugin_registry.hpp"
#include "problem.hpp"
#include "slam.hpp"

namespace mspace::kernel {
namespace {

constexpr const char* kCheckpointFile = "map.bin";

/// Poses as the columns of an 8 × N matrix: t, the six pose coordinates, the
/// known-coordinates mask.
Eigen::MatrixXd poses_matrix(const std::vector<StampedPose>& poses) {
  Eigen::MatrixXd m(8, static_cast<Eigen::Index>(poses.size()));
  for (std::size_t i = 0; i < poses.size(); ++i) {
    const auto c = static_cast<Eigen::Index>(i);
    m(0, c) = poses[i].t;
    m.col(c).segment<6>(1) = poses[i].pose;
    m(7, c) = poses[i].known;
  }
  return m;
}

std::vector<StampedPose> poses_from(const StateReader& in, const std::string& name) {
  const Eigen::MatrixXd& m = get_state(in, name, 8, -1, "run state");
  std::vector<StampedPose> poses(static_cast<std::size_t>(m.cols()));
  for (std::size_t i = 0; i < poses.size(); ++i) {
    const auto c = static_cast<Eigen::Index>(i);
    poses[i].t = m(0, c);
    poses[i].pose = m.col(c).segment<6>(1);
    if (!(m(7, c) >= 0 && m(7, c) <= kAllPoseCoords)) throw std::invalid_argument("run state: bad pose mask");
    poses[i].known = static_cast<std::uint8_t>(m(7, c));
  }
  return poses;
}

/// Entry (0, i) of `m`, which must be an integer in [lo, hi] (a count, an id, a step).
std::int64_t integer_at(const Eigen::MatrixXd& m, Eigen::Index i, double lo, double hi, const char* what) {
  const double v = m(0, i);
  if (!(v >= lo && v <= hi) || v != std::floor(v))
    throw std::invalid_argument(std::string("run state: ") + what + " (" + std::to_string(v) +
                                ") is not an integer in range");
  return static_cast<std::int64_t>(v);
}

Eigen::MatrixXd row_of(std::initializer_list<double> values) {
  Eigen::MatrixXd m(1, static_cast<Eigen::Index>(values.size()));
  Eigen::Index i = 0;
  for (double v : values) m(0, i++) = v;
  return m;
}

/// A plugin object of the run with the names that identify it.
struct PluginRef {
  std::string instance;
  std::string plugin;
  PluginObject* object = nullptr;
  const LoadedPlugin* library = nullptr;
};

/// Every plugin object of a run, in a fixed order: source, motion model,
/// estimator, feature types, extractors.
std::vector<PluginRef> plugin_objects(const RunConfig& config, DataSource& source, const LoadedPlugin& source_lib,
                                      MotionModel& motion, const LoadedPlugin& motion_lib, Estimator& estimator,
                                      const LoadedPlugin& estimator_lib, const std::vector<FeatureTypeSlot>& types,
                                      const std::vector<SensorSlot>& sensors) {
  std::vector<PluginRef> refs;
  refs.push_back({config.source.instance, config.source.plugin, &source, &source_lib});
  refs.push_back({config.motion.instance, config.motion.plugin, &motion, &motion_lib});
  refs.push_back({config.estimator.instance, config.estimator.plugin, &estimator, &estimator_lib});
  for (const FeatureTypeSlot& t : types) refs.push_back({t.instance, t.plugin, t.type.get(), t.library.get()});
  for (const SensorSlot& s : sensors)
    refs.push_back({s.config.extractor.instance, s.config.extractor.plugin, s.extractor.get(), s.library.get()});
  return refs;
}

}  // namespace

// ---- Slam: saving -------------------------------------------------------------

void Slam::require_checkpointable() const {
  const bool has_state = guarded(config_.estimator.instance, *estimator_lib_, "has_state",
                                 [&] { return estimator_->has_state(); });
  if (!has_state)
    throw PluginError("checkpoints are not supported by estimator '" + config_.estimator.plugin +
                      "' (it does not save its state: PluginObject::save_state); run without checkpoint_every / "
                      "--checkpoint-every, or with an estimator that does");
}

StoredMap Slam::snapshot_checkpoint(const std::filesystem::path& file) const {
  require_checkpointable();
  StoredMap map = snapshot_map(*this, file);
  map.kind = "checkpoint";
  StoredCheckpoint& c = map.checkpoint.emplace();
  c.config_file = config_.file.string();
  c.config_yaml = effective_config_yaml(config_);

  // The kernel's own state (RUN): everything step() reads that is not in the
  // features, the shared coordinates or a plugin.
  StoredState& run = c.run;
  run.put("step", row_of({static_cast<double>(step_)}));
  run.put("time", row_of({t_, started_ ? 1.0 : 0.0, path_distance_, finished_ ? 1.0 : 0.0}));
  run.put("ids", row_of({static_cast<double>(next_feature_id_), static_cast<double>(next_shared_id_)}));
  run.put("robot_pose", x_r_);
  put_ints(run, "dofs", dofs_);
  run.put("estimator_dim", row_of({static_cast<double>(estimator_->dim())}));
  const RunStats& s = stats_;
  run.put("counters", row_of({static_cast<double>(s.steps), static_cast<double>(s.readings),
                              static_cast<double>(s.measurements), static_cast<double>(s.matched),
                              static_cast<double>(s.updates), static_cast<double>(s.created),
                              static_cast<double>(s.extended), static_cast<double>(s.joined),
                              static_cast<double>(s.pruned), static_cast<double>(s.unknown_channel_readings)}));
  run.put("seconds", row_of({s.seconds_predict, s.seconds_extract, s.seconds_associate, s.seconds_update,
                             s.seconds_dense, s.seconds_extend, s.seconds_source}));
  run.put("nees", Eigen::Map<const Eigen::MatrixXd>(s.nees.data(), static_cast<Eigen::Index>(s.nees.size()), 1));
  run.put("nees_dof", row_of({static_cast<double>(s.nees_dof)}));
  run.put("trajectory", poses_matrix(trajectory_));
  run.put("ground_truth", poses_matrix(ground_truth_));
  run.put("evaluated", poses_matrix(evaluated_));
  run.put("dead_reckoning", poses_matrix(dead_reckoning_));
  run.put("dead_reckoning_pose", dead_reckoning_pose_);
  run.put("odometry_steps", row_of({static_cast<double>(odometry_steps_)}));
  const AssociationStats& a = associator_.stats();
  run.put("association", row_of({static_cast<double>(a.jcbb_readings), static_cast<double>(a.jcbb_nodes),
                                 static_cast<double>(a.jcbb_bounded), static_cast<double>(a.index_queries),
                                 static_cast<double>(a.ambiguous_readings), static_cast<double>(a.disputed_pairings),
                                 static_cast<double>(a.reentry_readings), static_cast<double>(a.reentry_confirmed),
                                 static_cast<double>(a.reentry_refused)}));
  for (std::size_t i = 0; i < health_.size(); ++i) health_[i].save(run, "health_" + std::to_string(i) + "_");
  covariance_health_.save(run, "covariance_health_");
  // Loop closing (slam_loop_closure.cpp): its history and counters, and per
  // feature (id, created_path, last_seen_path, merged_into, seen_since_path) — kernel
  // bookkeeping that map files do not need.
  Eigen::MatrixXd loop_features(5, static_cast<Eigen::Index>(features_.size()));
  for (std::size_t i = 0; i < features_.size(); ++i) {
    const MapFeature& mf = features_[i];
    loop_features.col(static_cast<Eigen::Index>(i)) << mf.id, mf.created_path, mf.last_seen_path, mf.merged_into,
        mf.seen_since_path;
  }
  run.put("loop_features", loop_features);
  // With ground truth: the matches' check (check_matches_against_ground_truth)
  // — its counters; the wrong matches (step, feature id, previous step); per
  // feature with one its truth image (id, length), and the images' values one
  // after another.
  run.put("match_truth", row_of({static_cast<double>(s.matches_checked), static_cast<double>(s.matches_wrong),
                                 static_cast<double>(s.matches_long_unseen),
                                 static_cast<double>(s.matches_wrong_long_unseen)}));
  Eigen::MatrixXd wrong(static_cast<Eigen::Index>(wrong_matches_.size()), 3);
  for (std::size_t i = 0; i < wrong_matches_.size(); ++i)
    wrong.row(static_cast<Eigen::Index>(i)) << static_cast<double>(wrong_matches_[i].step), wrong_matches_[i].feature,
        static_cast<double>(wrong_matches_[i].previous_step);
  run.put("match_truth_wrong", wrong);
  {
    std::vector<std::pair<int, const Eigen::VectorXd*>> images;
    Eigen::Index n_values = 0;
    for (const MapFeature& mf : features_)
      if (mf.truth_image.size() > 0) {
        images.emplace_back(mf.id, &mf.truth_image);
        n_values += mf.truth_image.size();
      }
    Eigen::MatrixXd index(static_cast<Eigen::Index>(images.size()), 2);
    Eigen::MatrixXd values(n_values, 1);
    Eigen::Index at = 0;
    for (std::size_t i = 0; i < images.size(); ++i) {
      index.row(static_cast<Eigen::Index>(i)) << images[i].first, static_cast<double>(images[i].second->size());
      values.middleRows(at, images[i].second->size()) = *images[i].second;
      at += images[i].second->size();
    }
    run.put("truth_image_index", index);
    run.put("truth_image_values", values);
  }
  run.put("record_path",
          Eigen::Map<const Eigen::MatrixXd>(record_path_.data(), static_cast<Eigen::Index>(record_path_.size()), 1));
  run.put("loops", row_of({last_loop_attempt_path_, static_cast<double>(last_loop_local_signature_), last_anchor_path_,
                           static_cast<double>(s.loop_attempts), static_cast<double>(s.loop_closures),
                           static_cast<double>(s.loop_ambiguous), static_cast<double>(s.loop_merged),
                           static_cast<double>(s.loop_checked), static_cast<double>(s.loop_false),
                           s.loop_worst_disagreement, s.seconds_loops, static_cast<double>(s.loop_unconfirmed),
                           static_cast<double>(s.loop_scan_placed), static_cast<double>(s.loop_wrong_pairs),
                           last_revisit_path_, static_cast<double>(s.loop_confirmed_by_repeats),
                           static_cast<double>(s.loop_wide_searches), static_cast<double>(s.loop_wide_closures),
                           static_cast<double>(s.relocalize_steps), static_cast<double>(s.relocalized),
                           static_cast<double>(s.relocalized_along_a_line), static_cast<double>(s.relocalize_refused),
                           static_cast<double>(s.relocalize_checked), static_cast<double>(s.relocalize_wrong),
                           relocalizing_.active ? 1.0 : 0.0, static_cast<double>(relocalizing_.from_record),
                           relocalizing_.from_path, relocalizing_.step_sigma_xy, relocalizing_.step_sigma_theta, relocalizing_.sigma_xy,
                           relocalizing_.sigma_theta}));
  const PendingClosure& pending = pending_closure_;
  run.put("loop_pending", row_of({pending.active ? 1.0 : 0.0, pending.motion.theta, pending.motion.t.x(),
                                  pending.motion.t.y(), pending.motion.pivot.x(), pending.motion.pivot.y(),
                                  pending.sigma_translation, pending.sigma_rotation, pending.seeded ? 1.0 : 0.0,
                                  pending.path, static_cast<double>(pending.repeats)}));
  Eigen::MatrixXd pending_ids(static_cast<Eigen::Index>(pending.local_ids.size()), 1);
  for (std::size_t i = 0; i < pending.local_ids.size(); ++i) pending_ids(static_cast<Eigen::Index>(i), 0) = pending.local_ids[i];
  run.put("loop_pending_ids", pending_ids);
  // association.loop_scans: every kept scan (record, path, sensor origin,
  // range, number of end points) and their end points, in order.
  Eigen::MatrixXd scan_index(static_cast<Eigen::Index>(scans_.size()), 6);
  std::size_t n_points = 0;
  for (const KeptScan& k : scans_) n_points += k.points.size();
  Eigen::MatrixXd scan_points(static_cast<Eigen::Index>(n_points), 2);
  Eigen::Index row = 0;
  for (std::size_t i = 0; i < scans_.size(); ++i) {
    const KeptScan& k = scans_[i];
    scan_index.row(static_cast<Eigen::Index>(i)) << static_cast<double>(k.record), k.path, k.origin.x(), k.origin.y(),
        k.range, static_cast<double>(k.points.size());
    for (const Eigen::Vector2f& p : k.points) scan_points.row(row++) << p.x(), p.y();
  }
  run.put("loop_scans", scan_index);
  run.put("loop_scan_points", scan_points);

  // Every plugin object with run-time state (PSTA).
  for (const PluginRef& p : plugin_objects(config_, *source_, *source_lib_, *motion_, *motion_lib_, *estimator_,
                                           *estimator_lib_, types_, sensors_)) {
    if (!guarded(p.instance, *p.library, "has_state", [&] { return p.object->has_state(); })) continue;
    StoredPluginState ps;
    ps.instance = p.instance;
    ps.plugin = p.plugin;
    try {
      ps.version = p.object->state_version();
      p.object->save_state(ps.state);
    } catch (const std::exception& e) {
      throw PersistenceError(file, p.instance + ": save_state() failed: " + e.what(), std::nullopt, p.plugin);
    }
    c.plugins.push_back(std::move(ps));
  }
  // The nonlinear problem of a re-linearising estimator (PROB).
  if (problem_) problem_->save_state(c.problem.emplace());
  return map;
}

// ---- Slam: restoring ----------------------------------------------------------

void Slam::restore_checkpoint(const StoredMap& map, const std::filesystem::path& file) {
  if (!map.checkpoint) throw PersistenceError(file, "not a checkpoint");
  if (step_ != 0) throw PersistenceError(file, "a checkpoint is restored only into a run that has not started");
  const StoredCheckpoint& c = *map.checkpoint;
  const auto fail = [&](const std::string& what, const std::string& plugin = {}) {
    return PersistenceError(file, what, std::nullopt, plugin);
  };
  try {
    require_checkpointable();
  } catch (const PluginError& e) {
    throw fail(e.what(), config_.estimator.plugin);
  }

  // 1. The features, all or nothing, through their plugins' restore().
  std::vector<MapFeature> features = restored_features(map, file);
  std::vector<SharedCoordinate> shared;
  for (const StoredShared& s : map.shared) shared.push_back({s.id, s.kind, s.state_idx, s.members});

  // 2. Every plugin object's state; each must have one record exactly when it has state.
  std::vector<bool> used(c.plugins.size(), false);
  for (const PluginRef& p : plugin_objects(config_, *source_, *source_lib_, *motion_, *motion_lib_, *estimator_,
                                           *estimator_lib_, types_, sensors_)) {
    std::size_t found = c.plugins.size();
    for (std::size_t i = 0; i < c.plugins.size(); ++i)
      if (!used[i] && c.plugins[i].instance == p.instance) found = i;
    const bool has_state = guarded(p.instance, *p.library, "has_state", [&] { return p.object->has_state(); });
    if (found == c.plugins.size()) {
      if (has_state)
        throw fail(p.instance + ": the plugin has run-time state but the checkpoint holds none for it (written by "
                   "another version of the plugin?)",
                   p.plugin);
      continue;
    }
    used[found] = true;
    const StoredPluginState& ps = c.plugins[found];
    if (ps.plugin != p.plugin)
      throw fail(p.instance + ": the checkpoint's state is of plugin '" + ps.plugin + "', this run has '" + p.plugin +
                     "'",
                 p.plugin);
    if (!has_state)
      throw fail(p.instance + ": the checkpoint holds run-time state for it but the plugin has none (another "
                 "version of the plugin?)",
                 p.plugin);
    try {
      p.object->restore_state(ps.state, ps.version);
    } catch (const std::exception& e) {
      throw fail(p.instance + ": restore_state() refused the saved state (version " + std::to_string(ps.version) +
                     "): " + e.what(),
                 p.plugin);
    }
  }
  for (std::size_t i = 0; i < used.size(); ++i)
    if (!used[i])
      throw fail("state of instance '" + c.plugins[i].instance + "' (plugin '" + c.plugins[i].plugin +
                     "'), which this run does not have",
                 c.plugins[i].plugin);

  if (problem_.operator bool() != c.problem.has_value())
    throw fail(problem_ ? "the estimator re-linearises but the checkpoint holds no nonlinear problem (PROB record; "
                          "written by an older mspace or for another estimator?)"
                        : "the checkpoint holds a nonlinear problem but this run's estimator does not re-linearise",
               config_.estimator.plugin);

  // 3. The kernel's own state.
  const StoredState& run = c.run;
  std::int64_t step = 0;
  try {
    step = integer_at(get_state(run, "step", 1, 1, "run state"), 0, 0, 1e15, "step");
    const Eigen::MatrixXd& time = get_state(run, "time", 1, 4, "run state");
    const Eigen::MatrixXd& ids = get_state(run, "ids", 1, 2, "run state");
    const std::int64_t next_feature_id = integer_at(ids, 0, 1, 2e9, "next feature id");
    const std::int64_t next_shared_id = integer_at(ids, 1, 1, 2e9, "next shared id");
    const std::vector<int> dofs = get_ints<int>(run, "dofs", 0, 5, "run state");
    if (dofs != dofs_) throw std::invalid_argument("the robot's estimated coordinates differ from the motion model's");
    const auto estimator_dim =
        static_cast<int>(integer_at(get_state(run, "estimator_dim", 1, 1, "run state"), 0, 1, 1e8, "estimator_dim"));
    if (estimator_->dim() != estimator_dim)
      throw std::invalid_argument("the estimator has " + std::to_string(estimator_->dim()) +
                                  " state rows after restore_state(), the run had " + std::to_string(estimator_dim));
    for (const MapFeature& mf : features)
      for (int i : mf.state_idx)
        if (i < static_cast<int>(dofs_.size()) || i >= estimator_dim)
          throw PersistenceError(file, "state index " + std::to_string(i) + " is outside the estimator's rows", mf.id,
                                 types_[static_cast<std::size_t>(mf.type)].plugin);
    const Eigen::MatrixXd& counters = get_state(run, "counters", 1, 10, "run state");
    const Eigen::MatrixXd& seconds = get_state(run, "seconds", 1, 7, "run state");
    const Eigen::MatrixXd& nees = get_state(run, "nees", -1, 1, "run state");
    // 4 counters, 6 since association.refuse_ambiguous (2026-11-29), 9 since reentry_joint_test (2026-12-07).
    const Eigen::MatrixXd& association = get_state(run, "association", 1, -1, "run state");
    if (association.cols() != 4 && association.cols() != 6 && association.cols() != 9)
      throw std::invalid_argument("run state: association has " + std::to_string(association.cols()) +
                                  " columns, expected 4, 6 or 9");
    // 31 entries; 14 in a checkpoint written before last_revisit_path_ was kept (then: the last anchor), 15 before
    // the closures confirmed by repeated searches were counted (then: none), 16 before the wider window's, 18
    // before relocalization by the scans (then: none, and not gathering).
    const Eigen::MatrixXd& loops = get_state(run, "loops", 1, -1, "run state");
    if (loops.cols() < 14 || (loops.cols() > 18 && loops.cols() != 31) || loops.cols() == 17)
      throw fail("run state: 'loops' has " + std::to_string(loops.cols()) + " entries, 14, 15, 16, 18 or 31 expected");
    // 11 entries; 10 in a checkpoint written before the pending placement's repeats were kept (then: none).
    const Eigen::MatrixXd& pending_row = get_state(run, "loop_pending", 1, -1, "run state");
    if (pending_row.cols() != 10 && pending_row.cols() != 11)
      throw fail("run state: 'loop_pending' has " + std::to_string(pending_row.cols()) + " entries, 10 or 11 expected");
    const Eigen::MatrixXd& pending_ids = get_state(run, "loop_pending_ids", -1, 1, "run state");
    const Eigen::MatrixXd& scan_index = get_state(run, "loop_scans", -1, 6, "run state");
    const Eigen::MatrixXd& scan_points = get_state(run, "loop_scan_points", -1, 2, "run state");
    std::vector<KeptScan> scans(static_cast<std::size_t>(scan_index.rows()));
    Eigen::Index point_row = 0;
    for (std::size_t i = 0; i < scans.size(); ++i) {
      const auto r = static_cast<Eigen::Index>(i);
      KeptScan& k = scans[i];
      k.record = static_cast<std::size_t>(integer_at(scan_index.row(r), 0, 0, 1e15, "loop_scans record"));
      k.path = scan_index(r, 1);
      k.origin = Eigen::Vector2f(static_cast<float>(scan_index(r, 2)), static_cast<float>(scan_index(r, 3)));
      k.range = static_cast<float>(scan_index(r, 4));
      const auto count = static_cast<Eigen::Index>(integer_at(scan_index.row(r), 5, 0, 1e9, "loop_scans points"));
      if (point_row + count > scan_points.rows()) throw fail("run state: 'loop_scans' counts more end points than 'loop_scan_points' holds");
      for (Eigen::Index j = 0; j < count; ++j, ++point_row)
        k.points.emplace_back(static_cast<float>(scan_points(point_row, 0)), static_cast<float>(scan_points(point_row, 1)));
    }
    if (point_row != scan_points.rows()) throw fail("run state: 'loop_scan_points' holds end points no scan counts");
    PendingClosure pending;
    pending.active = pending_row(0, 0) != 0.0;
    pending.motion = PlanarMotion{pending_row(0, 1), {pending_row(0, 2), pending_row(0, 3)},
                                  {pending_row(0, 4), pending_row(0, 5)}};
    pending.sigma_translation = pending_row(0, 6);
    pending.sigma_rotation = pending_row(0, 7);
    pending.seeded = pending_row(0, 8) != 0.0;
    pending.path = pending_row(0, 9);
    if (pending_row.cols() > 10)
      pending.repeats = static_cast<int>(integer_at(pending_row, 10, 0, 1e9, "loop_pending repeats"));
    for (Eigen::Index i = 0; i < pending_ids.rows(); ++i)
      pending.local_ids.push_back(static_cast<int>(integer_at(pending_ids.row(i), 0, 0, 1e9, "loop_pending_ids")));
    const Eigen::MatrixXd& record_path = get_state(run, "record_path", -1, 1, "run state");
    // Four rows in a checkpoint written before `seen_since_path` (5th row) was kept: then the run of
    // observations is taken to begin at the creation, which the anchor rule reads as "never revisited".
    const Eigen::MatrixXd& loop_features =
        get_state(run, "loop_features", -1, static_cast<Eigen::Index>(features.size()), "run state");
    if (loop_features.rows() != 4 && loop_features.rows() != 5)
      throw fail("run state: 'loop_features' has " + std::to_string(loop_features.rows()) + " rows, 4 or 5 expected");
    for (std::size_t i = 0; i < features.size(); ++i) {
      const auto c = static_cast<Eigen::Index>(i);
      if (loop_features(0, c) != features[i].id) throw fail("run state: 'loop_features' is not in the map's order");
      features[i].created_path = loop_features(1, c);
      features[i].last_seen_path = loop_features(2, c);
      features[i].seen_since_path = loop_features.rows() > 4 ? loop_features(4, c) : features[i].created_path;
      features[i].merged_into = static_cast<int>(integer_at(loop_features.col(c).transpose(), 3, 0, 1e9, "merged_into"));
    }
    // The matches' ground-truth check (absent from checkpoints written before it existed: then nothing is checked
    // until each feature's next update).
    if (run.has("truth_image_index")) {
      const Eigen::MatrixXd& index = get_state(run, "truth_image_index", -1, 2, "run state");
      const Eigen::MatrixXd& values = get_state(run, "truth_image_values", -1, 1, "run state");
      std::unordered_map<int, std::size_t> at_id;
      for (std::size_t i = 0; i < features.size(); ++i) at_id[features[i].id] = i;
      Eigen::Index at = 0;
      for (Eigen::Index r = 0; r < index.rows(); ++r) {
        const auto id = static_cast<int>(integer_at(index.row(r), 0, 1, 2e9, "truth image feature id"));
        const Eigen::Index n = integer_at(index.row(r), 1, 1, 1e6, "truth image length");
        const auto it = at_id.find(id);
        if (it == at_id.end()) throw fail("run state: a truth image of feature #" + std::to_string(id) + ", which the map does not hold");
        if (at + n > values.rows()) throw fail("run state: 'truth_image_values' is shorter than its index says");
        features[it->second].truth_image = values.middleRows(at, n);
        at += n;
      }
    }
    std::vector<StampedPose> trajectory = poses_from(run, "trajectory");
    std::vector<StampedPose> ground_truth = poses_from(run, "ground_truth");
    std::vector<StampedPose> evaluated = poses_from(run, "evaluated");
    std::vector<StampedPose> dead_reckoning = poses_from(run, "dead_reckoning");
    const Pose6 dead_reckoning_pose = get_state(run, "dead_reckoning_pose", 6, 1, "run state");
    const std::int64_t odometry_steps =
        integer_at(get_state(run, "odometry_steps", 1, 1, "run state"), 0, 0, 1e15, "odometry_steps");
    for (std::size_t i = 0; i < health_.size(); ++i) health_[i].restore(run, "health_" + std::to_string(i) + "_");
    covariance_health_.restore(run, "covariance_health_");

    RunStats s;
    s.steps = integer_at(counters, 0, 0, 1e15, "steps");
    s.readings = integer_at(counters, 1, 0, 1e15, "readings");
    s.measurements = integer_at(counters, 2, 0, 1e15, "measurements");
    s.matched = integer_at(counters, 3, 0, 1e15, "matched");
    s.updates = integer_at(counters, 4, 0, 1e15, "updates");
    s.created = integer_at(counters, 5, 0, 1e15, "created");
    s.extended = integer_at(counters, 6, 0, 1e15, "extended");
    s.joined = integer_at(counters, 7, 0, 1e15, "joined");
    s.pruned = integer_at(counters, 8, 0, 1e15, "pruned");
    s.unknown_channel_readings = integer_at(counters, 9, 0, 1e15, "readings without sensor");
    s.seconds_predict = seconds(0, 0);
    s.seconds_extract = seconds(0, 1);
    s.seconds_associate = seconds(0, 2);
    s.seconds_update = seconds(0, 3);
    s.seconds_dense = seconds(0, 4);
    s.seconds_extend = seconds(0, 5);
    s.seconds_source = seconds(0, 6);
    s.nees.assign(nees.data(), nees.data() + nees.size());
    s.nees_dof = static_cast<int>(integer_at(get_state(run, "nees_dof", 1, 1, "run state"), 0, 0, 6, "nees_dof"));
    AssociationStats a;
    a.jcbb_readings = integer_at(association, 0, 0, 1e15, "jcbb_readings");
    a.jcbb_nodes = integer_at(association, 1, 0, 1e15, "jcbb_nodes");
    a.jcbb_bounded = integer_at(association, 2, 0, 1e15, "jcbb_bounded");
    a.index_queries = integer_at(association, 3, 0, 1e15, "index_queries");
    if (association.cols() >= 6) {
      a.ambiguous_readings = integer_at(association, 4, 0, 1e15, "ambiguous_readings");
      a.disputed_pairings = integer_at(association, 5, 0, 1e15, "disputed_pairings");
    }
    if (association.cols() >= 9) {
      a.reentry_readings = integer_at(association, 6, 0, 1e15, "reentry_readings");
      a.reentry_confirmed = integer_at(association, 7, 0, 1e15, "reentry_confirmed");
      a.reentry_refused = integer_at(association, 8, 0, 1e15, "reentry_refused");
    }
    s.loop_attempts = integer_at(loops, 3, 0, 1e15, "loop_attempts");
    s.loop_closures = integer_at(loops, 4, 0, 1e15, "loop_closures");
    s.loop_ambiguous = integer_at(loops, 5, 0, 1e15, "loop_ambiguous");
    s.loop_merged = integer_at(loops, 6, 0, 1e15, "loop_merged");
    s.loop_checked = integer_at(loops, 7, 0, 1e15, "loop_checked");
    s.loop_false = integer_at(loops, 8, 0, 1e15, "loop_false");
    s.loop_worst_disagreement = loops(0, 9);
    s.seconds_loops = loops(0, 10);
    s.loop_unconfirmed = integer_at(loops, 11, 0, 1e15, "loop_unconfirmed");
    s.loop_scan_placed = integer_at(loops, 12, 0, 1e15, "loop_scan_placed");
    s.loop_wrong_pairs = integer_at(loops, 13, 0, 1e15, "loop_wrong_pairs");
    if (loops.cols() > 15) s.loop_confirmed_by_repeats = integer_at(loops, 15, 0, 1e15, "loop_confirmed_by_repeats");
    if (loops.cols() > 17) {
      s.loop_wide_searches = integer_at(loops, 16, 0, 1e15, "loop_wide_searches");
      s.loop_wide_closures = integer_at(loops, 17, 0, 1e15, "loop_wide_closures");
    }
    if (loops.cols() == 31) {
      s.relocalize_steps = integer_at(loops, 18, 0, 1e15, "relocalize_steps");
      s.relocalized = integer_at(loops, 19, 0, 1e15, "relocalized");
      s.relocalized_along_a_line = integer_at(loops, 20, 0, 1e15, "relocalized_along_a_line");
      s.relocalize_refused = integer_at(loops, 21, 0, 1e15, "relocalize_refused");
      s.relocalize_checked = integer_at(loops, 22, 0, 1e15, "relocalize_checked");
      s.relocalize_wrong = integer_at(loops, 23, 0, 1e15, "relocalize_wrong");
      relocalizing_.active = loops(0, 24) != 0.0;
      relocalizing_.from_record = static_cast<std::size_t>(integer_at(loops, 25, 0, 1e15, "relocalizing from_record"));
      relocalizing_.from_path = loops(0, 26);
      relocalizing_.step_sigma_xy = loops(0, 27);
      relocalizing_.step_sigma_theta = loops(0, 28);
      relocalizing_.sigma_xy = loops(0, 29);
      relocalizing_.sigma_theta = loops(0, 30);
    }
    std::vector<WrongMatch> wrong_matches;
    if (run.has("match_truth")) {
      const Eigen::MatrixXd& match_truth = get_state(run, "match_truth", 1, 4, "run state");
      s.matches_checked = integer_at(match_truth, 0, 0, 1e15, "matches_checked");
      s.matches_wrong = integer_at(match_truth, 1, 0, 1e15, "matches_wrong");
      s.matches_long_unseen = integer_at(match_truth, 2, 0, 1e15, "matches_long_unseen");
      s.matches_wrong_long_unseen = integer_at(match_truth, 3, 0, 1e15, "matches_wrong_long_unseen");
      const Eigen::MatrixXd& wrong = get_state(run, "match_truth_wrong", -1, 3, "run state");
      for (Eigen::Index r = 0; r < wrong.rows(); ++r)
        wrong_matches.push_back({integer_at(wrong.row(r), 0, 0, 1e15, "wrong match step"),
                                 static_cast<int>(integer_at(wrong.row(r), 1, 0, 2e9, "wrong match feature")),
                                 integer_at(wrong.row(r), 2, 0, 1e15, "wrong match previous step")});
    }

    // The nonlinear problem (after the estimator, whose rows it checks; its
    // live factors bind to the restored features).
    if (problem_) problem_->restore_state(*c.problem, features);

    // Everything read: take it.
    features_ = std::move(features);
    shared_ = std::move(shared);
    t_ = time(0, 0);
    started_ = time(0, 1) != 0.0;
    path_distance_ = time(0, 2);
    finished_ = time(0, 3) != 0.0;
    next_feature_id_ = static_cast<int>(next_feature_id);
    next_shared_id_ = static_cast<int>(next_shared_id);
    x_r_ = get_state(run, "robot_pose", 6, 1, "run state");
    stats_ = std::move(s);
    associator_.restore_stats(a);
    trajectory_ = std::move(trajectory);
    ground_truth_ = std::move(ground_truth);
    evaluated_ = std::move(evaluated);
    dead_reckoning_ = std::move(dead_reckoning);
    dead_reckoning_pose_ = dead_reckoning_pose;
    odometry_steps_ = odometry_steps;
    record_path_.assign(record_path.data(), record_path.data() + record_path.size());
    last_loop_attempt_path_ = loops(0, 0);
    last_loop_local_signature_ = static_cast<std::int64_t>(loops(0, 1));
    last_anchor_path_ = loops(0, 2);
    last_revisit_path_ = loops.cols() > 14 ? loops(0, 14) : last_anchor_path_;
    pending_closure_ = std::move(pending);
    scans_ = std::move(scans);
    wrong_matches_ = std::move(wrong_matches);
  } catch (const PersistenceError&) {
    throw;
  } catch (const std::exception& e) {
    throw fail(e.what());
  }

  // 4. The data source's position: restored with its state, or replayed.
  const bool source_has_state =
      guarded(config_.source.instance, *source_lib_, "has_state", [&] { return source_->has_state(); });
  if (!source_has_state) {
    // Reading the source up to the checkpoint is part of loading it.
    const auto replay_start = std::chrono::steady_clock::now();
    DataStep skipped;
    for (std::int64_t k = 0; k < step; ++k)
      if (!guarded(config_.source.instance, *source_lib_, "next", [&] { return source_->next(skipped); }))
        throw fail(config_.source.instance + ": the data ends after " + std::to_string(k) +
                       " steps, before the checkpoint's step " + std::to_string(step) + " (other data?)",
                   config_.source.plugin);
    source_load_seconds_ += std::chrono::duration<double>(std::chrono::steady_clock::now() - replay_start).count();
  }
  step_ = step;
}

// ---- Files ----------------------------------------------------------------------

std::filesystem::path checkpoint_dir(const RunConfig& config) {
  return std::filesystem::path(config.output.dir) / "checkpoint";
}

std::uintmax_t write_checkpoint(const Slam& slam, const std::filesystem::path& dir) {
  const std::filesystem::path file = dir / kCheckpointFile;
  write_map_file(file, slam.snapshot_checkpoint(file));
  return std::filesystem::file_size(file);
}

std::filesystem::path find_checkpoint_file(const std::filesystem::path& given) {
  namespace fs = std::filesystem;
  std::error_code ec;
  if (fs::is_regular_file(given, ec)) return given;
  if (fs::is_directory(given, ec)) {
    // A run's output folder holds its final map.bin too: its checkpoint first.
    if (fs::is_regular_file(given / "checkpoint" / kCheckpointFile, ec)) return given / "checkpoint" / kCheckpointFile;
    if (fs::is_regular_file(given / kCheckpointFile, ec)) return given / kCheckpointFile;
    throw PersistenceError(given, std::string("no checkpoint here: neither ") + kCheckpointFile + " nor checkpoint/" +
                                      kCheckpointFile);
  }
  throw PersistenceError(given, "no such file or folder");
}

std::unique_ptr<Slam> resume_from_checkpoint(const std::filesystem::path& given, PluginRegistry& registry,
                                             const std::function<void(RunConfig&)>& adjust) {
  const std::filesystem::path file = find_checkpoint_file(given);
  const StoredMap map = read_map_file(file, "checkpoint");  // the whole file, checked
  const StoredCheckpoint& c = *map.checkpoint;
  RunConfig config;
  try {
    config = parse_config(c.config_yaml, file.string() + " (configuration of " + c.config_file + ")", registry);
  } catch (const std::exception& e) {
    throw PersistenceError(file, std::string("its configuration does not load with the plugins installed now: ") +
                                     e.what());
  }
  config.file = c.config_file;
  for (const auto& dir : config.plugin_path) registry.add_search_dir(dir);
  if (adjust) adjust(config);
  std::unique_ptr<Slam> slam;
  try {
    slam = std::make_unique<Slam>(config, registry);
  } catch (const std::exception& e) {
    throw PersistenceError(file, std::string("cannot make the run's plugins: ") + e.what());
  }
  slam->restore_checkpoint(map, file);
  return slam;
}

}  // namespace mspace::kernel
