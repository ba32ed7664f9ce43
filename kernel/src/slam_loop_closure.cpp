// slam_loop_closure.cpp — Slam's side of map matching (loop_closing.hpp):
// which features form the local and the old map, the search window, and
// what an accepted closure does to the estimate.
//
// After a step that created or matched features, when the robot has moved a
// tenth of association.loop_local_path since the last search:
//   local map  features in the estimator created within the last
//              loop_local_path metres of travel;
//   old map    features in the estimator created more than
//              loop_min_gap_path metres ago (some may be tracked again
//              already: a re-entry often re-associates a feature or two before
//              the duplicates give the place away);
//   window     3σ of the robot's position and heading plus the drift the
//              odometry may have had since the robot was last anchored to
//              the old map (note_anchor: matches with old features that fix
//              its position and heading): loop_drift_per_metre (and
//              _deg_per_metre) of that path.
// A placement is taken only when it is found twice: a later search, after
// the robot has mapped more of the place, must find the same placement with
// local features the first did not pair (a local map of a few metres fits
// a wrong place by chance in a corridor with doors at a regular spacing).
// Searches in between that place nothing, or place it again without new
// evidence, keep it waiting; an ambiguous search or a different placement
// drops it.
// An accepted closure declares each paired local feature a duplicate of its
// old partner (MapFeature::merged_into: never associated again; the old one
// absorbs the duplicate's dense information, Feature::absorb). With a
// re-linearising estimator the recent trajectory and local map are first
// moved to the closure's guess — the correction spread along the path since
// the old map was last seen — and a coincidence factor per pair is added
// (problem.hpp); the estimator re-optimises. An EKF gets the coincidences as
// one update, linearised where it stands (it cannot do better).
#include <algorithm>
#include <cmath>
#include <limits>
#include <numbers>
#include <sstream>
#include <unordered_set>

#include <Eigen/Cholesky>

#include "association.hpp"
#include "loop_closing.hpp"
#include "occupancy_grid.hpp"
#include "problem.hpp"
#include "scan_evidence.hpp"
#include "slam.hpp"

