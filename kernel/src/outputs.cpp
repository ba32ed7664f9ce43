#include "outputs.hpp"

#include <charconv>
#include <chrono>
#include <cmath>
#include <fstream>
#include <iomanip>
#include <numbers>
#include <optional>
#include <sstream>
#include <stdexcept>

#include <yaml-cpp/yaml.h>

#include "slam.hpp"

namespace mspace::kernel {
namespace {

/// The summary's comment on a σ factor of the health report (sensor_health.hpp).
std::string sigma_scale_comment(int beyond, const char* how) {
  std::string text = "extractor sigma x this makes the NIS its expectation (";
  text += how;
  text += ")";
  if (beyond != 0) text += beyond < 0 ? "; below the range searched" : "; above the range searched";
  return text;
}

constexpr double kRadToDeg = 180.0 / std::numbers::pi;

std::ofstream open_for_writing(const std::filesystem::path& file) {
  if (file.has_parent_path()) std::filesystem::create_directories(file.parent_path());
  std::ofstream out(file);
  if (!out) throw std::runtime_error("cannot write '" + file.string() + "'");
  out.precision(9);
  return out;
}

/// The ATE figures of `e` as keys of the open map (12 significant digits, so
/// that a third-party check on the pose files can be exact).
void emit_trajectory_errors(YAML::Emitter& y, const TrajectoryErrors& e) {
  y << YAML::Key << "poses_compared" << YAML::Value << e.matched;
  y << YAML::Key << "ate_rmse_m" << YAML::Value << YAML::DoublePrecision(12) << e.ate_rmse;
  y << YAML::Key << "ate_median_m" << YAML::Value << YAML::DoublePrecision(12) << e.ate_median;
  y << YAML::Key << "ate_max_m" << YAML::Value << YAML::DoublePrecision(12) << e.ate_max;
  y << YAML::Key << "final_translation_error_m" << YAML::Value << e.final_translation;
  if (e.final_heading) y << YAML::Key << "final_heading_error_deg" << YAML::Value << *e.final_heading * kRadToDeg;
}

/// The relation statistics of `r` as keys of the open map.
void emit_relation_errors(YAML::Emitter& y, const RelationErrors& r) {
  y << YAML::Key << "given" << YAML::Value << r.total;
  y << YAML::Key << "matched" << YAML::Value << r.matched;
  auto mean_std = [&](const char* key, const MeanStd& m) {
    y << YAML::Key << key << YAML::Value << YAML::Flow << YAML::BeginMap << YAML::Key << "mean" << YAML::Value
      << m.mean << YAML::Key << "std" << YAML::Value << m.std << YAML::EndMap;
  };
  mean_std("translation_m", r.translation);
  mean_std("translation_squared_m2", r.translation_sq);
  mean_std("rotation_deg", r.rotation_deg);
  mean_std("rotation_squared_deg2", r.rotation_sq_deg);
}

/// "ATE RMSE 0.059 m (median 0.029, max 0.226), final error 0.024 m / 0.20 deg"
void print_trajectory_errors(std::ostream& os, const TrajectoryErrors& e) {
  os << "ATE RMSE " << e.ate_rmse << " m (median " << e.ate_median << ", max " << e.ate_max << "), final error "
     << e.final_translation << " m";
  if (e.final_heading) os << " / " << std::setprecision(2) << *e.final_heading * kRadToDeg << " deg";
  os << std::setprecision(3);
}

/// "translation 0.020 ± 0.024 m, rotation 0.45 ± 0.61 deg"
void print_relation_errors(std::ostream& os, const RelationErrors& r) {
  os << "translation " << r.translation.mean << " ± " << r.translation.std << " m, rotation " << std::setprecision(2)
     << r.rotation_deg.mean << " ± " << r.rotation_deg.std << " deg" << std::setprecision(3);
}

void emit_vector(YAML::Emitter& y, const Eigen::VectorXd& v) {
  y << YAML::Flow << YAML::BeginSeq;
  for (Eigen::Index i = 0; i < v.size(); ++i) y << v[i];
  y << YAML::EndSeq;
}

void emit_matrix(YAML::Emitter& y, const Eigen::MatrixXd& m) {
  y << YAML::BeginSeq;
  for (Eigen::Index r = 0; r < m.rows(); ++r) emit_vector(y, m.row(r).transpose());
  y << YAML::EndSeq;
}

/// Appends `value` with `decimals` digits after the point, exactly as
/// printf("%.*f") and an iostream in std::fixed write it (both round
/// correctly), at a fraction of their cost: the trajectory is formatted at
/// every step of a run.
void append_fixed(std::string& out, double value, int decimals) {
  char buf[512];  // the longest double in fixed notation: 309 digits, sign, point, decimals
  const auto [end, ec] = std::to_chars(buf, buf + sizeof buf, value, std::chars_format::fixed, decimals);
  if (ec != std::errc()) throw std::runtime_error("cannot format a pose coordinate");
  out.append(buf, end);
}

/// One line `t x y z qx qy qz qw`: the time with 6 decimals (µs), the rest with 9.
void append_pose_line(std::string& out, const StampedPose& p) {
  const Eigen::Vector4d q = quaternion_xyzw(p.pose);
  append_fixed(out, p.t, 6);
  for (const double v : {p.pose[kX], p.pose[kY], p.pose[kZ], q[0], q[1], q[2], q[3]}) {
    out += ' ';
    append_fixed(out, v, 9);
  }
  out += '\n';
}

/// Each line of `text` as a '#' comment line.
void write_header_lines(std::ostream& out, const std::string& text) {
  std::istringstream lines(text);
  for (std::string line; std::getline(lines, line);) out << "# " << line << '\n';
}

}  // namespace

void write_atomically(const std::filesystem::path& file,
                      const std::function<void(const std::filesystem::path& temporary)>& write) {
  if (file.has_parent_path()) std::filesystem::create_directories(file.parent_path());
  const std::filesystem::path temporary =
      file.parent_path() / (file.stem().string() + ".writing" + file.extension().string());
  write(temporary);
  std::error_code ec;
  std::filesystem::rename(temporary, file, ec);
  if (ec) throw std::runtime_error("cannot move '" + temporary.string() + "' to '" + file.string() + "': " + ec.message());
}

// Lines are formatted into `pending` and handed to the file when it holds
// kWriteBytes or when the flush is due: one write per batch instead of an
// iostream insertion per number (the stream appends at every step).
struct TrajectoryStream::Impl {
  static constexpr std::size_t kWriteBytes = 64 * 1024;
  std::filesystem::path file;
  std::ofstream out;
  std::string pending;
  double flush_seconds = 2.0;
  std::chrono::steady_clock::time_point last_flush = std::chrono::steady_clock::now();

