// eval_command.cpp — see eval_command.hpp.
#include "eval_command.hpp"

#include <algorithm>
#include <cmath>
#include <fstream>
#include <iomanip>
#include <ostream>
#include <sstream>
#include <stdexcept>
#include <string_view>

#include <Eigen/Geometry>

#include "mspace/records.hpp"

namespace mspace::kernel {
namespace {

/// The pose of one line of a trajectory file: `t x y theta` or TUM's
/// `t x y z qx qy qz qw`; "" when it parses, else what is wrong.
std::string parse_pose_line(const std::vector<std::string_view>& fields, StampedPose& out) {
  double v[8] = {};
  for (std::size_t i = 0; i < fields.size(); ++i)
    if (!records::parse_finite(fields[i], v[i]))
      return "field " + std::to_string(i + 1) + " ('" + std::string(fields[i]) + "') is not a finite number";
  out.t = v[0];
  if (fields.size() == 4) {
    out.pose = make_pose2d(v[1], v[2], wrap_angle(v[3]));
    return "";
  }
  const Eigen::Quaterniond q(v[7], v[4], v[5], v[6]);  // Eigen's order: w, x, y, z
  // Files written with 6–9 decimals have |q| within ~1e-6 of 1; anything far
  // from it is not a rotation (e.g. columns in another order).
  if (std::abs(q.norm() - 1.0) > 1e-3)
    return "the quaternion (qx qy qz qw) = (" + std::string(fields[4]) + " " + std::string(fields[5]) + " " +
           std::string(fields[6]) + " " + std::string(fields[7]) + ") is not of unit length (|q| = " +
           std::to_string(q.norm()) + ")";
  const Vec3 euler = euler_from_rotation(q.normalized().toRotationMatrix());
  out.pose = make_pose(v[1], v[2], v[3], euler[0], euler[1], euler[2]);
  return "";
}

/// Relations whose length |t2 − t1| is at least (long_ones) or below `seconds`.
std::vector<Relation> relations_by_length(const std::vector<Relation>& all, double seconds, bool long_ones) {
  std::vector<Relation> out;
  for (const Relation& r : all)
    if ((std::abs(r.t2 - r.t1) >= seconds) == long_ones) out.push_back(r);
  return out;
}

std::string span_text(const std::vector<StampedPose>& poses) {
  std::ostringstream s;
  s << std::fixed << std::setprecision(3) << poses.front().t << " … " << poses.back().t << " s";
  return s.str();
}

void print_relations(std::ostream& out, const char* label, const RelationErrors& r) {
  out << "  " << label << " (" << r.matched << " of " << r.total << " matched): ";
  if (r.matched == 0) {
    out << "none\n";
    return;
  }
  out << std::setprecision(4) << "translation " << r.translation.mean << " ± " << r.translation.std
      << " m, rotation " << std::setprecision(3) << r.rotation_deg.mean << " ± " << r.rotation_deg.std << " deg\n";
}

void yaml_relations(std::ostream& out, const char* prefix, const std::optional<RelationErrors>& r) {
  if (!r) return;
  out << prefix << "_total: " << r->total << "\n" << prefix << "_matched: " << r->matched << "\n";
  if (r->matched == 0) return;
  out << prefix << "_translation_mean_m: " << r->translation.mean << "\n"
      << prefix << "_translation_std_m: " << r->translation.std << "\n"
      << prefix << "_rotation_mean_deg: " << r->rotation_deg.mean << "\n"
      << prefix << "_rotation_std_deg: " << r->rotation_deg.std << "\n";
}

}  // namespace

std::vector<StampedPose> read_trajectory_file(const std::filesystem::path& file) {
  std::ifstream in(file);
  if (!in) throw std::runtime_error(file.string() + ": cannot open the trajectory file");
  std::vector<StampedPose> poses;
  std::size_t width = 0;
  std::string line;
  for (int line_no = 1; std::getline(in, line); ++line_no) {
    const std::vector<std::string_view> fields = records::split(line);
    if (fields.empty() || fields[0].front() == '#') continue;
    if (width == 0) {
      if (fields.size() != 8 && fields.size() != 4)
        throw std::runtime_error(records::at(file.string(), line_no) + "expected a TUM pose `t x y z qx qy qz qw` "
                                 "(8 fields) or a planar pose `t x y theta` (4 fields), found " +
                                 std::to_string(fields.size()) + " field(s)");
      width = fields.size();
    } else if (fields.size() != width) {
      throw std::runtime_error(records::at(file.string(), line_no) + "expected " + std::to_string(width) +
                               " fields like the first pose line, found " + std::to_string(fields.size()));
    }
    StampedPose p;
    const std::string problem = parse_pose_line(fields, p);
    if (!problem.empty()) throw std::runtime_error(records::at(file.string(), line_no) + problem);
    poses.push_back(p);
  }
  if (poses.empty()) throw std::runtime_error(file.string() + ": no pose in the trajectory file");
  std::stable_sort(poses.begin(), poses.end(), [](const StampedPose& a, const StampedPose& b) { return a.t < b.t; });
  return poses;
}

EvalResult evaluate_files(const EvalOptions& o) {
  if (o.reference.empty() && o.relations.empty())
    throw std::runtime_error("nothing to evaluate " + o.estimate.string() +
                             " against: give a reference trajectory, a relations file or both");
  const std::vector<StampedPose> estimate = read_trajectory_file(o.estimate);
  EvalResult r;
  r.estimate_poses = estimate.size();
  r.estimate_t0 = estimate.front().t;
  r.estimate_t1 = estimate.back().t;
  if (!o.reference.empty()) {
    const std::vector<StampedPose> reference = read_trajectory_file(o.reference);
    r.ate = evaluate_trajectory(estimate, reference, o.max_gap);
    if (r.ate->matched == 0)
      throw std::runtime_error("no pose of the reference " + o.reference.string() + " (" + span_text(reference) +
                               ") falls inside the estimate " + o.estimate.string() + " (" + span_text(estimate) +
                               ") between two poses at most " + std::to_string(o.max_gap) +
                               " s apart: are both in the same time base?");
  }
  if (!o.relations.empty()) {
    const std::vector<Relation> all = read_relations(o.relations);
    r.relations_all = evaluate_relations(estimate, all, o.relations_max_dt);
    if (r.relations_all->matched == 0)
      throw std::runtime_error("none of the " + std::to_string(all.size()) + " relations of " + o.relations.string() +
                               " has both time stamps within " + std::to_string(o.relations_max_dt) +
                               " s of a pose of " + o.estimate.string() + " (" + span_text(estimate) +
                               "): are both in the same time base, and is the estimate's time precise enough?");
    r.relations_short = evaluate_relations(estimate, relations_by_length(all, o.long_seconds, false), o.relations_max_dt);
    r.relations_long = evaluate_relations(estimate, relations_by_length(all, o.long_seconds, true), o.relations_max_dt);
  }
  return r;
}

void print_eval(std::ostream& out, const EvalResult& r, const EvalOptions& o) {
  const auto precision = out.precision();
  out << o.estimate.string() << ": " << r.estimate_poses << " poses, " << std::fixed << std::setprecision(3)
      << r.estimate_t1 - r.estimate_t0 << " s" << std::defaultfloat << "\n";
  if (r.ate) {
    const TrajectoryErrors& e = *r.ate;
    out << std::setprecision(4) << "  ATE vs " << o.reference.string() << " (" << e.matched
        << " reference poses paired, SE(2) alignment): RMSE " << e.ate_rmse << " m, median " << e.ate_median
        << " m, max " << e.ate_max << " m\n";
  }
  if (r.relations_all) {
    out << "  relations of " << o.relations.string() << " (stamps within " << o.relations_max_dt << " s):\n";
    print_relations(out, "all", *r.relations_all);
    const std::string short_label = "short (< " + std::to_string(static_cast<int>(o.long_seconds)) + " s)";
    const std::string long_label = "long (≥ " + std::to_string(static_cast<int>(o.long_seconds)) + " s)";
    print_relations(out, short_label.c_str(), *r.relations_short);
    print_relations(out, long_label.c_str(), *r.relations_long);
  }
  out.precision(precision);
}

void write_eval_yaml(const std::filesystem::path& file, const EvalResult& r, const EvalOptions& o) {
  std::ofstream out(file);
  if (!out) throw std::runtime_error(file.string() + ": cannot write the evaluation file");
  out << std::setprecision(12);
  out << "estimate: \"" << o.estimate.string() << "\"\n"
      << "estimate_poses: " << r.estimate_poses << "\n"
      << "estimate_seconds: " << r.estimate_t1 - r.estimate_t0 << "\n";
  if (r.ate)
    out << "reference: \"" << o.reference.string() << "\"\n"
        << "ate_matched: " << r.ate->matched << "\n"
        << "ate_rmse_m: " << r.ate->ate_rmse << "\n"
        << "ate_median_m: " << r.ate->ate_median << "\n"
        << "ate_max_m: " << r.ate->ate_max << "\n";
  if (r.relations_all) {
    out << "relations: \"" << o.relations.string() << "\"\n"
        << "long_seconds: " << o.long_seconds << "\n";
    yaml_relations(out, "relations_all", r.relations_all);
    yaml_relations(out, "relations_short", r.relations_short);
    yaml_relations(out, "relations_long", r.relations_long);
  }
  if (!out.flush()) throw std::runtime_error(file.string() + ": cannot write the evaluation file");
}

}  // namespace mspace::kernel
