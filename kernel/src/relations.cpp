// relations.cpp — see relations.hpp.
#include "relations.hpp"

#include <algorithm>
#include <cmath>
#include <fstream>
#include <numbers>
#include <optional>
#include <stdexcept>
#include <string_view>

#include "mspace/records.hpp"

namespace mspace::kernel {
namespace {

/// Index of the pose closest in time to t within max_dt, in a trajectory
/// sorted by time.
std::optional<std::size_t> closest_pose(const std::vector<StampedPose>& sorted, double t, double max_dt) {
  const auto later = std::lower_bound(sorted.begin(), sorted.end(), t,
                                      [](const StampedPose& p, double value) { return p.t < value; });
  std::optional<std::size_t> best;
  double best_dt = max_dt;
  auto consider = [&](std::vector<StampedPose>::const_iterator it) {
    const double dt = std::abs(it->t - t);
    if (dt <= best_dt) {
      best_dt = dt;
      best = static_cast<std::size_t>(it - sorted.begin());
    }
  };
  if (later != sorted.end()) consider(later);
  if (later != sorted.begin()) consider(std::prev(later));
  return best;
}

/// Angle (rad) of the rotation of a pose, from the trace of its matrix.
double rotation_angle(const Pose6& pose) {
  const double c = (rotation(pose).trace() - 1.0) / 2.0;
  return std::acos(std::clamp(c, -1.0, 1.0));
}

MeanStd mean_std(const std::vector<double>& values) {
  MeanStd out;
  if (values.empty()) return out;
  const double n = static_cast<double>(values.size());
  for (double v : values) out.mean += v;
  out.mean /= n;
  double var = 0.0;
  for (double v : values) var += (v - out.mean) * (v - out.mean);
  out.std = std::sqrt(var / n);
  return out;
}

}  // namespace

std::vector<Relation> read_relations(const std::filesystem::path& file) {
  std::ifstream in(file);
  if (!in) throw std::runtime_error(file.string() + ": cannot open the relations file");
  std::vector<Relation> relations;
  std::string line;
  for (int line_no = 1; std::getline(in, line); ++line_no) {
    const std::vector<std::string_view> fields = records::split(line);
    if (fields.empty() || fields[0].front() == '#') continue;
    // t1 t2 x y z roll pitch yaw; evaluation input, so always strict (mspace/records.hpp).
    double v[8];
    bool ok = fields.size() == 8;
    for (std::size_t i = 0; ok && i < 8; ++i) ok = records::parse_finite(fields[i], v[i]);
    if (!ok)
      throw std::runtime_error(records::at(file.string(), line_no) + "expected 8 finite numbers `t1 t2 x y z roll pitch "
                               "yaw`, found " + std::to_string(fields.size()) + " field(s)");
    // Pose6 holds (x, y, z, yaw θ, pitch φ, roll ψ).
    relations.push_back({v[0], v[1], make_pose(v[2], v[3], v[4], v[7], v[6], v[5])});
  }
  return relations;
}

RelationErrors evaluate_relations(const std::vector<StampedPose>& trajectory,
                                  const std::vector<Relation>& relations, double max_dt) {
  std::vector<StampedPose> sorted = trajectory;
  std::stable_sort(sorted.begin(), sorted.end(),
                   [](const StampedPose& a, const StampedPose& b) { return a.t < b.t; });
  RelationErrors out;
  out.total = relations.size();
  std::vector<double> trans, trans_sq, rot, rot_sq;
  for (const Relation& r : relations) {
    const auto i1 = closest_pose(sorted, r.t1, max_dt);
    const auto i2 = closest_pose(sorted, r.t2, max_dt);
    if (!i1 || !i2) continue;
    const Pose6 estimated = relative(sorted[*i1].pose, sorted[*i2].pose);  // pose(t1)⁻¹ ⊕ pose(t2)
    const Pose6 error = relative(r.delta, estimated);                      // δ⁻¹ ⊕ estimate
    const double t = error.head<3>().norm();
    const double a = rotation_angle(error) * 180.0 / std::numbers::pi;
    trans.push_back(t);
    trans_sq.push_back(t * t);
    rot.push_back(a);
    rot_sq.push_back(a * a);
  }
  out.matched = trans.size();
  out.translation = mean_std(trans);
  out.translation_sq = mean_std(trans_sq);
  out.rotation_deg = mean_std(rot);
  out.rotation_sq_deg = mean_std(rot_sq);
  return out;
}

}  // namespace mspace::kernel