  void write_pending() {
    out.write(pending.data(), static_cast<std::streamsize>(pending.size()));
    pending.clear();
  }
};

TrajectoryStream::TrajectoryStream(const std::filesystem::path& dir, double flush_seconds, const std::string& frame)
    : impl_(std::make_unique<Impl>()) {
  impl_->file = dir / "trajectory.partial.tum";
  impl_->flush_seconds = flush_seconds;
  impl_->out = open_for_writing(impl_->file);
  impl_->out << "# t x y z qx qy qz qw — robot poses as estimated at each step, streamed while the run goes; "
                "a complete run replaces this file by trajectory.tum\n";
  write_header_lines(impl_->out, frame);
  impl_->out.flush();
}

TrajectoryStream::~TrajectoryStream() {
  if (impl_->out.is_open()) impl_->write_pending();  // what an ofstream's own buffer would have written
}

void TrajectoryStream::append(const std::vector<StampedPose>& poses) {
  for (; written_ < poses.size(); ++written_) append_pose_line(impl_->pending, poses[written_]);
  const auto now = std::chrono::steady_clock::now();
  if (std::chrono::duration<double>(now - impl_->last_flush).count() >= impl_->flush_seconds) {
    impl_->write_pending();
    impl_->out.flush();
    impl_->last_flush = now;
  } else if (impl_->pending.size() >= Impl::kWriteBytes) {
    impl_->write_pending();
  }
}

void TrajectoryStream::discard() {
  impl_->pending.clear();
  impl_->out.close();
  std::error_code ignored;
  std::filesystem::remove(impl_->file, ignored);
}

RunSummary summarize(const Slam& slam, double wall_seconds) {
  RunSummary s;
  s.run_name = slam.config().name;
  s.config_file = slam.config().file.string();
  s.steps = slam.stats().steps;
  s.wall_seconds = wall_seconds;
  s.source_load_seconds = slam.source_load_seconds();
  const auto& traj = slam.trajectory();
  if (!traj.empty()) s.data_seconds = traj.back().t - traj.front().t;
  // Robot, every feature's own dimensions and every shared coordinate once.
  s.state_dimension = static_cast<int>(slam.robot_dofs().size());
  for (const SharedCoordinate& c : slam.shared_coordinates()) s.state_dimension += static_cast<int>(c.state_idx.size());
  for (const FeatureTypeSlot& type : slam.feature_types()) s.features_by_dim[type.instance];
  for (const MapFeature& f : slam.features()) {
    ++s.features_by_dim[slam.feature_types()[f.type].instance][f.feature->mspace_dim()];
    s.state_dimension += static_cast<int>(f.own_idx.size());
  }
  s.skipped_records = slam.skipped_records();
  s.covariance_health = slam.covariance_health();
  try {
    s.final_covariance = slam.covariance_figures_now();
  } catch (const std::exception& e) {  // a broken estimator: the summary must still be written
    s.final_covariance_problem = e.what();
  }
  // Reference poses are paired with the estimate interpolated at their time,
  // as long as the estimate has poses less than a second apart.
  constexpr double kMaxGap = 1.0;
  const bool baseline = slam.odometry_steps() > 0;
  if (baseline && (!slam.ground_truth().empty() || !slam.config().evaluation.relations.empty()))
    s.dead_reckoning.emplace().odometry = slam.odometry_description();
  if (!slam.config().evaluation.relations.empty()) {
    const std::vector<Relation> relations = read_relations(slam.config().evaluation.relations);
    const double max_dt = slam.config().evaluation.relations_max_dt;
    s.relations = evaluate_relations(traj, relations, max_dt);
    if (s.dead_reckoning) s.dead_reckoning->relations = evaluate_relations(slam.dead_reckoning(), relations, max_dt);
  }
  if (!slam.ground_truth().empty()) {
    s.errors = evaluate_trajectory(slam.evaluated_trajectory(), slam.ground_truth(), kMaxGap);
    if (s.dead_reckoning)
      s.dead_reckoning->errors = evaluate_trajectory(slam.dead_reckoning_evaluated(), slam.ground_truth(), kMaxGap);
    const auto& nees = slam.stats().nees;
    double sum = 0.0;
    for (double v : nees) sum += v;
    s.mean_nees = nees.empty() ? 0.0 : sum / static_cast<double>(nees.size());
    s.nees_dof = slam.stats().nees_dof;
  }
  return s;
}

void write_tum(const std::filesystem::path& file, const std::vector<StampedPose>& poses, const std::string& header) {
  std::ofstream out = open_for_writing(file);
  out << "# t x y z qx qy qz qw\n";
  write_header_lines(out, header);
  std::string lines;
  lines.reserve(poses.size() * 100);
  for (const StampedPose& p : poses) append_pose_line(lines, p);
  out.write(lines.data(), static_cast<std::streamsize>(lines.size()));
  if (!out.flush()) throw std::runtime_error("cannot write '" + file.string() + "'");
}

void write_map_yaml(const std::filesystem::path& file, const Slam& slam) {
  // The covariances come from the estimator plugin; when it cannot give them
  // (a run stopped by a broken estimator), the map is written without them
  // and says why, rather than lost.
  std::string unreadable;
  const auto covariance = [&](const std::vector<int>& rows) -> std::optional<Eigen::MatrixXd> {
    if (!unreadable.empty()) return std::nullopt;
    try {
      return slam.state_covariance(rows);
    } catch (const std::exception& e) {
      unreadable = e.what();
      return std::nullopt;
    }
  };
  YAML::Emitter y;
  y.SetDoublePrecision(9);
  y << YAML::BeginMap;
  y << YAML::Key << "run" << YAML::Value << slam.config().name;
  y << YAML::Key << "robot_pose" << YAML::Value;
  emit_vector(y, slam.pose());
  y << YAML::Comment("x y z theta phi psi (m, rad)");
  y << YAML::Key << "features" << YAML::Value << YAML::BeginSeq;
  for (const MapFeature& f : slam.features()) {
    const FeatureTypeSlot& type = slam.feature_types()[f.type];
    y << YAML::BeginMap;
    y << YAML::Key << "id" << YAML::Value << f.id;
    y << YAML::Key << "type" << YAML::Value << type.instance;
    y << YAML::Key << "plugin" << YAML::Value << type.plugin;
    y << YAML::Key << "layout" << YAML::Value << f.feature->layout().describe();
    y << YAML::Key << "coords" << YAML::Value;
    emit_vector(y, f.feature->coords());
    y << YAML::Key << "mspace_dim" << YAML::Value << f.feature->mspace_dim();
    y << YAML::Key << "observations" << YAML::Value << f.times_matched + 1;
    if (!f.state_idx.empty())
      if (const auto C = covariance(f.state_idx)) {
        y << YAML::Key << "covariance" << YAML::Value;
        emit_matrix(y, *C);
      }
    if (!f.shared.empty()) {
      y << YAML::Key << "shared_blocks" << YAML::Value << YAML::Flow << YAML::BeginMap;
      for (const auto& [block, id] : f.shared) y << YAML::Key << block << YAML::Value << id;
      y << YAML::EndMap;
    }
    y << YAML::EndMap;
  }
  y << YAML::EndSeq;
  if (!slam.shared_coordinates().empty()) {
    y << YAML::Key << "shared_coordinates" << YAML::Value << YAML::BeginSeq;
    for (const SharedCoordinate& c : slam.shared_coordinates()) {
      y << YAML::BeginMap;
      y << YAML::Key << "id" << YAML::Value << c.id;
      y << YAML::Key << "kind" << YAML::Value << block_kind_name(c.kind);
      y << YAML::Key << "value" << YAML::Value;
      emit_vector(y, slam.shared_value(c));
      y << YAML::Key << "members" << YAML::Value << YAML::Flow << YAML::BeginSeq;
      for (const auto& [feature, block] : c.members)
        y << YAML::Flow << YAML::BeginMap << YAML::Key << "feature" << YAML::Value << feature << YAML::Key << "block"
          << YAML::Value << block << YAML::EndMap;
      y << YAML::EndSeq;
      if (const auto C = covariance(c.state_idx)) {
        y << YAML::Key << "covariance" << YAML::Value;
        emit_matrix(y, *C);
      }
      y << YAML::EndMap;
    }
    y << YAML::EndSeq;
  }
  if (!unreadable.empty()) y << YAML::Key << "covariances_unavailable" << YAML::Value << unreadable;
  y << YAML::EndMap;
  std::ofstream out = open_for_writing(file);
  out << "# mspace map: every feature with its coordinates x_f (map frame), its M-space\n"
         "# dimension and the covariance of its M-space perturbations.\n"
      << y.c_str() << '\n';
}

/// summary.yaml's covariance_health (kernel/src/covariance_health.hpp).
void emit_covariance_health(YAML::Emitter& y, const RunSummary& s) {
  const CovarianceHealthReport& h = s.covariance_health;
  y << YAML::Key << "covariance_health" << YAML::Value << YAML::BeginMap;
  y << YAML::Key << "touched_blocks_checked" << YAML::Value << h.block_checks;
  y << YAML::Key << "touched_blocks_not_positive_definite" << YAML::Value << h.blocks_not_pd;
  if (h.blocks_not_pd > 0) y << YAML::Key << "first_not_positive_definite_step" << YAML::Value << h.first_not_pd_step;
  y << YAML::Key << "full_checks" << YAML::Value << h.full_checks;
  if (h.full_checks > 0) {
    y << YAML::Key << "min_eigenvalue" << YAML::Value << h.min_eigenvalue;
    y << YAML::Key << "min_eigenvalue_relative" << YAML::Value << h.min_relative_eigenvalue;
    y << YAML::Comment("smallest / largest eigenvalue of that check");
    y << YAML::Key << "min_eigenvalue_step" << YAML::Value << h.min_eigenvalue_step;
  }
  y << YAML::Key << "max_asymmetry" << YAML::Value << h.max_asymmetry;
  y << YAML::Comment("max |C - C^T| / max |C| over every matrix checked");
  if (s.final_covariance) {
    y << YAML::Key << "final" << YAML::Value << YAML::BeginMap;
    y << YAML::Key << "min_eigenvalue" << YAML::Value << s.final_covariance->min_eigenvalue;
    y << YAML::Key << "max_eigenvalue" << YAML::Value << s.final_covariance->max_eigenvalue;
    y << YAML::Key << "asymmetry" << YAML::Value << s.final_covariance->asymmetry;
    y << YAML::EndMap;
  } else {
    y << YAML::Key << "final" << YAML::Value << ("not checked: " + s.final_covariance_problem);
  }
  y << YAML::EndMap;
}

void write_summary_yaml(const std::filesystem::path& file, const RunSummary& s, const Slam& slam) {
  const RunStats& st = slam.stats();
  YAML::Emitter y;
  y.SetDoublePrecision(6);
  y << YAML::BeginMap;
  y << YAML::Key << "run" << YAML::Value << s.run_name;
  y << YAML::Key << "config" << YAML::Value << s.config_file;
  y << YAML::Key << "steps" << YAML::Value << s.steps;
  if (!s.interrupted.empty()) y << YAML::Key << "interrupted" << YAML::Value << s.interrupted;
  if (!s.stopped_by_error.empty()) y << YAML::Key << "stopped_by_error" << YAML::Value << s.stopped_by_error;
  y << YAML::Key << "data_seconds" << YAML::Value << s.data_seconds;
  y << YAML::Key << "wall_seconds" << YAML::Value << s.wall_seconds;
  y << YAML::Key << "state_dimension" << YAML::Value << s.state_dimension;
  // The map mode (docs/maps.md): what was loaded, added and changed.
  y << YAML::Key << "map" << YAML::Value << YAML::BeginMap;
  y << YAML::Key << "mode" << YAML::Value << map_mode_name(slam.map_mode());
  if (const auto m = slam.map_session_report()) {
    y << YAML::Key << "loaded_from" << YAML::Value << m->file;
    y << YAML::Key << "features_loaded" << YAML::Value << m->loaded;
    if (m->tentative_dropped > 0)
      y << YAML::Key << "tentative_features_not_used" << YAML::Value << m->tentative_dropped;
    y << YAML::Key << "features_added" << YAML::Value << m->added;
    y << YAML::Key << "features_changed" << YAML::Value << m->changed;
    if (!m->covariance_model.empty()) {
      y << YAML::Key << "covariance_model" << YAML::Value << m->covariance_model;
      y << YAML::Key << "working_set_evictions" << YAML::Value << m->working_set_evictions;
    }
    if (m->switched_to_mapping_at_step > 0) {
      y << YAML::Key << "switched_to_mapping_at_step" << YAML::Value << m->switched_to_mapping_at_step;
      y << YAML::Key << "switched_at_path_m" << YAML::Value << m->switched_at_path;
    }
    if (m->searched) {  // initial_pose: search (docs/maps.md §3)
      y << YAML::Key << "pose_search" << YAML::Value << YAML::BeginMap;
      y << YAML::Key << "searches" << YAML::Value << m->searches;
      y << YAML::Key << "localized" << YAML::Value << m->localized.has_value();
      if (const auto& l = m->localized) {
        y << YAML::Key << "at_step" << YAML::Value << l->step;
        y << YAML::Key << "at_time_s" << YAML::Value << YAML::DoublePrecision(16) << l->t;  // logs stamp in epoch seconds
        y << YAML::Key << "at_path_m" << YAML::Value << l->path;
        y << YAML::Key << "pose" << YAML::Value << YAML::Flow << YAML::BeginSeq << l->x << l->y
          << l->theta * 180.0 / std::numbers::pi << YAML::EndSeq;
        y << YAML::Key << "local_features_paired" << YAML::Value << l->paired;
        y << YAML::Key << "local_features" << YAML::Value << l->local;
        y << YAML::Key << "best_other_placement_pairs" << YAML::Value << l->rival;
        y << YAML::Key << "placement_sigma_m" << YAML::Value << l->sigma_translation;
        y << YAML::Key << "placement_sigma_deg" << YAML::Value << l->sigma_rotation * 180.0 / std::numbers::pi;
        y << YAML::Key << "own_features_discarded" << YAML::Value << l->features_discarded;
      } else {
        y << YAML::Key << "last_search" << YAML::Value << m->last_search;
        y << YAML::Key << "frame" << YAML::Value << "the run's first pose (not the map's)";
      }
      y << YAML::EndMap;
    }
  }
  y << YAML::EndMap;
  y << YAML::Key << "counts" << YAML::Value << YAML::BeginMap;
  y << YAML::Key << "readings" << YAML::Value << st.readings;
  y << YAML::Key << "measurements" << YAML::Value << st.measurements;
  y << YAML::Key << "matched" << YAML::Value << st.matched;
  y << YAML::Key << "used_in_updates" << YAML::Value << st.updates;
  y << YAML::Key << "features_created" << YAML::Value << st.created;
  y << YAML::Key << "extensions" << YAML::Value << st.extended;
  y << YAML::Key << "shared_coordinates" << YAML::Value << st.joined;
  y << YAML::Key << "tentative_pruned" << YAML::Value << st.pruned;
  y << YAML::Key << "readings_without_sensor" << YAML::Value << st.unknown_channel_readings;
  y << YAML::Key << "skipped_input_records" << YAML::Value << s.skipped_records;
  y << YAML::EndMap;
  const AssociationStats& as = slam.association_stats();
  y << YAML::Key << "association" << YAML::Value << YAML::BeginMap;
  y << YAML::Key << "method" << YAML::Value << association_method_name(slam.config().association.method);
  y << YAML::Key << "index_queries" << YAML::Value << as.index_queries;
  y << YAML::Key << "jcbb_readings" << YAML::Value << as.jcbb_readings;
  y << YAML::Key << "jcbb_nodes" << YAML::Value << as.jcbb_nodes;
  y << YAML::Key << "jcbb_bounded" << YAML::Value << as.jcbb_bounded;
  if (slam.config().association.refuse_ambiguous) {
    y << YAML::Key << "ambiguous_readings" << YAML::Value << as.ambiguous_readings;
    y << YAML::Key << "disputed_pairings" << YAML::Value << as.disputed_pairings;
  }
  if (slam.config().association.reentry_joint_test) {
    y << YAML::Key << "reentry_test" << YAML::Value << YAML::BeginMap;
    y << YAML::Key << "readings" << YAML::Value << as.reentry_readings;
    y << YAML::Key << "confirmed" << YAML::Value << as.reentry_confirmed;
    y << YAML::Key << "refused" << YAML::Value << as.reentry_refused;
    y << YAML::EndMap;
  }
  if (slam.config().association.loop_closing) {
    y << YAML::Key << "loop_closing" << YAML::Value << YAML::BeginMap;
    y << YAML::Key << "searches" << YAML::Value << st.loop_attempts;
    y << YAML::Key << "closures" << YAML::Value << st.loop_closures;
    y << YAML::Key << "refused_ambiguous" << YAML::Value << st.loop_ambiguous;
    y << YAML::Key << "refused_unconfirmed" << YAML::Value << st.loop_unconfirmed;
    if (slam.config().association.loop_confirm_repeats > 0)
      y << YAML::Key << "confirmed_by_repeats" << YAML::Value << st.loop_confirmed_by_repeats;
    if (slam.config().association.loop_wide_drift_per_metre > 0.0) {
      y << YAML::Key << "wide_window_searches" << YAML::Value << st.loop_wide_searches;
      y << YAML::Key << "wide_window_closures" << YAML::Value << st.loop_wide_closures;
    }
    y << YAML::Key << "features_merged" << YAML::Value << st.loop_merged;
    if (slam.config().association.loop_scans)
      y << YAML::Key << "placed_by_scans" << YAML::Value << st.loop_scan_placed;
    if (st.loop_checked > 0) {
      y << YAML::Key << "checked_against_ground_truth" << YAML::Value << st.loop_checked;
      y << YAML::Key << "false_closures" << YAML::Value << st.loop_false;
      y << YAML::Key << "worst_disagreement_m" << YAML::Value << st.loop_worst_disagreement;
      y << YAML::Key << "wrong_associations" << YAML::Value << st.loop_wrong_pairs;
    }
    y << YAML::EndMap;
  }
  if (st.matches_checked > 0) {
    y << YAML::Key << "matches_against_ground_truth" << YAML::Value << YAML::BeginMap;
    y << YAML::Key << "checked" << YAML::Value << st.matches_checked;
    y << YAML::Key << "wrong" << YAML::Value << st.matches_wrong;
    y << YAML::Key << "to_features_long_unseen" << YAML::Value << st.matches_long_unseen;
    y << YAML::Key << "wrong_to_features_long_unseen" << YAML::Value << st.matches_wrong_long_unseen;
    y << YAML::EndMap;
  }
  if (slam.config().association.relocalize_by_scans) {
    y << YAML::Key << "relocalization" << YAML::Value << YAML::BeginMap;
    y << YAML::Key << "uncertain_steps" << YAML::Value << st.relocalize_steps;
    y << YAML::Key << "placed" << YAML::Value << st.relocalized;
    y << YAML::Key << "placed_across_a_corridor" << YAML::Value << st.relocalized_along_a_line;
    y << YAML::Key << "not_placed" << YAML::Value << st.relocalize_refused;
    if (st.relocalize_checked > 0) {
      y << YAML::Key << "checked_against_ground_truth" << YAML::Value << st.relocalize_checked;
      y << YAML::Key << "wrong" << YAML::Value << st.relocalize_wrong;
    }
    y << YAML::EndMap;
  }
  y << YAML::EndMap;
  y << YAML::Key << "features" << YAML::Value << YAML::BeginMap;
  for (const auto& [type, by_dim] : s.features_by_dim) {
    y << YAML::Key << type << YAML::Value << YAML::BeginMap;
    for (const auto& [dim, count] : by_dim) y << YAML::Key << ("dim" + std::to_string(dim)) << YAML::Value << count;
    y << YAML::EndMap;
  }
  y << YAML::EndMap;
  y << YAML::Key << "timings_seconds" << YAML::Value << YAML::BeginMap;
  // Before the first step, so not part of wall_seconds; `source` is reading the steps.
  y << YAML::Key << "source_load" << YAML::Value << s.source_load_seconds;
  y << YAML::Key << "source" << YAML::Value << st.seconds_source;
  y << YAML::Key << "predict" << YAML::Value << st.seconds_predict;
  y << YAML::Key << "extract" << YAML::Value << st.seconds_extract;
  y << YAML::Key << "associate" << YAML::Value << st.seconds_associate;
  y << YAML::Key << "update" << YAML::Value << st.seconds_update;
  y << YAML::Key << "dense_information" << YAML::Value << st.seconds_dense;
  y << YAML::Key << "extend" << YAML::Value << st.seconds_extend;
  y << YAML::Key << "loop_closing" << YAML::Value << st.seconds_loops;
  y << YAML::EndMap;
  emit_covariance_health(y, s);
  // The health report of every sensor (kernel/src/sensor_health.hpp).
  y << YAML::Key << "sensors" << YAML::Value << YAML::BeginMap;
  for (const SensorHealthReport& h : slam.sensor_health()) {
    y << YAML::Key << h.sensor << YAML::Value << YAML::BeginMap;
    y << YAML::Key << "readings" << YAML::Value << h.readings;
    y << YAML::Key << "measurements" << YAML::Value << h.measurements;
    y << YAML::Key << "measurements_per_reading" << YAML::Value
      << (h.readings > 0 ? static_cast<double>(h.measurements) / static_cast<double>(h.readings) : 0.0);
    y << YAML::Key << "matched" << YAML::Value << h.matched;
    y << YAML::Key << "matched_fraction" << YAML::Value
      << (h.measurements > 0 ? static_cast<double>(h.matched) / static_cast<double>(h.measurements) : 0.0);
    y << YAML::Key << "used_in_updates" << YAML::Value << h.updates;
    if (h.updates > 0) {
      y << YAML::Key << "nis_ratio" << YAML::Value << h.nis_ratio;
      y << YAML::Comment("observed / expected NIS under the gate: ~1 consistent, >1 noise too small");
      y << YAML::Key << "mean_nis_per_row" << YAML::Value << h.mean_nis_per_row;
      y << YAML::Key << "expected_nis_per_row" << YAML::Value << h.expected_nis_per_row;
    }
    if (!h.kinds.empty()) {
      // Noise from data (sensor_health.hpp): per measurement kind, the factor
      // on the extractor's σ that would make the NIS its expectation.
      y << YAML::Key << "by_kind" << YAML::Value << YAML::BeginMap;
      for (const KindNisReport& k : h.kinds) {
        y << YAML::Key << k.kind << YAML::Value << YAML::BeginMap;
        y << YAML::Key << "updates" << YAML::Value << k.updates;
        y << YAML::Key << "rows" << YAML::Value << k.rows;
        y << YAML::Key << "mean_nis" << YAML::Value << k.mean_nis;
        y << YAML::Key << "expected_nis" << YAML::Value << k.expected_nis;
        y << YAML::Key << "nis_ratio" << YAML::Value << k.nis_ratio;
        y << YAML::Key << "sigma_scale" << YAML::Value << k.sigma_scale;
        y << YAML::Comment(sigma_scale_comment(k.sigma_scale_beyond, "trusts the filter's robot covariance"));
        if (k.true_pose_updates > 0) {
          y << YAML::Key << "true_pose_updates" << YAML::Value << k.true_pose_updates;
          y << YAML::Key << "nis_ratio_true_pose" << YAML::Value << k.nis_ratio_true_pose;
          y << YAML::Key << "sigma_scale_true_pose" << YAML::Value << k.sigma_scale_true_pose;
          y << YAML::Comment(sigma_scale_comment(k.sigma_scale_true_pose_beyond, "the robot's error taken out"));
        }
        y << YAML::EndMap;
      }
      y << YAML::EndMap;
    }
    y << YAML::Key << "extract_seconds" << YAML::Value << h.extract_seconds;
    y << YAML::Key << "warnings" << YAML::Value << YAML::BeginSeq;
    for (const std::string& w : h.warnings) y << w;
    y << YAML::EndSeq;
    if (!h.notes.empty()) {
      y << YAML::Key << "notes" << YAML::Value << YAML::BeginSeq;
      for (const std::string& n : h.notes) y << n;
      y << YAML::EndSeq;
    }
    y << YAML::EndMap;
  }
  y << YAML::EndMap;
  if (s.errors) {
    const TrajectoryErrors& e = *s.errors;
    y << YAML::Key << "ground_truth" << YAML::Value << YAML::BeginMap;
    // The files the figures are computed from (an evo-style APE of the two,
    // SE(2) alignment, poses paired by time stamp, gives ate_rmse_m), and the
    // ATE figures with 12 significant digits so that such a check can be exact.
    const std::string& sensor = slam.config().evaluation.ground_truth_sensor;
    y << YAML::Key << "estimate_file" << YAML::Value
      << (sensor.empty() ? std::string("trajectory.tum") : "trajectory_" + sensor + ".tum");
    y << YAML::Key << "reference_file" << YAML::Value << "ground_truth.tum";
    if (!slam.config().evaluation.reference.empty())
      y << YAML::Key << "reference" << YAML::Value << slam.config().evaluation.reference;
    y << YAML::Key << "alignment" << YAML::Value << "SE(2), least squares over the compared positions";
    emit_trajectory_errors(y, e);
    y << YAML::Key << "mean_robot_nees" << YAML::Value << s.mean_nees;
    y << YAML::Key << "nees_dof" << YAML::Value << s.nees_dof;
    y << YAML::EndMap;
  }
  if (s.relations) {
    const RelationErrors& r = *s.relations;
    y << YAML::Key << "relations" << YAML::Value << YAML::BeginMap;
    y << YAML::Key << "file" << YAML::Value << slam.config().evaluation.relations;
    emit_relation_errors(y, r);
    y << YAML::EndMap;
  }
  if (s.dead_reckoning) {
    // The baseline: the same figures for the odometry alone.
    const RunSummary::DeadReckoning& d = *s.dead_reckoning;
    y << YAML::Key << "dead_reckoning" << YAML::Value << YAML::BeginMap;
    y << YAML::Key << "odometry" << YAML::Value << d.odometry;
    y << YAML::Key << "how" << YAML::Value
      << "the source's odometry increments through the motion model from the run's start, no update";
    if (d.errors) {
      y << YAML::Key << "ground_truth" << YAML::Value << YAML::BeginMap;
      emit_trajectory_errors(y, *d.errors);
      y << YAML::EndMap;
    }
    if (d.relations) {
      y << YAML::Key << "relations" << YAML::Value << YAML::BeginMap;
      emit_relation_errors(y, *d.relations);
      y << YAML::EndMap;
    }
    y << YAML::EndMap;
  }
  y << YAML::EndMap;
  std::ofstream out = open_for_writing(file);
  out << y.c_str() << '\n';
}

std::string format_summary(const RunSummary& s, const Slam& slam) {
  const RunStats& st = slam.stats();
  std::ostringstream os;
  os << std::fixed << std::setprecision(3);
  os << "run '" << s.run_name << "': " << s.steps << " steps, " << s.data_seconds << " s of data in "
     << s.wall_seconds << " s elapsed";
  if (s.wall_seconds > 0) os << " (" << std::setprecision(1) << s.data_seconds / s.wall_seconds << "x real time)";
  os << std::setprecision(3) << "\n";
  if (!s.interrupted.empty()) os << "  " << s.interrupted << "\n";
  if (const auto m = slam.map_session_report())
    os << "  map mode " << map_mode_name(slam.map_mode()) << " in " << m->file << ": " << m->loaded
       << " features loaded, " << m->added << " added, " << m->changed << " changed"
       << (m->covariance_model.empty() ? "" : "; map covariance: " + m->covariance_model)
       << (m->switched_to_mapping_at_step > 0
               ? "; switched from localize to mapping at step " + std::to_string(m->switched_to_mapping_at_step)
               : "")
       << "\n";
  if (const auto m = slam.map_session_report(); m && m->searched) {
    if (const auto& l = m->localized)
      os << "  pose search: localized at step " << l->step << " (" << l->t << " s, " << l->path
         << " m of travel, search " << m->searches << ") at " << l->x << ", " << l->y << " m, "
         << l->theta * 180.0 / std::numbers::pi << " deg; " << l->paired << " of " << l->local
         << " local features paired, best other placement " << l->rival << "\n";
    else
      os << "  pose search: NOT LOCALIZED after " << m->searches << " searches ("
         << (m->last_search.empty() ? "too few features to search with" : m->last_search)
         << "); the poses are in the frame of the run's first pose, not the map's\n";
  }
  os << "  measurements " << st.measurements << ", matched " << st.matched << ", used in updates " << st.updates
     << ", features created " << st.created << ", extended " << st.extended << ", tentative pruned " << st.pruned;
  if (st.joined > 0) os << ", shared coordinates " << st.joined;
  os << "\n";
  const AssociationStats& as = slam.association_stats();
  if (as.jcbb_readings > 0)
    os << "  joint compatibility: " << as.jcbb_readings << " readings, " << as.jcbb_nodes << " tree nodes, "
       << as.jcbb_bounded << " gave up at jcbb_max_nodes (nearest neighbour used)"
       << (slam.config().association.refuse_ambiguous
               ? ", " + std::to_string(as.disputed_pairings) + " pairings in " + std::to_string(as.ambiguous_readings) +
                     " readings not used: a rival hypothesis fitted as well"
               : std::string())
       << "\n";
  if (slam.config().association.reentry_joint_test)
    os << "  re-entry test: " << as.reentry_confirmed << " pairings with long-unseen features confirmed, "
       << as.reentry_refused << " refused (" << as.reentry_readings << " readings)\n";
  if (slam.config().association.loop_closing)
    os << "  loop closing by map matching: " << st.loop_closures << " closures (" << st.loop_merged
       << " features merged) in " << st.loop_attempts << " searches, " << st.loop_ambiguous
       << " refused as ambiguous, " << st.loop_unconfirmed << " not confirmed by the next search"
       << (slam.config().association.loop_confirm_repeats > 0
               ? ", " + std::to_string(st.loop_confirmed_by_repeats) + " confirmed by repeated searches"
               : std::string())
       << (slam.config().association.loop_wide_drift_per_metre > 0.0
               ? ", " + std::to_string(st.loop_wide_closures) + " placed by " + std::to_string(st.loop_wide_searches) +
                     " searches in the wider window"
               : std::string())
       << (slam.config().association.loop_scans ? ", " + std::to_string(st.loop_scan_placed) + " placed by the scans" : "");
  if (st.loop_checked > 0)
    os << "; against the ground truth " << st.loop_false << " of " << st.loop_checked
       << " false (worst disagreement " << st.loop_worst_disagreement << " m), " << st.loop_wrong_pairs
       << " pairing wrong objects";
  if (slam.config().association.loop_closing) os << "\n";
  if (slam.config().association.relocalize_by_scans) {
    os << "  relocalization by the scans: " << st.relocalize_steps << " uncertain steps, " << st.relocalized
       << " placed, " << st.relocalized_along_a_line << " placed across a corridor, " << st.relocalize_refused
       << " not placed";
    if (st.relocalize_checked > 0)
      os << "; against the ground truth " << st.relocalize_wrong << " of " << st.relocalize_checked << " wrong";
    os << "\n";
  }
  if (st.matches_checked > 0) {
    std::ostringstream gap;  // (the stream above writes fixed-point)
    gap << slam.config().association.loop_min_gap_path;
    os << "  associations against the ground truth: " << st.matches_wrong << " of " << st.matches_checked
       << " matches paired another object (" << st.matches_wrong_long_unseen << " of the " << st.matches_long_unseen
       << " with features unseen for over " << gap.str() << " m of travel)\n";
  }
  os << "  state dimension " << s.state_dimension << "\n";
  for (const auto& [type, by_dim] : s.features_by_dim) {
    os << "  features '" << type << "':";
    if (by_dim.empty()) os << " none";
    for (const auto& [dim, count] : by_dim) os << "  " << count << " at dim " << dim;
    os << "\n";
  }
  const double total = st.seconds_source + st.seconds_predict + st.seconds_extract + st.seconds_associate +
                       st.seconds_update + st.seconds_dense + st.seconds_extend + st.seconds_loops;
  os << "  time: source load " << s.source_load_seconds << " s (before the first step); steps: source "
     << st.seconds_source << " s, predict " << st.seconds_predict << " s, extract "
     << st.seconds_extract << " s, associate "
     << st.seconds_associate << " s, update " << st.seconds_update << " s, dense " << st.seconds_dense
     << " s, extend " << st.seconds_extend << " s";
  if (st.seconds_loops > 0.0) {  // map matching: loop closing, or an initial_pose: search
    const auto m = slam.map_session_report();
    os << (m && m->searched ? ", pose search " : ", loop closing ") << st.seconds_loops << " s";
  }
  os << " (total of the steps " << total << " s)\n";
  // What the source's ground truth is: the truth, or a named reference.
  const std::string& reference = slam.config().evaluation.reference;
  const std::string versus = reference.empty() ? std::string("ground truth") : "the reference (" + reference + ")";
  if (s.errors) {
    const TrajectoryErrors& e = *s.errors;
    os << "  vs " << versus << " (" << e.matched << " poses): ";
    print_trajectory_errors(os, e);
    os << ", mean robot NEES " << s.mean_nees << " (" << s.nees_dof << " dof)\n";
  }
  if (s.relations) {
    const RelationErrors& r = *s.relations;
    os << "  relations (" << r.matched << " of " << r.total << " matched): ";
    print_relation_errors(os, r);
    os << "\n";
  }
  if (s.dead_reckoning) {
    const RunSummary::DeadReckoning& d = *s.dead_reckoning;
    os << "  dead reckoning (odometry only; " << d.odometry << "):\n";
    if (d.errors) {
      os << "    vs " << versus << " (" << d.errors->matched << " poses): ";
      print_trajectory_errors(os, *d.errors);
      os << "\n";
    }
    if (d.relations) {
      os << "    relations (" << d.relations->matched << " of " << d.relations->total << " matched): ";
      print_relation_errors(os, *d.relations);
      os << "\n";
    }
  }
  for (const SensorHealthReport& h : slam.sensor_health()) {
    os << "  sensor " << h.sensor << ": " << h.measurements << " measurements in " << h.readings << " readings, "
       << h.matched << " matched";
    if (h.updates > 0) os << std::setprecision(2) << ", NIS " << h.nis_ratio << "x expected" << std::setprecision(3);
    os << "\n";
    for (const KindNisReport& k : h.kinds) {
      os << std::setprecision(2) << "    " << k.kind << ": " << k.updates << " updates, NIS " << k.nis_ratio
         << "x expected, consistent with sigma x " << (k.sigma_scale_beyond < 0 ? "<" : k.sigma_scale_beyond > 0 ? ">" : "")
         << k.sigma_scale;
      if (k.true_pose_updates > 0)
        os << " (with the true robot pose: NIS " << k.nis_ratio_true_pose << "x, sigma x "
           << (k.sigma_scale_true_pose_beyond < 0 ? "<" : k.sigma_scale_true_pose_beyond > 0 ? ">" : "")
           << k.sigma_scale_true_pose << ")";
      os << std::setprecision(3) << "\n";
    }
    for (const std::string& w : h.warnings) os << "  WARNING: " << w << "\n";
    for (const std::string& n : h.notes) os << "  note: " << n << "\n";
  }
  if (s.skipped_records > 0) os << "  skipped malformed input records: " << s.skipped_records << "\n";
  const CovarianceHealthReport& h = s.covariance_health;
  if (s.final_covariance)
    os << std::setprecision(3) << "  covariance: smallest eigenvalue " << s.final_covariance->min_eigenvalue
       << " at the end";
  else
    os << "  covariance: not checked at the end (" << s.final_covariance_problem << ")";
  if (h.full_checks > 0) os << ", " << h.min_eigenvalue << " at worst (step " << h.min_eigenvalue_step << ")";
  os << "; " << h.blocks_not_pd << " of " << h.block_checks << " updates left a block not positive definite\n";
  if (!s.stopped_by_error.empty()) os << "  STOPPED BY AN ERROR: " << s.stopped_by_error << "\n";
  return os.str();
}

}  // namespace mspace::kernel
