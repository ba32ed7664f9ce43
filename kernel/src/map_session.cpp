// map_session.cpp — a run that starts from a saved map (issue 16, docs/maps.md).
//
// The modes are modes of the one four-phase loop (slam.cpp), not a second loop:
//
//   mapping   the map starts empty (no file is read);
//   localize  the map of map.bin is read-only: association matches against it,
//             the update corrects the robot only, phases 3 and 4 leave the map
//             alone, nothing is created; with map.extend_when_unmapped it
//             becomes an extend session where the robot leaves the map;
//   extend    the map of map.bin is the start of this run's map: its features
//             and shared coordinates enter the estimator with the map's joint
//             covariance and the run maps on (features gain dimensions, new
//             ones enter); the map it writes is one map of both sessions.
//
// How localize accounts for the map's uncertainty: Schmidt's consider update
// (considered_map.cpp). The estimator holds the robot's rows only; the map's
// rows keep the covariance of the file (the joint one when map.bin holds it,
// else each feature's marginal) and are never updated, and the robot–map
// cross-covariance that every update creates is kept for a bounded working
// set of map rows (map.working_set_rows), so that the map's errors, common to
// all the features in view and to every pass over them, are not taken as
// fresh evidence each time. Association gates with the same covariance.
// Every step costs what the features in view and the working set cost: the
// spatial index finds the features, and no step touches the rest of the map.
#include <algorithm>
#include <cstdint>
#include <numeric>

#include <Eigen/Cholesky>

#include "considered_map.hpp"
#include "persistence.hpp"
#include "problem.hpp"
#include "slam.hpp"