namespace mspace::kernel {

namespace {

/// Coincidence factors' σ: two copies of one object, to about a centimetre.
constexpr double kCoincidenceSigma = 0.01;
/// Hard limits of the search window, whatever the drift allowance says.
constexpr double kMaxWindowTranslation = 30.0;  // m
constexpr double kMaxWindowRotation = 1.05;     // rad (60°)
/// An accepted pairing must fix the motion at least this well (1σ); the
/// estimator then refines it with every feature's own covariance.
constexpr double kMaxMotionSigmaTranslation = 0.3;  // m
constexpr double kMaxMotionSigmaRotation = 0.035;   // rad (2°)

/// The planar block of the robot covariance: σ of the position (largest
/// axis) and of the heading; 0 where the state does not estimate them.
/// Where x, y and the heading sit among the robot's estimated pose
/// coordinates `dofs` (−1 where they are not estimated).
struct PlanarIndices {
  int x = -1, y = -1, theta = -1;
  bool complete() const { return x >= 0 && y >= 0 && theta >= 0; }
};
PlanarIndices planar_indices(const std::vector<int>& dofs) {
  PlanarIndices p;
  for (std::size_t i = 0; i < dofs.size(); ++i) {
    if (dofs[i] == kX) p.x = static_cast<int>(i);
    if (dofs[i] == kY) p.y = static_cast<int>(i);
    if (dofs[i] == kTheta) p.theta = static_cast<int>(i);
  }
  return p;
}

std::pair<double, double> planar_sigmas(const Eigen::MatrixXd& P, const std::vector<int>& dofs) {
  const auto [ix, iy, it] = planar_indices(dofs);
  double position = 0.0, heading = 0.0;
  if (ix >= 0 && iy >= 0) position = std::sqrt(std::max(0.0, std::max(P(ix, ix), P(iy, iy))));
  if (it >= 0) heading = std::sqrt(std::max(0.0, P(it, it)));
  return {position, heading};
}

}  // namespace

// An anchor: the step's matches with old-map features (created over
// loop_min_gap_path m ago) fix the robot to the old map as well as an
// accepted closure must (kMaxMotionSigma*, 1σ) — information Σ J_rᵀ S⁻¹ J_r
// with S = C_η + J_f P_f J_fᵀ (the old map's own uncertainty counts).
// Matching two long parallel lines again fixes the heading and the offset
// across them, not the position along them: that is no anchor, and the
// search window keeps growing with the path. A revisit anchor
// (association.loop_revisit_window) is one made by revisited features only.
void Slam::note_anchor(const std::vector<std::pair<int, const Candidate*>>& matched) {
  const auto k = static_cast<Eigen::Index>(dofs_.size());
  const double gap = config_.association.loop_min_gap_path;
  // Two sums: every old feature matched, and only the revisits among them — features seen again after
  // loop_min_gap_path m unseen (now, or earlier in this run of observations), not ones tracked since they were
  // created, however long ago: a feature followed for 40 m says nothing about the drift since the robot was last
  // in that place.
  Eigen::MatrixXd info_all = Eigen::MatrixXd::Zero(k, k), info_revisits = Eigen::MatrixXd::Zero(k, k);
  bool any = false, any_revisit = false;
  for (const auto& [feature, candidate] : matched) {
    const MapFeature& mf = features_[static_cast<std::size_t>(feature)];
    if (mf.feature->mspace_dim() == 0 || mf.created_path > path_distance_ - gap) continue;
    const Candidate& c = *candidate;
    const Eigen::MatrixXd J_f = c.J_state.rightCols(c.J_state.cols() - k);
    const Eigen::MatrixXd S = c.C_eta + J_f * checked_marginal(mf.state_idx) * J_f.transpose();
    const Eigen::LDLT<Eigen::MatrixXd> ldlt(S);
    if (ldlt.info() != Eigen::Success || !ldlt.isPositive()) continue;
    const Eigen::MatrixXd J_r = c.J_state.leftCols(k);
    const Eigen::MatrixXd info = J_r.transpose() * ldlt.solve(J_r);
    info_all += info;
    any = true;
    if (path_distance_ - mf.last_seen_path > gap || mf.seen_since_path > mf.created_path) {
      info_revisits += info;
      any_revisit = true;
    }
  }
  const auto fixes_the_robot = [&](const Eigen::MatrixXd& info) {
    // A tiny ridge keeps directions nothing measured (height, tilt) finite
    // without touching the planar ones that were measured.
    const Eigen::MatrixXd cov =
        (info + 1e-9 * Eigen::MatrixXd::Identity(k, k)).ldlt().solve(Eigen::MatrixXd::Identity(k, k));
    const auto [sigma_xy, sigma_theta] = planar_sigmas(cov, dofs_);
    return sigma_xy <= kMaxMotionSigmaTranslation && sigma_theta <= kMaxMotionSigmaRotation;
  };
  if (any && fixes_the_robot(info_all)) last_anchor_path_ = path_distance_;
  if (any_revisit && fixes_the_robot(info_revisits)) last_revisit_path_ = path_distance_;
}

// A closure is right when it puts the robot where the old features say it
// is: for each pair, the robot's pose relative to its pose when it first saw
// the old feature (created it) must be the true relative pose (relative poses do not
// depend on how the old map as a whole has drifted). The median over the
// pairs is compared with 1 m and 5°.
std::optional<std::pair<double, double>> Slam::disagreement_with_ground_truth(
    const PlanarMotion& T, const std::vector<double>& seen_paths, const DataStep& data) const {
  if (!data.ground_truth || ground_truth_.empty()) return std::nullopt;
  const auto planar = [](const Pose6& x) { return Eigen::Vector3d(x[kX], x[kY], x[kTheta]); };
  const auto relative = [](const Eigen::Vector3d& from, const Eigen::Vector3d& to) {
    const double c = std::cos(from.z()), s = std::sin(from.z());
    const Eigen::Vector2d d = to.head<2>() - from.head<2>();
    return Eigen::Vector3d(c * d.x() + s * d.y(), -s * d.x() + c * d.y(), wrap_angle(to.z() - from.z()));
  };
  const Eigen::Vector3d now(T.apply(Eigen::Vector2d(x_r_.head<2>())).x(), T.apply(Eigen::Vector2d(x_r_.head<2>())).y(),
                            wrap_angle(x_r_[kTheta] + T.theta));
  const Eigen::Vector3d truth_now = planar(*data.ground_truth);
  std::vector<double> position, heading;
  for (double seen : seen_paths) {
    const auto then = std::lower_bound(record_path_.begin(), record_path_.end(), seen);
    if (then == record_path_.end()) continue;
    const StampedPose& est = trajectory_[static_cast<std::size_t>(then - record_path_.begin())];
    const auto gt = std::lower_bound(ground_truth_.begin(), ground_truth_.end(), est.t,
                                     [](const StampedPose& g, double t) { return g.t < t; });
    if (gt == ground_truth_.end() || std::abs(gt->t - est.t) > 1e-6) continue;
    const Eigen::Vector3d e = relative(planar(est.pose), now) - relative(planar(gt->pose), truth_now);
    position.push_back(e.head<2>().norm());
    heading.push_back(std::abs(wrap_angle(e.z())));
  }
  if (position.empty()) return std::nullopt;
  const auto median = [](std::vector<double> v) {
    std::nth_element(v.begin(), v.begin() + static_cast<std::ptrdiff_t>(v.size() / 2), v.end());
    return v[v.size() / 2];
  };
  return std::pair{median(position), median(heading)};
}

std::optional<std::pair<int, int>> Slam::pairs_against_ground_truth(const MapMatchHypothesis& h,
                                                                    const std::vector<FeatureShape>& local,
                                                                    const std::vector<FeatureShape>& old,
                                                                    const DataStep& data) const {
  if (!data.ground_truth || ground_truth_.empty()) return std::nullopt;
  const auto to_truth = [&](double path) { return estimate_to_truth_at(path); };
  // A local feature is estimated together with the current pose (the same
  // filter state); an old one was last updated from the pose that last saw
  // it (or, second opinion, the one that created it), smoothed with it since.
  const Pose6& truth_now = *data.ground_truth;
  const Eigen::Vector2d here(x_r_[kX], x_r_[kY]);
  const PlanarMotion local_to_truth{wrap_angle(truth_now[kTheta] - x_r_[kTheta]),
                                    Eigen::Vector2d(truth_now[kX], truth_now[kY]) - here, here};
  int wrong = 0, checked = 0;
  std::ostringstream residuals;
  residuals.precision(2);
  for (const auto& [li, oi] : h.pairs) {
    const FeatureShape& a = local[static_cast<std::size_t>(li)];
    const FeatureShape& b = old[static_cast<std::size_t>(oi)];
    const MapFeature& fb = features_[static_cast<std::size_t>(b.feature)];
    double worst = std::numeric_limits<double>::infinity();
    for (const double path : {fb.last_seen_path, fb.created_path}) {
      const auto Gb = to_truth(path);
      if (!Gb) continue;
      if (const auto d = distance_apart(a, local_to_truth, b, *Gb)) worst = std::min(worst, *d);
    }
    if (!std::isfinite(worst)) continue;
    ++checked;
    residuals << " " << worst;
    if (log_->enabled(LogLevel::Debug)) {  // where each copy lies in the true frame, and when the old one was observed
      residuals << " [old observed at " << fb.created_path << "–" << fb.last_seen_path << " m of travel; true frame: local "
                << local_to_truth.apply(*a.layout, a.x).transpose();
      if (const auto Gb = to_truth(fb.last_seen_path)) residuals << ", old " << Gb->apply(*b.layout, b.x).transpose();
      residuals << "]";
    }
    if (worst > 0.5) ++wrong;
  }
  if (log_->enabled(LogLevel::Debug))
    log_->debug("step ", step_, ": the pairs' worst residuals in the true frame (m):", residuals.str());
  if (checked == 0) return std::nullopt;
  return std::pair{wrong, checked};
}

void Slam::check_against_ground_truth(const PlanarMotion& T, const std::vector<double>& seen_paths,
                                      const DataStep& data) {
  const auto off = disagreement_with_ground_truth(T, seen_paths, data);
  if (!off) return;
  const auto [disagreement, heading_disagreement] = *off;
  ++stats_.loop_checked;
  stats_.loop_worst_disagreement = std::max(stats_.loop_worst_disagreement, disagreement);
  if (disagreement > 1.0 || heading_disagreement > 5.0 * std::numbers::pi / 180.0) {
    ++stats_.loop_false;
    log_->warn("step ", step_, ": the loop closure disagrees with the ground truth by ", disagreement, " m, ",
               heading_disagreement * 180.0 / std::numbers::pi, " deg: a false closure");
  }
}

std::optional<PlanarMotion> Slam::estimate_to_truth_at(double path) const {
  // p ↦ R(θ_gt − θ_est)(p − t_est) + t_gt at the record where `path` was reached.
  const auto then = std::lower_bound(record_path_.begin(), record_path_.end(), path);
  if (then == record_path_.end()) return std::nullopt;
  const StampedPose& est = trajectory_[static_cast<std::size_t>(then - record_path_.begin())];
  const auto gt = std::lower_bound(ground_truth_.begin(), ground_truth_.end(), est.t,
                                   [](const StampedPose& g, double t) { return g.t < t; });
  if (gt == ground_truth_.end() || std::abs(gt->t - est.t) > 1e-6) return std::nullopt;
  const Eigen::Vector2d t_est(est.pose[kX], est.pose[kY]), t_gt(gt->pose[kX], gt->pose[kY]);
  return PlanarMotion{wrap_angle(gt->pose[kTheta] - est.pose[kTheta]), t_gt - t_est, t_est};
}

std::optional<Slam::TrueCounterparts> Slam::true_counterparts(const std::vector<FeatureShape>& local,
                                                             const std::vector<FeatureShape>& old,
                                                             const DataStep& data) const {
  if (!data.ground_truth || ground_truth_.empty()) return std::nullopt;
  const Pose6& truth_now = *data.ground_truth;
  const Eigen::Vector2d here(x_r_[kX], x_r_[kY]);
  const PlanarMotion local_to_truth{wrap_angle(truth_now[kTheta] - x_r_[kTheta]),
                                    Eigen::Vector2d(truth_now[kX], truth_now[kY]) - here, here};
  std::vector<std::optional<PlanarMotion>> old_to_truth;
  for (const FeatureShape& b : old)
    old_to_truth.push_back(estimate_to_truth_at(features_[static_cast<std::size_t>(b.feature)].last_seen_path));
  // For the debug log: where a local feature without a counterpart lies in the true frame, and the old feature
  // of its type nearest to it there (by footprint, then distance).
  const auto describe_unmatched = [&](const FeatureShape& a) {
    std::ostringstream what;
    what.precision(3);
    what << " #" << features_[static_cast<std::size_t>(a.feature)].id << " at ("
         << local_to_truth.apply(*a.layout, a.x).transpose() << ")";
    double nearest = std::numeric_limits<double>::infinity();
    std::size_t at = old.size();
    for (std::size_t j = 0; j < old.size(); ++j) {
      if (!old_to_truth[j] || old[j].type != a.type) continue;
      for (double margin : {0.3, 1.0, 3.0})
        if (footprints_overlap(a, local_to_truth, old[j], *old_to_truth[j], margin)) {
          const auto d = distance_apart(a, local_to_truth, old[j], *old_to_truth[j]);
          const double score = margin + (d ? *d : 10.0);
          if (score < nearest) {
            nearest = score;
            at = j;
          }
          break;
        }
    }
    if (at < old.size()) {
      const auto d = distance_apart(a, local_to_truth, old[at], *old_to_truth[at]);
      what << ": nearest old #" << features_[static_cast<std::size_t>(old[at].feature)].id << " at ("
           << old_to_truth[at]->apply(*old[at].layout, old[at].x).transpose() << "), " << (d ? *d : -1.0)
           << " m apart, " << (arranged_alike(a, local_to_truth, old[at], *old_to_truth[at], 0.3) ? "" : "not ")
           << "the same way round";
    } else {
      what << ": no old one within 3 m";
    }
    what << ";";
    return what.str();
  };
  TrueCounterparts c;
  for (const FeatureShape& a : local) {
    bool any = false;
    std::optional<std::size_t> counterpart;
    for (std::size_t j = 0; j < old.size() && !counterpart; ++j) {
      if (!old_to_truth[j] || old[j].type != a.type) continue;
      const auto d = distance_apart(a, local_to_truth, old[j], *old_to_truth[j]);
      if (!d) continue;
      any = true;
      if (*d <= 0.3 && footprints_overlap(a, local_to_truth, old[j], *old_to_truth[j], 0.3) &&
          arranged_alike(a, local_to_truth, old[j], *old_to_truth[j], 0.3))
        counterpart = j;
    }
    c.checked += any ? 1 : 0;
    if (!counterpart) {
      c.unmatched += describe_unmatched(a);
      continue;
    }
    ++c.found;
    c.pairs.emplace_back(static_cast<int>(&a - local.data()), static_cast<int>(*counterpart));
    // The robot taken to the truth through the current pose, then back into the estimate through the pose that
    // last saw the old feature (G⁻¹: q ↦ R(−θ)(q − pivot − t) + pivot).
    const PlanarMotion& G = *old_to_truth[*counterpart];
    const Eigen::Vector2d q = local_to_truth.apply(here) - G.pivot - G.t;
    const double cos_t = std::cos(G.theta), sin_t = std::sin(G.theta);
    const Eigen::Vector2d back =
        Eigen::Vector2d(cos_t * q.x() + sin_t * q.y(), -sin_t * q.x() + cos_t * q.y()) + G.pivot;
    const Eigen::Vector2d moved = back - here;
    c.needed.emplace_back(wrap_angle(local_to_truth.theta - G.theta), moved.x(), moved.y());
  }
  if (c.checked == 0) return std::nullopt;
  return c;
}

namespace {
/// The component-wise median of the motions the true counterparts need (θ, t_x, t_y).
Eigen::Vector3d median_need(const std::vector<Eigen::Vector3d>& needed) {
  Eigen::Vector3d median;
  for (int k = 0; k < 3; ++k) {
    std::vector<double> v;
    for (const Eigen::Vector3d& n : needed) v.push_back(n[k]);
    std::nth_element(v.begin(), v.begin() + static_cast<std::ptrdiff_t>(v.size() / 2), v.end());
    median[k] = v[v.size() / 2];
  }
  return median;
}
}  // namespace

std::string Slam::ground_truth_verdict(const MapMatch& match, const std::vector<FeatureShape>& local,
                                      const std::vector<FeatureShape>& old, const DataStep& data) const {
  std::ostringstream out;
  out.precision(3);
  if (const auto c = true_counterparts(local, old, data)) {
    out << " (ground truth: " << c->found << " of " << c->checked << " local features are old ones of the window";
    if (!c->needed.empty()) {
      // The component-wise median, and how far the counterparts' own motions lie from it.
      const Eigen::Vector3d median = median_need(c->needed);
      double spread = 0.0;
      for (const Eigen::Vector3d& n : c->needed) spread = std::max(spread, (n.tail<2>() - median.tail<2>()).norm());
      out << "; laying them on it needs " << median.tail<2>().norm() << " m, " << median[0] * 180.0 / std::numbers::pi
          << " deg (median), their own needs up to " << spread << " m apart";
    }
    out << ")";
  }
  if (match.probe_votes >= 0)
    out << " (ground truth: the transform gave that motion " << match.probe_votes << " votes, " << match.probe_outvoted
        << " of its peaks more)";
  if (match.best.pairs.empty()) return out.str();
  std::vector<double> seen;
  for (const auto& [li, oi] : match.best.pairs)
    seen.push_back(features_[static_cast<std::size_t>(old[static_cast<std::size_t>(oi)].feature)].created_path);
  const auto best = disagreement_with_ground_truth(match.best.motion, seen, data);
  const auto now = disagreement_with_ground_truth(PlanarMotion{}, seen, data);
  if (!best || !now) return out.str();
  out << " (ground truth: the best placement is " << best->first << " m, " << best->second * 180.0 / std::numbers::pi
      << " deg off; the estimate without it " << now->first << " m, " << now->second * 180.0 / std::numbers::pi
      << " deg)";
  // The verified hypothesis nearest the truth, and what kept it out.
  const MapMatchHypothesis* nearest = nullptr;
  const std::string* why = nullptr;
  std::pair<double, double> nearest_off{INFINITY, 0.0};
  std::size_t rank = 0;
  for (std::size_t k = 0; k < match.verified.size(); ++k) {
    const auto& [h, refused] = match.verified[k];
    std::vector<double> paths;
    for (const auto& [li, oi] : h.pairs)
      paths.push_back(features_[static_cast<std::size_t>(old[static_cast<std::size_t>(oi)].feature)].created_path);
    const auto off = disagreement_with_ground_truth(h.motion, paths, data);
    if (off && off->first < nearest_off.first) {
      nearest = &h;
      why = &refused;
      nearest_off = *off;
      rank = k;
    }
  }
  if (nearest != nullptr)
    out << " (ground truth: of " << match.verified.size() << " verified hypotheses the nearest, #" << rank + 1
        << ", is " << nearest_off.first << " m, " << nearest_off.second * 180.0 / std::numbers::pi << " deg off, "
        << nearest->pairs.size() << " pairs" << (nearest->seeded ? ", seeded" : "") << ", dense score "
        << nearest->dense_score << ": " << (why->empty() ? "acceptable" : *why) << ")";
  return out.str();
}

std::int64_t Slam::local_map_signature(const std::vector<int>& idx) const {
  // (kept below 2^50 so that a checkpoint stores it exactly as a double)
  constexpr std::int64_t kModulus = std::int64_t{1} << 50;
  auto signature = static_cast<std::int64_t>(idx.size());
  for (int i : idx) signature = (signature * 1009 + features_[static_cast<std::size_t>(i)].id) % kModulus;
  return signature;
}

FeatureShape Slam::estimated_shape(int i) const {
  const MapFeature& mf = features_[static_cast<std::size_t>(i)];
  FeatureShape s = feature_shape(mf, checked_marginal(mf.state_idx));
  s.feature = i;
  s.seen_first = mf.created_path;
  s.seen_last = mf.last_seen_path;
  return s;
}

MapMatchOptions Slam::map_match_options() const {
  const AssociationConfig& a = config_.association;
  MapMatchOptions o;
  o.min_matches = a.loop_min_matches;
  o.ambiguity_ratio = a.loop_ambiguity_ratio;
  o.probability = a.gate_probability;
  o.max_translation_std = kMaxMotionSigmaTranslation;
  o.max_rotation_std = kMaxMotionSigmaRotation;
  // The drift over loop_min_gap_path of travel is what makes a feature
  // "old" (beyond the association gate): two old features observed that far
  // apart in travel, and never together, may disagree as much with each other.
  o.pass_gap = a.loop_min_gap_path;
  return o;
}

// Scan evidence (scan_evidence.hpp): end points 10 cm apart along a scan,
// the recent ones thinned to one per 25 cm cell (at most 300), the old ones'
// field in 10 cm cells with σ 15 cm (the laser's noise is a centimetre or
// two; the rest is both maps' own distortion over loop_local_path m). All
// stated, not searched (README, "Range scans as evidence").
constexpr double kScanPointSpacing = 0.10;  // m
constexpr double kScanLocalCell = 0.25;     // m
constexpr double kScanResolution = 0.10;    // m
constexpr double kScanSigma = 0.15;         // m
/// Old scans taken within this of the last one used are left out.
constexpr double kScanKeyDistance = 0.2;    // m
constexpr double kScanKeyTurn = 0.087;      // rad (5°)
/// The recent end points are thinned further to at most this many (every k-th).
constexpr std::size_t kScanMaxLocalPoints = 300;
/// The scans search headings within ± this of the estimate at most (the
/// features search the whole window), for the search's cost, which grows
/// with it. Not a bound on the drift: a sparse log needed 20.8° after 403 m
/// (README, "Range scans as evidence").
constexpr double kScanMaxRotation = 0.35;  // rad (20°)
constexpr double kScanRotationStep = 0.0175;  // rad (1°)
/// What an end point costs where the old scans saw empty space.
constexpr double kScanMiss = 0.5;
/// The scans say something when their best placement explains this much.
constexpr double kScanMinScore = 0.4;
/// A feature placement scoring below this fraction of the scans' best is
/// contradicted by them.
constexpr double kScanAgreement = 0.8;
/// The scans' best placement is unique when no clearly different one scores
/// this fraction of it.
constexpr double kScanUniqueRatio = 0.9;
/// In the wider window (association.loop_wide_drift_per_metre) the scans'
/// placement is tried as a hypothesis only when it explains this much: the
/// window holds many more places that a few feature pairs could confirm by
/// chance (on 216 generated buildings, the two weakest false closures of a
/// single wide window were scans' placements scoring 0.47 and 0.48, 14 m and
/// 5 m along a corridor; README, "A second search in a wider window").
constexpr double kScanWideMinScore = 0.5;

/// Relocalization (association.relocalize_by_scans) follows a step whose own
/// odometry σ exceeds two cells of the scans' field or two of their rotation
/// steps: then the scans can tell the pose better than the prediction does.
constexpr double kRelocalizeStepSigma = 2.0 * kScanResolution;          // m
constexpr double kRelocalizeStepSigmaRotation = 2.0 * kScanRotationStep;  // rad
/// Gathered scans with fewer end points (one per 25 cm cell) are not placed.
constexpr std::size_t kRelocalizeMinPoints = 20;
/// The placement must explain this much of the gathered end points: the
/// wider window's floor (kScanWideMinScore), for the same reason — a window
/// of several metres and tens of degrees holds many places to fit by chance.
constexpr double kRelocalizeMinScore = kScanWideMinScore;

void Slam::log_scan_placement(const ScanPlacement& scans, std::size_t points, const std::vector<FeatureShape>& old,
                              const Eigen::Vector2d& here, const DataStep& data) const {
  const AssociationConfig& a = config_.association;
  std::vector<double> seen;
  for (const FeatureShape& f : old) seen.push_back(features_[static_cast<std::size_t>(f.feature)].created_path);
  const auto truth = disagreement_with_ground_truth(scans.best, seen, data);
  std::ostringstream what;
  what.precision(3);
  what << "step " << step_ << ": scans placed " << points << " end points (" << scans.best.t.norm() << " m, "
       << scans.best.theta * 180.0 / std::numbers::pi << " deg), score " << scans.score
       << ", best clearly different placement " << scans.rival_score << " (" << scans.leaves << " placements scored)";
  if (truth) what << "; ground truth: " << truth->first << " m, " << truth->second * 180.0 / std::numbers::pi << " deg off";
  if (scans.slide.squaredNorm() > 0.0) {
    what << "; the placements as good slide along (" << scans.slide.x() << ", " << scans.slide.y() << ") over "
         << scans.slide_extent << " m";
    // The point of that line nearest the truth (searched 1 m beyond the slide's extent either way).
    std::optional<std::pair<double, double>> nearest;
    double at = 0.0;
    for (double along = -scans.slide_extent - 1.0; along <= scans.slide_extent + 1.0; along += 0.1) {
      PlanarMotion slid = scans.best;
      slid.t += along * scans.slide;
      const auto off = disagreement_with_ground_truth(slid, seen, data);
      if (off && (!nearest || off->first < nearest->first)) {
        nearest = off;
        at = along;
      }
    }
    if (nearest)
      what << " (ground truth: the line passes " << nearest->first << " m, " << nearest->second * 180.0 / std::numbers::pi
           << " deg off, " << at << " m along)";
  }
  // Against the old scans taken within 2 m of where the placement puts
  // the robot: the old map may hold several passes that disagree.
  const Eigen::Vector2d placed = scans.best.apply(here);
  std::vector<double> paths;
  for (const KeptScan& s : scans_) {
    if (s.path > path_distance_ - a.loop_min_gap_path) break;
    if (s.record >= trajectory_.size()) continue;
    const Pose6& x = trajectory_[s.record].pose;
    if ((Eigen::Vector2d(x[kX], x[kY]) - placed).norm() < 2.0) paths.push_back(s.path);
  }
  if (const auto local_truth = disagreement_with_ground_truth(scans.best, paths, data))
    what << "; against the old scans there: " << local_truth->first << " m, "
         << local_truth->second * 180.0 / std::numbers::pi << " deg off";
  log_->debug(what.str());
}

void Slam::keep_scans(const DataStep& data) {
  for (const SensorReading& reading : data.readings) {
    const auto sensor = std::find_if(sensors_.begin(), sensors_.end(),
                                     [&](const SensorSlot& s) { return s.config.channel == reading.channel; });
    if (sensor == sensors_.end() || !is_range_scan(reading.values)) continue;
    KeptScan scan;
    scan.record = trajectory_.size();
    scan.path = path_distance_;
    scan.origin = Eigen::Vector2f(static_cast<float>(sensor->config.mount[kX]), static_cast<float>(sensor->config.mount[kY]));
    scan.points = scan_end_points(reading.values, sensor->config.mount, sensor->config.max_range, kScanPointSpacing);
    for (const Eigen::Vector2f& p : scan.points) scan.range = std::max(scan.range, (p - scan.origin).norm());
    if (!scan.points.empty()) scans_.push_back(std::move(scan));
  }
}

std::pair<Eigen::Matrix2d, Eigen::Vector2d> Slam::scan_pose(const KeptScan& s) const {
  const Pose6& x = s.record < trajectory_.size() ? trajectory_[s.record].pose : x_r_;
  const double c = std::cos(x[kTheta]), sn = std::sin(x[kTheta]);
  Eigen::Matrix2d R;
  R << c, -sn, sn, c;
  return {R, Eigen::Vector2d(x[kX], x[kY])};
}

std::vector<Eigen::Vector2d> Slam::scan_points(const std::function<bool(const KeptScan&)>& take,
                                               const Eigen::Vector2d& here, double& radius) const {
  std::vector<Eigen::Vector2d> points;
  radius = 0.0;
  std::unordered_set<std::int64_t> taken;
  for (const KeptScan& s : scans_) {
    if (!take(s)) continue;
    const auto [R, t] = scan_pose(s);
    for (const Eigen::Vector2f& q : s.points) {
      const Eigen::Vector2d p = R * q.cast<double>() + t;
      const auto ix = static_cast<std::int64_t>(std::floor(p.x() / kScanLocalCell));
      const auto iy = static_cast<std::int64_t>(std::floor(p.y() / kScanLocalCell));
      if (!taken.insert(ix * 2000003 + iy).second) continue;
      points.push_back(p);
      radius = std::max(radius, (p - here).norm());
    }
  }
  if (points.size() > kScanMaxLocalPoints) {
    const double stride = static_cast<double>(points.size()) / static_cast<double>(kScanMaxLocalPoints);
    std::vector<Eigen::Vector2d> kept;
    for (std::size_t i = 0; i < kScanMaxLocalPoints; ++i) kept.push_back(points[static_cast<std::size_t>(i * stride)]);
    points = std::move(kept);
  }
  return points;
}

std::unique_ptr<ScanField> Slam::old_scan_field(const Eigen::Vector2d& here, double reach,
                                                const std::function<bool(const KeptScan&)>& old_enough) const {
  std::vector<ScanRay> old;
  // Old scans from poses within kScanKeyDistance of the last one used add
  // little: one in such a run is used.
  Eigen::Vector3d last_used(std::nan(""), 0.0, 0.0);
  for (const KeptScan& s : scans_) {
    if (!old_enough(s)) break;  // (kept in the order of travel)
    const auto [R, t] = scan_pose(s);
    const double heading = std::atan2(R(1, 0), R(0, 0));
    if (std::isfinite(last_used.x()) && (t - last_used.head<2>()).norm() < kScanKeyDistance &&
        std::abs(std::remainder(heading - last_used.z(), 2.0 * std::numbers::pi)) < kScanKeyTurn)
      continue;
    if ((t - here).norm() > reach + s.range) continue;
    last_used << t, heading;
    const Eigen::Vector2d from = R * s.origin.cast<double>() + t;
    for (const Eigen::Vector2f& q : s.points) {
      const Eigen::Vector2d p = R * q.cast<double>() + t;
      if ((p - here).norm() <= reach) old.push_back({from, p});
    }
  }
  return std::make_unique<ScanField>(old, kScanResolution, kScanSigma, kScanMiss);
}

ScanPlacement Slam::place_scans(const Eigen::Vector2d& here, const MapMatchOptions& o,
                                std::unique_ptr<ScanField>& field, std::vector<Eigen::Vector2d>& local) const {
  const AssociationConfig& a = config_.association;
  double local_radius = 0.0;
  local = scan_points([&](const KeptScan& s) { return s.path >= path_distance_ - a.loop_local_path; }, here,
                      local_radius);
  const double reach = local_radius + o.max_translation + 3.0 * kScanSigma;
  field = old_scan_field(here, reach,
                         [&](const KeptScan& s) { return s.path <= path_distance_ - a.loop_min_gap_path; });
  ScanSearchOptions so;
  so.max_translation = o.max_translation;
  so.max_rotation = std::min(o.max_rotation, kScanMaxRotation);
  so.rotation_step = kScanRotationStep;
  so.rival_ratio = kScanUniqueRatio;  // every rival that could make the best not unique
  return field->search(local, here, so);
}

void Slam::relate_to_old_pose(const PlanarMotion& T, const MapMatchHypothesis& h) {
  const Eigen::Vector2d placed = T.apply(Eigen::Vector2d(x_r_[kX], x_r_[kY]));
  const Eigen::Vector3d sigma(h.sigma_translation, h.sigma_translation, h.sigma_rotation);
  relate_to_nearest_node(Eigen::Vector3d(placed.x(), placed.y(), wrap_angle(x_r_[kTheta] + T.theta)),
                         sigma.cwiseProduct(sigma).asDiagonal(),
                         path_distance_ - config_.association.loop_min_gap_path);
}

void Slam::relate_to_nearest_node(const Eigen::Vector3d& placed, const Eigen::Matrix3d& C_placed, double newest_path) {
  const int current = problem_->num_pose_nodes() - 1;
  int nearest = -1;
  double best = std::numeric_limits<double>::infinity();
  for (int node = 0; node < current; ++node) {
    const std::size_t record = problem_->node_record(node);
    if (record >= record_path_.size() || record_path_[record] > newest_path) break;  // (nodes in the order of travel)
    const Pose6 x = problem_->node_value(node);
    const double d = (Eigen::Vector2d(x[kX], x[kY]) - placed.head<2>()).norm();
    if (d < best) {
      best = d;
      nearest = node;
    }
  }
  if (nearest < 0) return;
  const Pose6 from = problem_->node_value(nearest);
  const double c = std::cos(from[kTheta]), s = std::sin(from[kTheta]);
  Eigen::Matrix3d Rt = Eigen::Matrix3d::Identity();  // map frame → the old node's frame
  Rt.topLeftCorner<2, 2>() << c, s, -s, c;
  const Eigen::Vector2d d = placed.head<2>() - Eigen::Vector2d(from[kX], from[kY]);
  const Eigen::Vector3d z(c * d.x() + s * d.y(), -s * d.x() + c * d.y(), wrap_angle(placed.z() - from[kTheta]));
  problem_->relate(nearest, current, z, Rt * C_placed * Rt.transpose());
  log_->debug("step ", step_, ": pose relation to the pose node of step record ", problem_->node_record(nearest), " (",
              best, " m from where the scans put the robot), sigma ", std::sqrt(C_placed(0, 0)), " m, ",
              std::sqrt(C_placed(2, 2)) * 180.0 / std::numbers::pi, " deg");
}

// Relocalizing after an uncertain step (association.relocalize_by_scans).
// A logging gap leaves the robot metres and degrees from where its wheels
// say, often back on mapped ground; the features it then sees are matched with
// a pose that uncertain, and a wrong match shrinks the covariance as much as
// a right one. The scans are kept anyway (keep_scans): those taken from the
// uncertain step on are gathered (mapping goes on) until they hold as many
// end points as a loop-closing search's local map, and then placed on every
// older scan by the same exhaustive search (scan_evidence.hpp) in a window
// of 3σ of the prediction at the uncertain step. A unique placement sets the
// pose; one whose rivals slide along a corridor sets the heading and the
// position across it.
void Slam::relocalize(const DataStep& data) {
  const std::size_t now = trajectory_.size();
  const bool has_older_scans = !scans_.empty() && scans_.front().record < now;
  if (step_motion_Q_.rows() == static_cast<Eigen::Index>(dofs_.size()) && has_older_scans) {
    const auto [step_xy, step_theta] = planar_sigmas(step_motion_Q_, dofs_);
    if (step_xy >= kRelocalizeStepSigma || step_theta >= kRelocalizeStepSigmaRotation) {
      // (A second jump while gathering starts the gathering again: the scans before it are old now.)
      ++stats_.relocalize_steps;
      const auto [sigma_xy, sigma_theta] = planar_sigmas(checked_marginal(robot_idx_), dofs_);
      relocalizing_ = Relocalizing{true, now, path_distance_, step_xy, step_theta, sigma_xy, sigma_theta};
      log_->debug("step ", step_, ": an uncertain step (its odometry's sigma ", step_xy, " m, ",
                  step_theta * 180.0 / std::numbers::pi, " deg): its scans will be placed on the older ones");
    }
  }
  if (!relocalizing_.active) return;
  const std::size_t from = relocalizing_.from_record;
  // The gathered scans' relative poses are the odometry's and the matches' since the uncertain step.
  double radius = 0.0;
  const Eigen::Vector2d here(x_r_[kX], x_r_[kY]);
  const std::vector<Eigen::Vector2d> points =
      scan_points([&](const KeptScan& s) { return s.record >= from; }, here, radius);
  if (points.size() < kScanMaxLocalPoints && path_distance_ - relocalizing_.from_path < config_.association.loop_local_path)
    return;
  relocalizing_.active = false;
  const PlanarIndices planar = planar_indices(dofs_);
  if (!planar.complete()) return;
  const int ix = planar.x, iy = planar.y, it = planar.theta;

  // The window: 3σ of the prediction at the uncertain step, or now if larger
  // (matches made since with a pose that uncertain may be wrong and still
  // have shrunk the covariance); at most the loop search's hard limits.
  const Eigen::MatrixXd P = checked_marginal(robot_idx_);
  const auto [sigma_xy_now, sigma_theta_now] = planar_sigmas(P, dofs_);
  const double sigma_xy = std::max(sigma_xy_now, relocalizing_.sigma_xy);
  const double sigma_theta = std::max(sigma_theta_now, relocalizing_.sigma_theta);
  std::ostringstream what;
  what.precision(3);
  what << "step " << step_ << ": after an uncertain step (its odometry's sigma " << relocalizing_.step_sigma_xy
       << " m, " << relocalizing_.step_sigma_theta * 180.0 / std::numbers::pi << " deg) the scans of " << now - from + 1
       << " steps (" << points.size() << " end points) ";
  if (points.size() < kRelocalizeMinPoints) {
    ++stats_.relocalize_refused;
    log_->debug(what.str(), "are too few to place");
    return;
  }
  ScanSearchOptions so;
  so.max_translation = std::min(kMaxWindowTranslation, 3.0 * sigma_xy);
  so.max_rotation = std::min(kScanMaxRotation, 3.0 * sigma_theta);
  so.rotation_step = kScanRotationStep;
  so.rival_ratio = kScanUniqueRatio;
  const double reach = radius + so.max_translation + 3.0 * kScanSigma;
  const std::unique_ptr<ScanField> field =
      old_scan_field(here, reach, [&](const KeptScan& s) { return s.record < from; });
  const ScanPlacement p = field->search(points, here, so);
  what << "placed on the older ones within " << so.max_translation << " m, "
       << so.max_rotation * 180.0 / std::numbers::pi << " deg: ";

  // The ground truth's verdict (when known) on a placement: the robot's pose
  // relative to the poses of the five older scans nearest to where it puts
  // the robot, against the true relative poses.
  const auto against_truth = [&](const PlanarMotion& T) -> std::optional<std::pair<double, double>> {
    if (!data.ground_truth || ground_truth_.empty()) return std::nullopt;
    const Eigen::Vector2d placed = T.apply(here);
    std::vector<std::pair<double, double>> by_distance;  // (distance, path)
    for (const KeptScan& s : scans_)
      if (s.record < from) by_distance.emplace_back((scan_pose(s).second - placed).norm(), s.path);
    const auto n = std::min<std::ptrdiff_t>(5, static_cast<std::ptrdiff_t>(by_distance.size()));
    std::partial_sort(by_distance.begin(), by_distance.begin() + n, by_distance.end());
    std::vector<double> paths;
    for (std::ptrdiff_t i = 0; i < n; ++i) paths.push_back(by_distance[static_cast<std::size_t>(i)].second);
    return disagreement_with_ground_truth(T, paths, data);
  };
  const auto verdict = [&](const PlanarMotion& T) {
    std::ostringstream v;
    v.precision(3);
    if (const auto off = against_truth(T))
      v << "; against the ground truth " << off->first << " m, " << off->second * 180.0 / std::numbers::pi << " deg off";
    return v.str();
  };
  if (!p.found || p.score < kRelocalizeMinScore) {
    ++stats_.relocalize_refused;
    log_->debug(what.str(), "best score ", p.score, ", under ", kRelocalizeMinScore, ": nothing there to place them on");
    return;
  }
  const bool along_a_line = p.rival_score > 0.0 && p.slide_extent > 0.0;
  if (p.rival_score > 0.0 && !along_a_line) {
    ++stats_.relocalize_refused;
    if (log_->enabled(LogLevel::Debug))
      log_->debug(what.str(), "best score ", p.score, " at ", p.best.t.norm(), " m, ",
                  p.best.theta * 180.0 / std::numbers::pi, " deg, a rival as good elsewhere (score ", p.rival_score,
                  "): not used", verdict(p.best));
    return;
  }

  // The pose where the scans fit, to the search's resolution (a cell, a
  // rotation step); along a corridor whose rivals slide, only the position
  // across it and the heading.
  const double sigma_t = kScanResolution, sigma_r = kScanRotationStep;
  const Eigen::Vector2d n(-p.slide.y(), p.slide.x());  // across the line (when along_a_line)
  PlanarMotion applied = p.best;
  if (along_a_line) applied.t = n * n.dot(p.best.t);
  if (along_a_line)
    ++stats_.relocalized_along_a_line;
  else
    ++stats_.relocalized;
  what << "score " << p.score << ", correction " << applied.t.norm() << " m, " << applied.theta * 180.0 / std::numbers::pi
       << " deg" << (along_a_line ? " (across a corridor and in heading: its rivals slide along it)" : "");
  if (const auto off = against_truth(applied)) {
    ++stats_.relocalize_checked;
    // Along a corridor only the heading and the position across it were set: the heading is checked.
    const bool wrong = off->second > 5.0 * std::numbers::pi / 180.0 || (!along_a_line && off->first > 1.0);
    if (wrong) ++stats_.relocalize_wrong;
    what << "; against the ground truth " << off->first << " m, " << off->second * 180.0 / std::numbers::pi << " deg off"
         << (wrong ? " (wrong)" : "");
  }
  log_->info(what.str());

  Eigen::Matrix2d C_xy = sigma_t * sigma_t * Eigen::Matrix2d::Identity();
  if (along_a_line) {  // along the line no more than the robot's 3σ there
    Eigen::Matrix2d P_xy;
    P_xy << P(ix, ix), P(ix, iy), P(iy, ix), P(iy, iy);
    C_xy += 9.0 * p.slide.dot(P_xy * p.slide) * p.slide * p.slide.transpose();
  }
  if (problem_) {
    // As a loop closure (close_loops): a pose relation to the old pose node
    // nearest to where the scans put the robot, and a first guess — the
    // poses and the features since the uncertain step moved with the robot.
    Eigen::Matrix3d C_placed = Eigen::Matrix3d::Zero();
    C_placed.topLeftCorner<2, 2>() = C_xy;
    C_placed(2, 2) = sigma_r * sigma_r;
    const Eigen::Vector2d placed = applied.apply(here);
    relate_to_nearest_node(Eigen::Vector3d(placed.x(), placed.y(), wrap_angle(x_r_[kTheta] + applied.theta)), C_placed,
                           from > 0 && from - 1 < record_path_.size() ? record_path_[from - 1] : 0.0);
    std::vector<std::pair<int, PlanarMotion>> moves;
    for (std::size_t i = 0; i < features_.size(); ++i)
      if (!features_[i].state_idx.empty() && features_[i].created_path >= relocalizing_.from_path)
        moves.emplace_back(static_cast<int>(i), applied);
    problem_->warp(
        [&](std::size_t record) -> std::optional<PlanarMotion> {
          if (record >= from) return applied;
          return std::nullopt;
        },
        applied, moves);
  } else {
    // A filter: one update of the robot's pose; what it mapped since the
    // uncertain step moves with it through the cross-covariances.
    LinearizedObservation ob;
    ob.idx = {robot_idx_[static_cast<std::size_t>(ix)], robot_idx_[static_cast<std::size_t>(iy)],
              robot_idx_[static_cast<std::size_t>(it)]};
    if (along_a_line) {
      ob.eta = Eigen::Vector2d(n.dot(p.best.t), p.best.theta);
      ob.J = Eigen::MatrixXd::Zero(2, 3);
      ob.J.row(0) << n.x(), n.y(), 0.0;
      ob.J(1, 2) = 1.0;
      ob.C_eta = Eigen::Vector2d(sigma_t * sigma_t, sigma_r * sigma_r).asDiagonal();
    } else {
      ob.eta = Eigen::Vector3d(p.best.t.x(), p.best.t.y(), p.best.theta);
      ob.J = Eigen::MatrixXd::Identity(3, 3);
      ob.C_eta = Eigen::Vector3d(sigma_t * sigma_t, sigma_t * sigma_t, sigma_r * sigma_r).asDiagonal();
    }
    apply_correction(estimator_update({ob}, "update (relocalization by the scans)"));
  }
  associator_.map_changed();
}

double Slam::typical_speed() const {
  // The median over the recorded steps that moved (a gap's step, its net displacement over minutes, is one of many).
  std::vector<double> speeds;
  for (std::size_t i = 1; i < record_path_.size() && i < trajectory_.size(); ++i) {
    const double dt = trajectory_[i].t - trajectory_[i - 1].t, moved = record_path_[i] - record_path_[i - 1];
    if (dt > 0.0 && moved > 1e-3) speeds.push_back(moved / dt);
  }
  if (speeds.empty()) return 0.0;
  const auto mid = speeds.begin() + static_cast<std::ptrdiff_t>(speeds.size() / 2);
  std::nth_element(speeds.begin(), mid, speeds.end());
  return *mid;
}

void Slam::close_loops(const DataStep& data) {
  const AssociationConfig& a = config_.association;
  if (path_distance_ - last_loop_attempt_path_ < 0.1 * a.loop_local_path) return;

  std::vector<int> local_idx, old_idx;
  for (std::size_t i = 0; i < features_.size(); ++i) {
    const MapFeature& mf = features_[i];
    if (mf.merged_into != 0 || mf.state_idx.empty() || mf.feature->mspace_dim() == 0) continue;
    if (mf.created_path >= path_distance_ - a.loop_local_path)
      local_idx.push_back(static_cast<int>(i));
    else if (mf.created_path <= path_distance_ - a.loop_min_gap_path)
      old_idx.push_back(static_cast<int>(i));
  }
  if (static_cast<int>(local_idx.size()) < a.loop_min_matches || old_idx.empty()) return;
  // Nothing new in the local map since the last search: same answer.
  const std::int64_t signature = local_map_signature(local_idx);
  if (signature == last_loop_local_signature_) return;
  last_loop_local_signature_ = signature;
  last_loop_attempt_path_ = path_distance_;

  // The window: 3σ plus the drift the odometry may have had since the robot
  // last matched anything older than the local map.
  const auto [sigma_xy, sigma_theta] = planar_sigmas(checked_marginal(robot_idx_), dofs_);
  const Eigen::Vector2d here = x_r_.head<2>();
  // Two anchors (note_anchor): any match with old features that fixed the robot, and a revisit that did. The
  // window grows with the path since the last anchor; with association.loop_revisit_window, since the last
  // revisit, and an old feature may then be moved onto only by the drift over the path since the last anchor
  // of either kind plus the drift since the robot last saw that feature (MapMatchOptions::drift_per_metre) —
  // so features tracked for 30 m do not hold the window shut while the robot comes back to a place it left
  // long ago, and a place that repeats cannot be laid onto its neighbour 14 m away either.
  const double drift_rad_per_metre = a.loop_drift_deg_per_metre * std::numbers::pi / 180.0;
  const double unanchored = path_distance_ - last_anchor_path_;
  const double widening = a.loop_revisit_window ? path_distance_ - last_revisit_path_ : unanchored;
  MapMatchOptions o = map_match_options();
  o.max_translation = std::min(kMaxWindowTranslation, 3.0 * sigma_xy + a.loop_drift_per_metre * widening);
  o.max_rotation = std::min(kMaxWindowRotation, 3.0 * sigma_theta + drift_rad_per_metre * widening);
  if (a.loop_revisit_window) {
    o.drift_per_metre = a.loop_drift_per_metre;
    o.drift_rad_per_metre = drift_rad_per_metre;
    o.pair_base_translation = 3.0 * sigma_xy + a.loop_drift_per_metre * unanchored;
    o.pair_base_rotation = 3.0 * sigma_theta + drift_rad_per_metre * unanchored;
  }
  std::vector<FeatureShape> local;
  for (int i : local_idx) local.push_back(estimated_shape(i));
  // With loop_revisit_window, the travel since each old feature was last seen: the path, or — across a logging gap
  // whose odometry holds only the net displacement — the robot's typical speed times the time, whichever is longer.
  const double speed = a.loop_revisit_window ? typical_speed() : 0.0;
  const auto travel_unseen = [&](const MapFeature& mf) {
    return std::max(path_distance_ - mf.last_seen_path, speed * (t_ - mf.last_seen_t));
  };

  // One search in one window: the old features it can reach, the scans'
  // placement there, and the features' placement.
  struct Search {
    MapMatchOptions o;
    std::vector<FeatureShape> old;
    std::unique_ptr<ScanField> field;
    std::vector<Eigen::Vector2d> scan_points;
    ScanPlacement scans;
    MapMatch match;
    bool wide = false;
  };
  const auto search = [&](Search& s, const std::vector<int>& nearby) {
    MapMatchOptions& so = s.o;
    so.keep_verified = !ground_truth_.empty() && log_->enabled(LogLevel::Debug);
    if (so.keep_verified) {
      std::vector<FeatureShape> old_shapes;
      for (int i : nearby) old_shapes.push_back(estimated_shape(i));
      const auto c = true_counterparts(local, old_shapes, data);
      if (c && !c->unmatched.empty())
        log_->debug("step ", step_, ": ground truth: local features without a counterpart:", c->unmatched);
      if (c && !c->needed.empty()) {
        const Eigen::Vector3d need = median_need(c->needed);
        so.probe = PlanarMotion{need[0], need.tail<2>(), here};
        // Would the search pair the true counterparts at that motion?
        std::ostringstream why;
        why.precision(3);
        int pairable = 0;
        for (const auto& [li, oi] : c->pairs) {
          const std::string refusal = pair_refusal(local[static_cast<std::size_t>(li)],
                                                   old_shapes[static_cast<std::size_t>(oi)], *so.probe, so);
          if (refusal.empty()) {
            ++pairable;
            continue;
          }
          why << " #" << features_[static_cast<std::size_t>(local[static_cast<std::size_t>(li)].feature)].id << "->#"
              << features_[static_cast<std::size_t>(old_shapes[static_cast<std::size_t>(oi)].feature)].id << ": "
              << refusal << ";";
        }
        log_->debug("step ", step_, ": ground truth: at the motion it needs, ", pairable, " of the ", c->pairs.size(),
                    " true counterpart pairs pass the pairing's tests", pairable < static_cast<int>(c->pairs.size()) ? "; refused:" : "",
                    why.str());
      }
    }
    for (int i : nearby) {
      FeatureShape shape = estimated_shape(i);
      if (a.loop_revisit_window) shape.travel_unseen = travel_unseen(features_[static_cast<std::size_t>(i)]);
      s.old.push_back(std::move(shape));
    }
    // The scans' own placement (association.loop_scans): a feature placement
    // they contradict is refused, and a placement they find unique is tried
    // as a hypothesis of its own (loop_closing.hpp, dense evidence) — in the
    // wider window only when it explains kScanWideMinScore of the end points.
    if (a.loop_scans) {
      s.scans = place_scans(here, so, s.field, s.scan_points);
      if (s.scans.found && s.scans.score >= kScanMinScore) {
        so.dense_score = [&s](const PlanarMotion& T) { return s.field->score(s.scan_points, T); };
        so.dense_floor = kScanAgreement * s.scans.score;
        if (s.scans.rival_score < kScanUniqueRatio * s.scans.score && (!s.wide || s.scans.score >= kScanWideMinScore))
          so.seeds.push_back(s.scans.best);
        // The scans' placement is good to a few σ of their field and a rotation step or two.
        so.seed_tolerance_translation = 3.0 * kScanSigma;
        so.seed_tolerance_rotation = 2.0 * kScanRotationStep;
      }
      if (log_->enabled(LogLevel::Debug)) log_scan_placement(s.scans, s.scan_points.size(), s.old, here, data);
    }
    s.match = match_local_map(local, s.old, here, so);
  };

  Search narrow;
  narrow.o = o;
  {
    const double reach = a.loop_local_path + o.max_translation;
    std::vector<int> nearby;
    for (int i : old_idx)
      if (planar_distance(*features_[static_cast<std::size_t>(i)].feature, here) <= reach) nearby.push_back(i);
    if (nearby.empty()) return;
    ++stats_.loop_attempts;
    search(narrow, nearby);
  }
  // The second search (association.loop_wide_drift_per_metre): when the
  // first placed nothing, a window as wide as a nearby old feature can have
  // drifted at the measured rate since the robot last saw it, each pair held
  // to that rate too. A robot anchored to one pass of the old map that comes
  // back to another pass, which drifted from it, needs that motion (README,
  // "Too few true counterparts": with it, still the largest class of the
  // refused searches that had enough true counterparts).
  Search wide;
  if (a.loop_wide_drift_per_metre > 0.0 && !narrow.match.accepted &&
      narrow.match.reason.rfind("ambiguous", 0) != 0) {
    // Headings drift in the same proportion to the stated bounds (loop_drift_deg_per_metre).
    const double rate = a.loop_wide_drift_per_metre;
    wide.o = o;
    wide.o.drift_per_metre = rate;
    wide.o.drift_rad_per_metre =
        a.loop_drift_per_metre > 0.0 ? rate * drift_rad_per_metre / a.loop_drift_per_metre : 0.0;
    std::vector<int> nearby;
    for (int i : old_idx) {
      const MapFeature& mf = features_[static_cast<std::size_t>(i)];
      const double travel = travel_unseen(mf);
      const double feature_reach = std::min(kMaxWindowTranslation, o.pair_base_translation + rate * travel);
      if (planar_distance(*mf.feature, here) > a.loop_local_path + std::max(feature_reach, o.max_translation)) continue;
      nearby.push_back(i);
      wide.o.max_translation = std::max(wide.o.max_translation, feature_reach);
      const double turn = std::min(kMaxWindowRotation, o.pair_base_rotation + wide.o.drift_rad_per_metre * travel);
      wide.o.max_rotation = std::max(wide.o.max_rotation, turn);
    }
    if (wide.o.max_translation > o.max_translation + o.cell) {
      ++stats_.loop_wide_searches;
      if (log_->enabled(LogLevel::Debug))
        log_->debug("step ", step_, ": map matching in the window ", o.max_translation, " m: ", narrow.match.reason,
                    ground_truth_verdict(narrow.match, local, narrow.old, data), "; searching again in ",
                    wide.o.max_translation, " m, ", wide.o.max_rotation * 180.0 / std::numbers::pi, " deg");
      wide.wide = true;
      search(wide, nearby);
      if (!wide.match.accepted && log_->enabled(LogLevel::Debug))
        log_->debug("step ", step_, ": map matching in the wider window (", nearby.size(), " old features): ",
                    wide.match.reason, ground_truth_verdict(wide.match, local, wide.old, data));
    }
  }
  // The wider search speaks only when it placed the local map: its refusals
  // (a rival farther out, too few pairs) say nothing against what the first
  // search found or keeps waiting.
  const Search& chosen = wide.wide && wide.match.accepted ? wide : narrow;
  o = chosen.o;
  const std::vector<FeatureShape>& old = chosen.old;
  const ScanPlacement& scans = chosen.scans;
  const MapMatch& match = chosen.match;
  // Whether placement h agrees with the waiting one p: the robot's position
  // and heading under both within 3σ of their difference (plus the local
  // map's own distortion, floor_sigma); `moved`, `turned`: how far apart.
  double moved = 0.0, turned = 0.0;
  const auto agrees = [&](const PendingClosure& p, const MapMatchHypothesis& h) {
    return placements_agree(p.motion, p.sigma_translation, p.sigma_rotation, h, here, o.floor_sigma, moved, turned);
  };
  if (!match.accepted) {
    // A placement waiting for confirmation is dropped when this search found
    // another one as good (ambiguous) or a different best placement; a
    // search that placed nothing, or whose best placement is the waiting one
    // with too little evidence this time, says nothing against it.
    bool keep = false;
    if (pending_closure_.active && match.reason.rfind("ambiguous", 0) != 0) {
      keep = match.best.pairs.empty() || agrees(pending_closure_, match.best);
      // A placement the scans made stands while the scans keep placing the
      // local map there, whatever the features' best guess.
      if (pending_closure_.seeded && scans.found) {
        MapMatchHypothesis by_scans;
        by_scans.motion = scans.best;
        keep = keep || agrees(pending_closure_, by_scans);
      }
    }
    if (!keep) pending_closure_ = PendingClosure{};
    if (match.reason.rfind("ambiguous", 0) == 0) {
      ++stats_.loop_ambiguous;
      log_->info("step ", step_, ": loop closure refused, ", match.reason, " (", local.size(), " local, ", old.size(),
                 " old features, window ", o.max_translation, " m / ", o.max_rotation * 180.0 / std::numbers::pi,
                 " deg)");
    } else if (log_->enabled(LogLevel::Debug)) {
      log_->debug("step ", step_, ": map matching, ", local.size(), " local and ", old.size(), " old features (window ",
                  o.max_translation, " m, ", o.max_rotation * 180.0 / std::numbers::pi, " deg): ", match.reason,
                  ground_truth_verdict(match, local, old, data));
    }
    return;
  }

  // Confirmation: one local map can fit a wrong place by chance (a corridor
  // with doors at a regular spacing, a wing like another); the next search,
  // once the robot has mapped more of the place, must find the same
  // placement with local features this one did not pair — independent
  // evidence (agrees(), above).
  {
    std::vector<int> paired_ids;
    for (const auto& [li, oi] : match.best.pairs)
      paired_ids.push_back(features_[static_cast<std::size_t>(local[static_cast<std::size_t>(li)].feature)].id);
    PendingClosure& p = pending_closure_;
    bool same = false, fresh = false;
    if (p.active) {
      same = agrees(p, match.best);
      fresh = std::any_of(paired_ids.begin(), paired_ids.end(), [&](int id) {
        return std::find(p.local_ids.begin(), p.local_ids.end(), id) == p.local_ids.end();
      });
      // Scans placed it again after half a local map of new scans.
      fresh = fresh || (p.seeded && match.best.seeded && path_distance_ - p.path >= 0.5 * a.loop_local_path);
      // Found again, over a local map that changed since (a search runs only
      // then), by loop_confirm_repeats searches in a row: a robot that only
      // crosses the old place pairs the same few features each time.
      if (same && !fresh) {
        ++p.repeats;
        if (a.loop_confirm_repeats > 0 && p.repeats >= a.loop_confirm_repeats) {
          fresh = true;
          ++stats_.loop_confirmed_by_repeats;
          log_->debug("step ", step_, ": the waiting placement found again by ", p.repeats,
                      " searches without new pairs: confirmed");
        }
      }
      if (!same) {
        ++stats_.loop_unconfirmed;
        log_->info("step ", step_, ": map matching's placement of ", match.best.pairs.size(),
                   " features differs from the previous search's by ", moved, " m, ",
                   turned * 180.0 / std::numbers::pi, " deg: that one is dropped, this one waits for the next search");
      }
    }
    if (!(same && fresh)) {
      // Remember this placement (a placement confirmed but with nothing new
      // keeps the first one's features) and wait for the next search.
      if (!same)
        pending_closure_ = PendingClosure{true, match.best.motion, match.best.sigma_translation,
                                          match.best.sigma_rotation, paired_ids, match.best.seeded, path_distance_};
      if (log_->enabled(LogLevel::Debug))
        log_->debug("step ", step_, ": map matching placed ", match.best.pairs.size(), " of ", local.size(),
                    " local features (", match.best.motion.t.norm(), " m, ",
                    match.best.motion.theta * 180.0 / std::numbers::pi, " deg): waiting for the next search", ground_truth_verdict(match, local, old, data));
      return;
    }
    pending_closure_ = PendingClosure{};
  }

  const PlanarMotion& T = match.best.motion;
  double loop_start = 0.0;  // where the old map was last seen: the drift grew from there
  for (const auto& [li, oi] : match.best.pairs)
    loop_start = std::max(loop_start, features_[static_cast<std::size_t>(old[static_cast<std::size_t>(oi)].feature)]
                                          .last_seen_path);
  const double span = std::max(path_distance_ - loop_start, 1e-9);
  const auto share = [&](double path) { return std::clamp((path - loop_start) / span, 0.0, 1.0); };
  {
    std::ostringstream what;
    what.precision(3);
    what << "step " << step_ << ": loop closed by map matching: " << match.best.pairs.size() << " of "
         << local.size() << " features of the last " << a.loop_local_path << " m are older ones last seen "
         << span << " m of travel ago; correction " << T.t.norm() << " m, " << T.theta * 180.0 / std::numbers::pi
         << " deg (about the robot; best other placement pairs " << match.rival_matches << ")";
    if (match.best.seeded) what << "; placed by the scans (score " << match.best.dense_score << ")";
    if (chosen.wide) what << "; in the wider window (" << o.max_translation << " m)";
    log_->info(what.str());
  }
  if (log_->enabled(LogLevel::Debug)) {
    std::ostringstream pairs;
    pairs.precision(3);
    for (std::size_t p = 0; p < match.best.pairs.size(); ++p) {
      const auto [li, oi] = match.best.pairs[p];
      const MapFeature& fa = features_[static_cast<std::size_t>(local[static_cast<std::size_t>(li)].feature)];
      const MapFeature& fb = features_[static_cast<std::size_t>(old[static_cast<std::size_t>(oi)].feature)];
      pairs << " " << fa.id << "(dim " << fa.feature->mspace_dim() << ": " << fa.feature->coords().transpose()
            << ") -> " << fb.id << "(dim " << fb.feature->mspace_dim() << ": " << fb.feature->coords().transpose()
            << ") D² " << match.best.pair_d2[p] << ", " << match.best.pair_rivals[p] << " rivals in the gate;";
    }
    log_->debug("step ", step_, ": loop closure pairs (local -> old):", pairs.str());
  }
  ++stats_.loop_closures;
  if (match.best.seeded) ++stats_.loop_scan_placed;
  if (chosen.wide) ++stats_.loop_wide_closures;
  stats_.loop_merged += static_cast<std::int64_t>(match.best.pairs.size());
  {
    std::vector<double> seen;
    for (const auto& [li, oi] : match.best.pairs)
      seen.push_back(features_[static_cast<std::size_t>(old[static_cast<std::size_t>(oi)].feature)].created_path);
    check_against_ground_truth(T, seen, data);
    if (const auto by_pairs = pairs_against_ground_truth(match.best, local, old, data)) {
      const auto [wrong, checked] = *by_pairs;
      // One wrong pair is enough: a corridor's walls, whose ends slide, are
      // "the same object" at any shift along them, so the pairs that fix
      // the shift may be the only ones that can be wrong.
      if (wrong > 0) {
        ++stats_.loop_wrong_pairs;
        log_->warn("step ", step_, ": ", wrong, " of the closure's ", checked,
                   " pairs are not the same object by the ground truth: a wrong association");
      } else if (log_->enabled(LogLevel::Debug)) {
        log_->debug("step ", step_, ": ", checked - wrong, " of the closure's ", checked,
                    " pairs are the same object by the ground truth");
      }
    }
  }

  if (problem_) {
    // Placed by the scans with a direction the pairs leave free (a corridor):
    // the current pose node relative to the old one nearest to where the
    // scans put the robot, with the placement's σ — else the odometry would
    // pull the free direction back where the drift had it.
    if (match.best.seeded && !match.best.determined) relate_to_old_pose(T, match.best);
    // A first guess: the trajectory and the features since the loop's start
    // moved by their share of the correction.
    std::vector<std::pair<int, PlanarMotion>> moves;
    for (std::size_t i = 0; i < features_.size(); ++i) {
      const MapFeature& mf = features_[i];
      if (mf.state_idx.empty() || mf.created_path <= loop_start) continue;
      moves.emplace_back(static_cast<int>(i), T.scaled(share(mf.created_path)));
    }
    problem_->warp(
        [&](std::size_t record) -> std::optional<PlanarMotion> {
          const double path = record < record_path_.size() ? record_path_[record] : path_distance_;
          if (path <= loop_start) return std::nullopt;
          return T.scaled(share(path));
        },
        T, moves);
    for (const auto& [li, oi] : match.best.pairs)
      problem_->coincide(features_[static_cast<std::size_t>(local[static_cast<std::size_t>(li)].feature)].id,
                         features_[static_cast<std::size_t>(old[static_cast<std::size_t>(oi)].feature)].id,
                         kCoincidenceSigma);
  } else {
    // A filter: one update with every coincidence, linearised here.
    std::vector<LinearizedObservation> obs;
    for (const auto& [li, oi] : match.best.pairs) {
      const MapFeature& fa = features_[static_cast<std::size_t>(local[static_cast<std::size_t>(li)].feature)];
      const MapFeature& fb = features_[static_cast<std::size_t>(old[static_cast<std::size_t>(oi)].feature)];
      LinearizedObservation ob;
      if (!linearize_coincidence(fa, fb, ob.eta, ob.J, ob.idx)) continue;
      ob.C_eta = kCoincidenceSigma * kCoincidenceSigma * Eigen::MatrixXd::Identity(ob.eta.size(), ob.eta.size());
      obs.push_back(std::move(ob));
    }
    if (!obs.empty()) {
      apply_correction(estimator_update(obs, "update (loop closure)"));
    }
  }
  for (const auto& [li, oi] : match.best.pairs) {
    MapFeature& dup = features_[static_cast<std::size_t>(local[static_cast<std::size_t>(li)].feature)];
    MapFeature& kept = features_[static_cast<std::size_t>(old[static_cast<std::size_t>(oi)].feature)];
    dup.merged_into = kept.id;
    kept.feature->absorb(*dup.feature);  // what the local copy saw beyond the old one (SDK 6)
    kept.last_seen_path = path_distance_;
  }
  associator_.map_changed();
}

}  // namespace mspace::kernel
