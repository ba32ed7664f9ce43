// slam_pose_search.cpp — global localization, the kidnapped robot (issue 16,
// item 3; docs/maps.md §3): `initial_pose: search` in a localize run.
//
// Where the robot starts in the loaded map is unknown. Until it is found:
//
//   the run maps   in a frame of its own (the first pose is the origin), as a
//                  mapping run does: its features enter its estimator, and
//                  the loaded map waits aside (PoseSearch), untouched;
//   searches       every tenth of association.loop_local_path of travel, the
//                  features the run has seen in the last two loop_local_path
//                  metres (its local map) are looked for in the whole loaded
//                  map at every heading (locate_local_map, loop_closing.hpp):
//                  Hough voting, refinement, the joint compatibility test of
//                  the aligned maps, and no clearly different placement
//                  nearly as good anywhere in the map;
//   confirmation   a placement is taken only when a later search finds the
//                  same one with local features the first did not pair (as
//                  loop closing confirms a closure): one local map may fit a
//                  wrong place by chance, and a symmetric building offers
//                  several right-looking places; until the ambiguity is
//                  broken the run is "not localized" and keeps searching.
//
// Once placed, everything the run recorded moves into the map's frame by the
// placement T — the robot, the trajectory so far, the dead-reckoning
// baseline — the run's own features are dropped, and the run goes on as a
// localize run (map_session.cpp) from there. The robot's covariance is its
// covariance in the run's frame carried over by T, plus the placement's own
// uncertainty: an over-estimate (the robot is known better relative to the
// local map than to the run's origin), which the first updates against the
// map reduce.
//
// A run whose data ends before it is placed puts the loaded map back (the
// map it writes is the loaded one, unchanged) and says so; its poses stay in
// its own frame.
#include <algorithm>
#include <cmath>
#include <numbers>
#include <sstream>

#include "considered_map.hpp"
#include "loop_closing.hpp"
#include "problem.hpp"
#include "slam.hpp"