namespace mspace::kernel {

std::vector<MapFeature> Slam::restored_features(const StoredMap& map, const std::filesystem::path& file) const {
  std::vector<RestoredFeature> restored = restore_features(map, file, types_);
  std::vector<MapFeature> features;
  features.reserve(restored.size());
  for (std::size_t i = 0; i < restored.size(); ++i) {
    const StoredFeature& sf = map.features[i];
    MapFeature mf;
    mf.id = static_cast<int>(sf.id);
    mf.type = restored[i].type;
    mf.feature = std::move(restored[i].feature);
    static_cast<FeatureBookkeeping&>(mf) = sf;
    if (mf.last_sensor < 0 || mf.last_sensor >= static_cast<int>(sensors_.size()))
      throw PersistenceError(file, "its last sensor " + std::to_string(mf.last_sensor) + " is not in the run", sf.id,
                             types_[static_cast<std::size_t>(mf.type)].plugin);
    features.push_back(std::move(mf));
  }
  return features;
}

void Slam::load_map() {
  const std::filesystem::path file = find_map_file(config_.map.load);
  const StoredMap map = read_map_file(file, "map");  // the whole file, checked
  const char* mode = map_mode_name(config_.map.mode);
  const auto fail = [&](const std::string& what) { return PersistenceError(file, what); };
  if (problem_ && config_.map.mode == MapConfig::Mode::Localize)
    throw fail(std::string("map.mode ") + mode + ": estimator '" + config_.estimator.plugin +
               "' re-linearises (it records a nonlinear problem; localize's consider update keeps the map out of "
               "the estimator, so there is nothing to re-linearise against); localize needs an estimator that does "
               "not (`mspace plugins` lists the estimators); extend works with it");
  if (!map.covariance)
    throw fail("the map holds no covariance (format version " + std::to_string(map.format_version) +
               "; maps hold it from version 3): re-create it with this build of mspace");
  const StoredCovariance& cov = *map.covariance;
  const bool localize = localizing();
  if (!localize && !cov.joint)
    throw fail(std::string("map.mode ") + mode +
               " needs the joint covariance of the map, and this map holds only each feature's marginal (it was "
               "saved with output.map_covariance: marginal): re-create it with output.map_covariance: joint");

  // 1. The features through their plugins, all or nothing; the map's rows
  //    renumbered after this run's robot rows.
  std::vector<MapFeature> features = restored_features(map, file);
  const int k = static_cast<int>(dofs_.size());
  const auto renumber = [&](std::vector<int>& idx) {
    for (int& i : idx) i = i - cov.first_row + k;
  };
  std::vector<SharedCoordinate> shared;
  for (const StoredShared& s : map.shared) {
    shared.push_back({s.id, s.kind, s.state_idx, s.members});
    renumber(shared.back().state_idx);
  }
  MapSessionReport report;
  report.file = file.string();
  if (localize) {
    if (config_.map.extend_when_unmapped > 0.0 && !cov.joint)
      throw fail("map.extend_when_unmapped needs the joint covariance of the map (to map on from it), and this map "
                 "holds only each feature's marginal (saved with output.map_covariance: marginal)");
    std::shared_ptr<const Eigen::MatrixXd> joint;
    if (cov.joint)  // the map's block (the saved robot is not this run's robot)
      joint = std::make_shared<const Eigen::MatrixXd>(cov.joint->bottomRightCorner(cov.rows, cov.rows));
    if (config_.map.extend_when_unmapped > 0.0) map_joint_ = joint;
    considered_ = std::make_unique<ConsideredMap>(k, cov.rows, std::move(joint), config_.map.working_set_rows);
  }
  std::vector<MapFeature> kept;
  for (std::size_t i = 0; i < features.size(); ++i) {
    MapFeature& mf = features[i];
    renumber(mf.state_idx);
    renumber(mf.own_idx);
    // This session's history starts now (steps and path distance are the run's).
    mf.created_step = mf.last_seen_step = 0;
    mf.created_path = mf.last_seen_path = 0.0;
    next_feature_id_ = std::max(next_feature_id_, mf.id + 1);
    if (localize) {
      // Tentative features are evidence for mapping, not part of the map.
      if (mf.feature->mspace_dim() == 0) {
        ++report.tentative_dropped;
        continue;
      }
      considered_->set_block(mf.state_idx, map.features[i].covariance);
    }
    loaded_state_[mf.id] = {mf.feature->coords(), mf.feature->mspace_dim()};
    kept.push_back(std::move(mf));
  }
  for (const SharedCoordinate& c : shared) next_shared_id_ = std::max(next_shared_id_, c.id + 1);
  report.loaded = static_cast<int>(kept.size());

  // 2. The robot, and 3. (extend) the map's rows in the estimator, in one
  //    augmentation δx_map = J δx_r + w, w ~ N(0, C):
  //    - start: config — the robot where the configuration (or the source)
  //      puts it, with initial_pose.sigma, uncorrelated with the map: J = 0,
  //      C = P_mm, the map's block of the saved joint covariance;
  //    - start: map_end — the robot where the map's run ended, with its saved
  //      covariance P_rr and its correlation with the map: J = P_mr P_rr⁻¹,
  //      C = P_mm − P_mr P_rr⁻¹ P_rm (the map given the robot), so that the
  //      estimator holds the saved joint covariance and the session goes on
  //      as the saved run would have.
  const bool from_end = config_.map.start_at_map_end;
  if (from_end) x_r_ = map.robot_pose;
  Eigen::MatrixXd P_robot;
  if (localize || !from_end) {
    P_robot = initial_covariance();
  } else if (cov.first_row != k) {
    throw fail("start: map_end needs the robot coordinates the map's run estimated (" +
               std::to_string(cov.first_row) + " rows; this run's motion model estimates " + std::to_string(k) + ")");
  } else {
    P_robot = cov.joint->topLeftCorner(k, k);
  }
  reset_estimator(P_robot);
  // A re-linearising estimator's problem starts again at this pose; the map's
  // rows enter it below as a linear factor (Problem::added).
  if (problem_) problem_->start(P_robot);
  if (!localize && cov.rows > 0) {
    const Eigen::MatrixXd& P = *cov.joint;
    const Eigen::MatrixXd P_mm = P.bottomRightCorner(cov.rows, cov.rows);
    StateAugmentation aug;
    if (from_end) {
      const Eigen::LDLT<Eigen::MatrixXd> P_rr(P.topLeftCorner(k, k));
      if (P_rr.info() != Eigen::Success || !(P_rr.vectorD().array() > 0.0).all())
        throw fail("start: map_end: the saved robot covariance is not positive definite");
      const Eigen::MatrixXd P_mr = P.bottomLeftCorner(cov.rows, k);
      aug.idx = robot_idx_;
      aug.J = P_rr.solve(P_mr.transpose()).transpose();
      const Eigen::MatrixXd C = P_mm - aug.J * P_mr.transpose();
      aug.C_new = 0.5 * (C + C.transpose());
    } else {
      aug.J = Eigen::MatrixXd::Zero(cov.rows, 0);
      aug.C_new = P_mm;
    }
    const int first =
        guarded(config_.estimator.instance, *estimator_lib_, "augment", [&] { return estimator_->augment(aug); });
    if (first != k || estimator_->dim() != k + cov.rows)
      throw fail("estimator '" + config_.estimator.plugin + "' put the map's " + std::to_string(cov.rows) +
                 " rows at " + std::to_string(first) + " (expected " + std::to_string(k) + ")");
    if (problem_) problem_->added(aug, first);  // the old session marginalised: the map as a prior
  }
  report.searched = config_.map.search_pose;
  map_session_ = report;
  if (config_.map.search_pose) {
    // The kidnapped robot (slam_pose_search.cpp): the map waits aside while
    // the run maps in the frame of its first pose, which is the origin.
    pose_search_ = std::make_unique<PoseSearch>();
    pose_search_->map_features = std::move(kept);
    pose_search_->map_shared = std::move(shared);
    pose_search_->considered = std::move(considered_);
    x_r_[kX] = x_r_[kY] = x_r_[kTheta] = 0.0;
    reset_estimator(Eigen::MatrixXd::Zero(static_cast<Eigen::Index>(k), static_cast<Eigen::Index>(k)));
    return;
  }
  features_ = std::move(kept);
  shared_ = std::move(shared);
  associator_.map_changed();
}

void Slam::skip_data_steps() {
  DataStep skipped;
  for (std::int64_t k = 0; k < config_.skip_steps; ++k)
    if (!guarded(config_.source.instance, *source_lib_, "next", [&] { return source_->next(skipped); }))
      throw ConfigError(config_.file.string() + ": run.skip_steps: the data ends after " + std::to_string(k) +
                        " steps, before the " + std::to_string(config_.skip_steps) + " to skip");
}

Eigen::MatrixXd Slam::state_covariance(const std::vector<int>& idx) const {
  // Checked (size, finiteness, exceptions named): association, the map files
  // and the picture index these rows by the request, so a plugin's matrix of
  // another size would be read out of bounds.
  if (!considered_) return checked_marginal(idx);
  return considered_->covariance(idx, checked_marginal(robot_idx_));
}

Eigen::VectorXd Slam::consider_update(const std::vector<LinearizedObservation>& obs) {
  const std::vector<LinearizedObservation> robot_only = {
      considered_->condition(obs, checked_marginal(robot_idx_), step_)};
  const Eigen::VectorXd dx = estimator_update(robot_only, "update");
  considered_->commit();
  return dx;
}

void Slam::watch_for_unmapped(bool matched) {
  if (matched || step_ == 1) last_matched_path_ = path_distance_;
  if (path_distance_ - last_matched_path_ < config_.map.extend_when_unmapped) return;
  // The robot left the map: from now on the run maps on from it (extend). The
  // map's rows enter the estimator with the covariance the consider update
  // has kept, δx_m = P_mr P_rr⁻¹ δx_r + w (considered_map.hpp), so the
  // estimator holds the joint covariance of robot and map as it is now.
  const StateAugmentation aug = considered_->as_augmentation(checked_marginal(robot_idx_), *map_joint_);
  const int k = static_cast<int>(robot_idx_.size());
  const int first =
      guarded(config_.estimator.instance, *estimator_lib_, "augment", [&] { return estimator_->augment(aug); });
  if (first != k || estimator_->dim() != k + static_cast<int>(aug.C_new.rows()))
    throw PluginError(config_.estimator.instance + " (plugin '" + config_.estimator.plugin + "'): put the map's " +
                      std::to_string(aug.C_new.rows()) + " rows at " + std::to_string(first) + " (expected " +
                      std::to_string(k) + ")");
  map_session_->covariance_model = considered_->joint() ? "joint" : "feature blocks";
  map_session_->working_set_evictions = considered_->evicted();
  considered_.reset();
  map_joint_.reset();
  config_.map.mode = MapConfig::Mode::Extend;
  map_session_->switched_to_mapping_at_step = step_;
  map_session_->switched_at_path = path_distance_;
  associator_.map_changed();
  log_->info("step ", step_, ": no measurement matched the map over the last ", config_.map.extend_when_unmapped,
             " m of path: localize switches to mapping (map.extend_when_unmapped)");
}

std::optional<Slam::MapSessionReport> Slam::map_session_report() const {
  if (!map_session_) return std::nullopt;
  MapSessionReport r = *map_session_;
  // Features made while the run searched its pose were its own, not the map's.
  r.added = pose_search_ ? 0 : static_cast<int>(stats_.created - created_while_searching_);
  const std::vector<MapFeature>& map_now = pose_search_ ? pose_search_->map_features : features_;
  if (considered_) {
    r.covariance_model = considered_->joint() ? "joint" : "feature blocks";
    r.working_set_evictions = considered_->evicted();
  }
  std::unordered_map<int, const MapFeature*> now;
  for (const MapFeature& mf : map_now) now[mf.id] = &mf;
  for (const auto& [id, state] : loaded_state_) {
    const auto it = now.find(id);
    if (it == now.end() || it->second->feature->mspace_dim() != state.second ||
        it->second->feature->coords() != state.first)
      ++r.changed;
  }
  return r;
}

}  // namespace mspace::kernel
