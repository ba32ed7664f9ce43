#include "evaluation.hpp"

#include <algorithm>
#include <cmath>

namespace mspace::kernel {

Eigen::Vector2d Se2Alignment::apply(const Eigen::Vector2d& p) const {
  const double c = std::cos(theta), s = std::sin(theta);
  return {c * p.x() - s * p.y() + t.x(), s * p.x() + c * p.y() + t.y()};
}

Se2Alignment align_se2(const std::vector<Eigen::Vector2d>& est, const std::vector<Eigen::Vector2d>& ref) {
  Se2Alignment a;
  const std::size_t n = std::min(est.size(), ref.size());
  if (n == 0) return a;
  Eigen::Vector2d me = Eigen::Vector2d::Zero(), mr = Eigen::Vector2d::Zero();
  for (std::size_t i = 0; i < n; ++i) {
    me += est[i];
    mr += ref[i];
  }
  me /= static_cast<double>(n);
  mr /= static_cast<double>(n);
  // The rotation maximising Σ (r_i − m_r)·R(e_i − m_e) has angle atan2(Σ e×r, Σ e·r).
  double dot = 0.0, cross = 0.0;
  for (std::size_t i = 0; i < n; ++i) {
    const Eigen::Vector2d e = est[i] - me, r = ref[i] - mr;
    dot += e.dot(r);
    cross += e.x() * r.y() - e.y() * r.x();
  }
  a.theta = (dot == 0.0 && cross == 0.0) ? 0.0 : std::atan2(cross, dot);
  a.t = Eigen::Vector2d::Zero();
  a.t = mr - a.apply(me);
  return a;
}

std::optional<Pose6> interpolate(const std::vector<StampedPose>& trajectory, double t, double max_gap) {
  if (trajectory.empty() || t < trajectory.front().t || t > trajectory.back().t) return std::nullopt;
  const auto after = std::lower_bound(trajectory.begin(), trajectory.end(), t,
                                      [](const StampedPose& p, double time) { return p.t < time; });
  if (after->t == t) return after->pose;
  const StampedPose& b = *after;
  const StampedPose& a = *(after - 1);
  if (b.t - a.t > max_gap) return std::nullopt;
  const double s = (t - a.t) / (b.t - a.t);
  const Pose6 delta = pose_difference(b.pose, a.pose);  // angles wrapped
  Pose6 p = a.pose + s * delta;
  for (int i = kTheta; i <= kPsi; ++i) p[i] = wrap_angle(p[i]);
  return p;
}

TrajectoryErrors evaluate_trajectory(const std::vector<StampedPose>& estimate,
                                     const std::vector<StampedPose>& reference, double max_gap) {
  TrajectoryErrors out;
  std::vector<Eigen::Vector2d> est, ref;
  std::optional<Pose6> last_est;
  const StampedPose* last_ref = nullptr;
  for (const StampedPose& r : reference) {
    const std::optional<Pose6> e = interpolate(estimate, r.t, max_gap);
    if (!e) continue;
    est.emplace_back((*e)[kX], (*e)[kY]);
    ref.emplace_back(r.pose[kX], r.pose[kY]);
    last_est = e;
    last_ref = &r;
  }
  out.matched = est.size();
  if (out.matched == 0) return out;
  const Se2Alignment a = align_se2(est, ref);
  std::vector<double> err(est.size());
  double sq = 0.0;
  for (std::size_t i = 0; i < est.size(); ++i) {
    err[i] = (a.apply(est[i]) - ref[i]).norm();
    sq += err[i] * err[i];
  }
  out.ate_rmse = std::sqrt(sq / static_cast<double>(err.size()));
  out.ate_max = *std::max_element(err.begin(), err.end());
  std::nth_element(err.begin(), err.begin() + static_cast<std::ptrdiff_t>(err.size() / 2), err.end());
  out.ate_median = err[err.size() / 2];
  const Pose6 d = pose_difference(*last_est, last_ref->pose);
  out.final_translation = d.head<2>().norm();
  if (last_ref->known & (1u << kTheta)) out.final_heading = std::abs(d[kTheta]);
  return out;
}

}  // namespace mspace::kernel