namespace mspace::kernel {

namespace {

/// The category of a search's answer, for the log: a line at info level when
/// it changes, at debug level otherwise.
std::string category(const std::string& reason) { return reason.substr(0, reason.find(':')); }

}  // namespace

void Slam::search_pose() {
  PoseSearch& s = *pose_search_;
  const AssociationConfig& a = config_.association;
  if (path_distance_ - s.last_search_path < 0.1 * a.loop_local_path) return;

  // The local map: the run's own estimated features seen lately.
  std::vector<int> local_idx;
  for (std::size_t i = 0; i < features_.size(); ++i) {
    const MapFeature& mf = features_[i];
    if (mf.merged_into != 0 || mf.state_idx.empty() || mf.feature->mspace_dim() == 0) continue;
    if (mf.last_seen_path >= path_distance_ - 2.0 * a.loop_local_path) local_idx.push_back(static_cast<int>(i));
  }
  if (static_cast<int>(local_idx.size()) < a.loop_min_matches) return;
  const std::int64_t signature = local_map_signature(local_idx);
  if (signature == s.last_signature) return;  // nothing new to search with
  s.last_signature = signature;
  s.last_search_path = path_distance_;

  if (s.map_shapes.empty()) {  // the map as map matching sees it, once (it does not change)
    const Eigen::MatrixXd P_rr = checked_marginal(robot_idx_);
    for (std::size_t i = 0; i < s.map_features.size(); ++i) {
      const MapFeature& mf = s.map_features[i];
      if (mf.feature->mspace_dim() == 0) continue;
      FeatureShape shape = feature_shape(mf, s.considered->covariance(mf.state_idx, P_rr));
      shape.feature = static_cast<int>(i);
      s.map_shapes.push_back(std::move(shape));
    }
  }
  std::vector<FeatureShape> local;
  for (int i : local_idx) local.push_back(estimated_shape(i));
  const MapMatchOptions o = map_match_options();  // its window is set by locate_local_map
  const Eigen::Vector2d here = x_r_.head<2>();
  const MapMatch match = locate_local_map(local, s.map_shapes, here, o);
  MapSessionReport& report = *map_session_;
  ++report.searches;

  const auto say = [&](const std::string& what) {
    const bool news = category(what) != category(report.last_search);
    report.last_search = what;
    const std::string line = "step " + std::to_string(step_) + ": not localized yet (search " +
                             std::to_string(report.searches) + ", " + std::to_string(local.size()) +
                             " local features in " + std::to_string(s.map_shapes.size()) + " of the map): " + what;
    if (news) log_->info(line);
    else if (log_->enabled(LogLevel::Debug)) log_->debug(line);
  };
  double moved = 0.0, turned = 0.0;
  const auto agrees = [&](const PendingClosure& p, const MapMatchHypothesis& h) {
    return placements_agree(p.motion, p.sigma_translation, p.sigma_rotation, h, here, o.floor_sigma, moved, turned);
  };
  if (!match.accepted) {
    // As for loop closing: a search that found no placement, or the waiting
    // one again on too little evidence, says nothing against the waiting one;
    // an ambiguous answer or a different best placement drops it.
    const bool ambiguous = match.reason.rfind("ambiguous", 0) == 0;
    if (!(s.waiting.active && !ambiguous && (match.best.pairs.empty() || agrees(s.waiting, match.best))))
      s.waiting = PendingClosure{};
    say(match.reason);
    return;
  }
  std::vector<int> paired_ids;
  for (const auto& [li, oi] : match.best.pairs)
    paired_ids.push_back(features_[static_cast<std::size_t>(local[static_cast<std::size_t>(li)].feature)].id);
  const bool same = s.waiting.active && agrees(s.waiting, match.best);
  const bool fresh = same && std::any_of(paired_ids.begin(), paired_ids.end(), [&](int id) {
                       return std::find(s.waiting.local_ids.begin(), s.waiting.local_ids.end(), id) ==
                              s.waiting.local_ids.end();
                     });
  if (!(same && fresh)) {
    std::ostringstream what;
    what.precision(3);
    if (s.waiting.active && !same)
      what << "placement differs from the previous search's by " << moved << " m, "
           << turned * 180.0 / std::numbers::pi << " deg; ";
    if (!same)
      s.waiting = PendingClosure{true, match.best.motion, match.best.sigma_translation, match.best.sigma_rotation,
                                 paired_ids};
    const Eigen::Vector2d at = match.best.motion.apply(here);
    what << "a placement pairs " << match.best.pairs.size() << " of " << local.size() << " local features (robot at "
         << at.x() << ", " << at.y() << " m, " << (x_r_[kTheta] + match.best.motion.theta) * 180.0 / std::numbers::pi
         << " deg): waiting for a search with new evidence";
    say(what.str());
    return;
  }

  // Confirmed: the run moves into the map's frame.
  MapSessionReport::Localization found;
  found.step = step_;
  found.t = t_;
  found.path = path_distance_;
  found.paired = static_cast<int>(match.best.pairs.size());
  found.local = static_cast<int>(local.size());
  found.rival = match.rival_matches;
  found.sigma_translation = match.best.sigma_translation;
  found.sigma_rotation = match.best.sigma_rotation;
  found.features_discarded = static_cast<int>(features_.size());
  const PlanarMotion T = match.best.motion;
  install_searched_map(&T, match.best.sigma_translation, match.best.sigma_rotation);
  found.x = x_r_[kX];
  found.y = x_r_[kY];
  found.theta = x_r_[kTheta];
  report.localized = found;
  report.last_search.clear();
  std::ostringstream what;
  what.precision(4);
  what << "step " << step_ << ": localized in the map after " << found.path << " m of travel and "
       << report.searches << " searches: robot at " << found.x << ", " << found.y << " m, "
       << found.theta * 180.0 / std::numbers::pi << " deg; " << found.paired << " of " << found.local
       << " local features paired (best other placement pairs " << found.rival << "), placement σ "
       << found.sigma_translation << " m, " << found.sigma_rotation * 180.0 / std::numbers::pi << " deg";
  log_->info(what.str());
}

void Slam::install_searched_map(const PlanarMotion* T, double sigma_translation, double sigma_rotation) {
  PoseSearch& s = *pose_search_;
  Eigen::MatrixXd P = checked_marginal(robot_idx_);
  if (T != nullptr) {
    // Every pose recorded so far, and the robot, into the map's frame: a
    // rigid motion moves positions and turns headings.
    const auto move = [&](Pose6& p) {
      const Eigen::Vector2d q = T->apply(Eigen::Vector2d(p[kX], p[kY]));
      p[kX] = q.x();
      p[kY] = q.y();
      p[kTheta] = wrap_angle(p[kTheta] + T->theta);
    };
    move(x_r_);
    move(dead_reckoning_pose_);
    for (auto* poses : {&trajectory_, &evaluated_, &dead_reckoning_})
      for (StampedPose& p : *poses) move(p.pose);
    // P ← J P Jᵀ + the placement's uncertainty (its σ on the position and the
    // heading, about the robot: T turns about the robot's position).
    const auto k = static_cast<Eigen::Index>(dofs_.size());
    Eigen::MatrixXd J = Eigen::MatrixXd::Identity(k, k);
    Eigen::MatrixXd Q = Eigen::MatrixXd::Zero(k, k);
    int ix = -1, iy = -1;
    for (Eigen::Index i = 0; i < k; ++i) {
      if (dofs_[static_cast<std::size_t>(i)] == kX) ix = static_cast<int>(i);
      if (dofs_[static_cast<std::size_t>(i)] == kY) iy = static_cast<int>(i);
      if (dofs_[static_cast<std::size_t>(i)] == kTheta) Q(i, i) = sigma_rotation * sigma_rotation;
    }
    if (ix >= 0 && iy >= 0) {
      const double c = std::cos(T->theta), sn = std::sin(T->theta);
      J(ix, ix) = c;
      J(ix, iy) = -sn;
      J(iy, ix) = sn;
      J(iy, iy) = c;
      Q(ix, ix) = Q(iy, iy) = sigma_translation * sigma_translation;
    }
    P = J * P * J.transpose() + Q;
    P = 0.5 * (P + P.transpose());
  }
  // The run's own features go; the estimator holds the robot alone again
  // and the loaded map comes in as a localize run has it.
  created_while_searching_ = stats_.created;
  features_ = std::move(s.map_features);
  shared_ = std::move(s.map_shared);
  considered_ = std::move(s.considered);
  reset_estimator(P);
  pose_search_.reset();
  last_matched_path_ = path_distance_;
  associator_.map_changed();
}

}  // namespace mspace::kernel
