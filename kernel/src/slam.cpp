#include "slam.hpp"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <numbers>
#include <numeric>
#include <sstream>
#include <unordered_map>

#include <Eigen/Cholesky>
#include <Eigen/LU>

#include "chi2.hpp"
#include "considered_map.hpp"
#include "logging.hpp"
#include "mspace/feature_log.hpp"
#include "mspace/transform.hpp"
#include "problem.hpp"

namespace mspace::kernel {
namespace {

using Clock = std::chrono::steady_clock;

double seconds_since(Clock::time_point start) {
  return std::chrono::duration<double>(Clock::now() - start).count();
}

/// The path "distance" used to age dense information weighs a radian of
/// rotation like this many metres of travel: heading errors grow faster and
/// do more harm than translation errors (ICRA §IV, "Add Information").
constexpr double kRotationWeightMetresPerRadian = 2.0;

/// Updates over which a sensor's NIS is averaged for a health warning.
constexpr int kNisWindow = 200;

bool all_finite(const Eigen::MatrixXd& m) { return m.allFinite(); }

/// The three columns of planar_global_motion before any is left out.
Eigen::MatrixXd planar_motion_rows(const Pose6& pose, const std::vector<int>& dofs) {
  Eigen::Matrix<double, 6, 3> all = Eigen::Matrix<double, 6, 3>::Zero();
  all.row(kX) << 1.0, 0.0, -pose[kY];
  all.row(kY) << 0.0, 1.0, pose[kX];
  all.row(kTheta) << 0.0, 0.0, 1.0;
  Eigen::MatrixXd rows(static_cast<Eigen::Index>(dofs.size()), 3);
  for (std::size_t i = 0; i < dofs.size(); ++i) rows.row(static_cast<Eigen::Index>(i)) = all.row(dofs[i]);
  return rows;
}

/// The columns of `rows` that are not zero.
std::vector<Eigen::Index> nonzero_columns(const Eigen::MatrixXd& rows) {
  std::vector<Eigen::Index> kept;
  for (Eigen::Index c = 0; c < rows.cols(); ++c)
    if (!rows.col(c).isZero(0.0)) kept.push_back(c);
  return kept;
}

/// The directions of the robot's estimated pose coordinates `dofs` along which
/// a global planar motion of robot and map moves them, at `pose`: one column
/// each for translation along the map's x and y axes and rotation about its z
/// axis through the origin (a rotation by δ moves (x, y) by δ·(−y, x) and the
/// heading θ by δ). Other coordinates (z, φ, ψ) do not move; a column that
/// touches no estimated coordinate is left out. For Estimator::set_unobservable.
Eigen::MatrixXd planar_global_motion(const Pose6& pose, const std::vector<int>& dofs) {
  const Eigen::MatrixXd rows = planar_motion_rows(pose, dofs);
  return rows(Eigen::all, nonzero_columns(rows));
}

/// How the same three global motions move a feature's coordinates x_f
/// (n × 3): the (x, y) of every point block by (1, 0), (0, 1) and (−y, x);
/// heights and scalar blocks not at all.
Eigen::MatrixXd feature_planar_motion(const CoordLayout& layout, const Eigen::VectorXd& x) {
  Eigen::MatrixXd D = Eigen::MatrixXd::Zero(x.size(), 3);
  for (int b = 0; b < layout.num_blocks(); ++b) {
    if (layout.kind(b) == BlockKind::Scalar) continue;
    const int o = layout.offset(b);
    D(o, 0) = 1.0;
    D(o + 1, 1) = 1.0;
    D(o, 2) = -x[o + 1];
    D(o + 1, 2) = x[o];
  }
  return D;
}

/// Throws a PluginError naming the instance when a plugin hands back NaN/inf.
void require_finite(const Eigen::MatrixXd& m, const char* what, const std::string& instance,
                    const LoadedPlugin& lib) {
  if (all_finite(m)) return;
  std::ostringstream os;
  os << instance << " (plugin '" << lib.descriptor->name << "', library '" << lib.path.string()
     << "'): " << what << " contains NaN or infinity";
  throw PluginError(os.str());
}

Eigen::MatrixXd columns(const Eigen::MatrixXd& m, const std::vector<int>& cols) {
  Eigen::MatrixXd out(m.rows(), static_cast<Eigen::Index>(cols.size()));
  for (std::size_t j = 0; j < cols.size(); ++j) out.col(static_cast<Eigen::Index>(j)) = m.col(cols[j]);
  return out;
}

}  // namespace

struct Slam::Match {
  int feature = 0;
  int sensor = 0;
  int measurement = 0;  ///< index into the reading's measurements
  Candidate candidate;
};

/// What phases 3 and 4 need from one reading.
struct Slam::ReadingWork {
  int sensor = 0;
  double t = 0.0;
  std::vector<Measurement> measurements;
  std::vector<Match> matches;
  std::vector<bool> may_create;  ///< per measurement: far from every feature
};

std::shared_ptr<Feature> FeatureTypeSlot::adopt(std::unique_ptr<Feature> feature, std::int64_t id) const {
  if (!feature) return nullptr;
  if (!log)  // tools and tests without the type's logger: feature_log() drops everything
    return std::shared_ptr<Feature>(feature.release(), [library = library](Feature* p) { delete p; });
  std::string prefix = "#";  // appended piecewise: GCC 12 -Wrestrict misfires on "#" + std::to_string(id)
  prefix.append(std::to_string(id)).append(": ");
  std::shared_ptr<Logger> prefixed = make_prefixed_logger(log, std::move(prefix));
  attach_feature_log(*feature, prefixed.get());
  // The deleter owns what the feature refers to, its plugin library and its
  // logger, and detaches the logger first (the address may be reused).
  return std::shared_ptr<Feature>(feature.release(), [library = library, prefixed](Feature* p) {
    attach_feature_log(*p, nullptr);
    delete p;
  });
}

Slam::Slam(const RunConfig& config, PluginRegistry& registry)
    : config_(config),
      log_(make_instance_logger("slam")),
      covariance_health_(config.health_check_every),
      associator_(config.association, config.sensors, log_) {
  auto make = [&](const InstanceConfig& inst, PluginKind kind, auto* tag,
                  std::shared_ptr<const LoadedPlugin>& lib) {
    using T = std::remove_pointer_t<decltype(tag)>;
    auto logger = make_instance_logger(inst.instance);
    plugin_loggers_.push_back(logger);
    PluginArgs args{inst.instance, inst.params, logger.get()};
    lib = registry.load(inst.plugin);
    return registry.create<T>(inst.plugin, kind, args);
  };
  const auto source_start = Clock::now();
  source_ = make(config_.source, PluginKind::Source, static_cast<DataSource*>(nullptr), source_lib_);
  source_load_seconds_ = seconds_since(source_start);
  motion_ = make(config_.motion, PluginKind::MotionModel, static_cast<MotionModel*>(nullptr), motion_lib_);
  estimator_ = make(config_.estimator, PluginKind::Estimator, static_cast<Estimator*>(nullptr), estimator_lib_);

  for (const InstanceConfig& fc : config_.features) {
    FeatureTypeSlot slot;
    slot.instance = fc.instance;
    slot.plugin = fc.plugin;
    slot.type = make(fc, PluginKind::Feature, static_cast<FeatureType*>(nullptr), slot.library);
    slot.log = plugin_loggers_.back();
    types_.push_back(std::move(slot));
  }
  for (const SensorConfig& sc : config_.sensors) {
    SensorSlot slot;
    slot.config = sc;
    slot.extractor = make(sc.extractor, PluginKind::Extractor, static_cast<Extractor*>(nullptr), slot.library);
    for (const std::string& feed : sc.feeds) {
      for (std::size_t i = 0; i < types_.size(); ++i)
        if (types_[i].instance == feed) slot.feeds.push_back(static_cast<int>(i));
    }
    health_.emplace_back(sc.name, "sensors." + sc.name + ".extractor, plugin '" + sc.extractor.plugin + "'",
                         sc.silent_readings, kNisWindow, config_.association.gate_probability);
    sensors_.push_back(std::move(slot));
  }

  for (std::size_t i = 0; i < sensors_.size(); ++i)
    if (sensors_[i].config.name == config_.evaluation.ground_truth_sensor) ground_truth_sensor_ = static_cast<int>(i);
  check_recorded_mounts();

  dofs_ = guarded(config_.motion.instance, *motion_lib_, "estimated_dofs",
                  [&] { return motion_->estimated_dofs(); });
  if (dofs_.empty() || !std::is_sorted(dofs_.begin(), dofs_.end()) || dofs_.front() < 0 || dofs_.back() > 5)
    throw PluginError(config_.motion.instance + " (plugin '" + config_.motion.plugin +
                      "'): estimated_dofs must be ascending pose indices in 0..5");
  robot_idx_.resize(dofs_.size());
  std::iota(robot_idx_.begin(), robot_idx_.end(), 0);

  x_r_ = guarded(config_.source.instance, *source_lib_, "initial_pose", [&] { return source_->initial_pose(); });
  if (!config_.initial_pose.isZero()) x_r_ = config_.initial_pose;
  const Eigen::MatrixXd P0 = initial_covariance();
  reset_estimator(P0);

  if (guarded(config_.estimator.instance, *estimator_lib_, "wants_problem",
              [&] { return estimator_->wants_problem(); })) {
    Problem::Context pc{&features_, &types_, &x_r_, dofs_, {}, motion_.get(), motion_lib_.get(),
                        config_.motion.instance, estimator_.get(), estimator_lib_.get(), config_.estimator.instance};
    for (const SensorSlot& s : sensors_) pc.mounts.push_back(s.config.mount);
    pc.freeze_in_sensor_frame = config_.problem.freeze_in_sensor_frame;
    problem_ = std::make_unique<Problem>(std::move(pc));
    problem_->start(P0);
  }
  if (config_.checkpoint_every > 0) require_checkpointable();  // say so now, not at the first checkpoint
  if (config_.checkpoint_every > 0 && (config_.map.mode != MapConfig::Mode::Mapping || config_.skip_steps > 0))
    throw ConfigError(config_.file.string() + ": run.checkpoint_every: checkpoints of a run that loads a map or skips "
                      "data steps are not supported yet (a resumed run would not know the map or the skipped steps)");
  if (config_.map.search_pose) {  // (the YAML reader and the command line check this too)
    const std::string problem = map_config_problem(config_.map);
    if (!problem.empty()) throw ConfigError(config_.file.string() + ": " + problem);
  }
  if (config_.map.mode != MapConfig::Mode::Mapping) load_map();
  const auto skip_start = Clock::now();
  skip_data_steps();
  source_load_seconds_ += seconds_since(skip_start);
}

Slam::~Slam() {
  // Features were created by plugins: drop them before the types and libraries.
  problem_.reset();
  features_.clear();
}

Eigen::MatrixXd Slam::initial_covariance() const {
  const int k = static_cast<int>(dofs_.size());
  Eigen::MatrixXd P0 = Eigen::MatrixXd::Zero(k, k);
  for (int i = 0; i < k; ++i) P0(i, i) = config_.initial_sigma[dofs_[i]] * config_.initial_sigma[dofs_[i]];
  return P0;
}

void Slam::reset_estimator(const Eigen::MatrixXd& P0) {
  guarded(config_.estimator.instance, *estimator_lib_, "reset", [&] { estimator_->reset(P0); });
  const Eigen::MatrixXd U_r = planar_global_motion(x_r_, dofs_);
  guarded(config_.estimator.instance, *estimator_lib_, "set_unobservable",
          [&] { estimator_->set_unobservable(U_r); });
}

std::size_t Slam::size_hint() const {
  const std::size_t hint = source_->size_hint();
  if (config_.max_steps > 0) {
    const auto cap = static_cast<std::size_t>(config_.max_steps);
    return hint == 0 ? cap : std::min(hint, cap);
  }
  return hint;
}

Eigen::MatrixXd Slam::true_landmarks() const { return source_->true_landmarks(); }

std::size_t Slam::skipped_records() const { return source_->skipped_records(); }

Eigen::MatrixXd Slam::robot_covariance() const { return checked_marginal(robot_idx_); }

Eigen::MatrixXd Slam::feature_covariance(const MapFeature& f) const {
  if (f.state_idx.empty()) return {};
  return state_covariance(f.state_idx);
}

Eigen::VectorXd Slam::shared_value(const SharedCoordinate& c) const {
  const auto [feature_id, block] = c.members.front();
  for (const MapFeature& mf : features_)
    if (mf.id == feature_id) {
      const CoordLayout& layout = mf.feature->layout();
      return mf.feature->coords().segment(layout.offset(block), block_size(layout.kind(block)));
    }
  return {};
}

bool Slam::step() {
  // The data ends before the robot was found in the map (initial_pose:
  // search): the loaded map goes back in place, the poses stay in the run's frame.
  const auto end_of_data = [&] {
    if (pose_search_) install_searched_map(nullptr, 0.0, 0.0);
    return relinearize(true);
  };
  if (config_.max_steps > 0 && step_ >= config_.max_steps) return end_of_data();
  DataStep data;
  auto t0 = Clock::now();
  const bool more = guarded(config_.source.instance, *source_lib_, "next", [&] { return source_->next(data); });
  stats_.seconds_source += seconds_since(t0);
  if (!more) return end_of_data();
  ++step_;
  ++stats_.steps;

  t0 = Clock::now();
  predict(data);
  // (While initial_pose: search searches, the robot is in a frame of its own: no truth to compare.)
  robot_truth_ = pose_search_ ? std::nullopt : robot_truth(data, ground_truth_sensor_, dofs_);
  if (problem_ && !data.readings.empty()) problem_->key_pose(trajectory_.size());
  stats_.seconds_predict += seconds_since(t0);
  const AssociationConfig& a = config_.association;
  if ((a.loop_closing && a.loop_scans) || a.relocalize_by_scans) keep_scans(data);
  if (a.relocalize_by_scans && !pose_search_ && !localizing()) {
    t0 = Clock::now();
    relocalize(data);
    stats_.seconds_loops += seconds_since(t0);
  }

  std::vector<ReadingWork> work;
  for (const SensorReading& reading : data.readings) process_reading(reading, work);
  if (localizing() && config_.map.extend_when_unmapped > 0.0)
    watch_for_unmapped(std::any_of(work.begin(), work.end(), [](const ReadingWork& w) { return !w.matches.empty(); }));

  t0 = Clock::now();
  add_dense_information(work);
  stats_.seconds_dense += seconds_since(t0);

  t0 = Clock::now();
  std::vector<int> touched;
  for (const ReadingWork& w : work)
    for (const Match& m : w.matches) touched.push_back(m.feature);
  if (!localizing())  // (localize creates nothing; this scan would cost O(map size) per step)
    for (std::size_t i = 0; i < features_.size(); ++i)
      if (features_[i].created_step == step_) touched.push_back(static_cast<int>(i));
  std::sort(touched.begin(), touched.end());
  touched.erase(std::unique(touched.begin(), touched.end()), touched.end());
  if (!localizing()) {  // a map being localized in is read-only: phases 3 and 4 leave it alone
    extend(touched);
    if (config_.association.join_distance > 0.0) join_shared_coordinates(touched);
    prune_tentative();
  }
  stats_.seconds_extend += seconds_since(t0);
  if (!work.empty() && !localizing()) associator_.map_changed();  // features were created, extended, joined
  if (pose_search_ && !work.empty()) {  // initial_pose: search
    t0 = Clock::now();
    search_pose();
    stats_.seconds_loops += seconds_since(t0);
  } else if (config_.association.loop_closing && !work.empty() && !localizing()) {
    t0 = Clock::now();
    close_loops(data);
    stats_.seconds_loops += seconds_since(t0);
  }

  relinearize(false);
  remember_truth_images();
  if (covariance_health_.full_check_due(step_)) covariance_health_.record_full(covariance_figures_now(), step_);

  record(data);
  if (step_observer_) step_observer_(data, trajectory_.size() - 1);
  return true;
}

bool Slam::relinearize(bool end_of_data) {
  if (!problem_ || finished_) return false;
  finished_ = end_of_data;
  const auto t0 = Clock::now();
  if (problem_->end_of_step(end_of_data)) {  // a re-linearising estimator moved everything
    problem_->smoothed(trajectory_, evaluated_,
                       ground_truth_sensor_ >= 0 ? &sensors_[ground_truth_sensor_].config.mount : nullptr);
    associator_.map_changed();
    refresh_unobservable();
  }
  stats_.seconds_update += seconds_since(t0);
  return false;
}

void Slam::refresh_unobservable() {
  const Eigen::MatrixXd robot = planar_motion_rows(x_r_, dofs_);
  const std::vector<Eigen::Index> kept = nonzero_columns(robot);
  Eigen::MatrixXd U = Eigen::MatrixXd::Zero(estimator_->dim(), 3);
  U.topRows(robot.rows()) = robot;
  // A feature's M-space rows move by δx_p = B(x_f) δx_f (eq. 10); a shared
  // coordinate's rows get the same values from each member (eq. 33's identity).
  for (const MapFeature& f : features_) {
    if (f.state_idx.empty()) continue;
    const FeatureTypeSlot& type = types_[static_cast<std::size_t>(f.type)];
    const Eigen::MatrixXd B = guarded(type.instance, *type.library, "B", [&] { return f.feature->B(); });
    const Eigen::MatrixXd rows = B * feature_planar_motion(f.feature->layout(), f.feature->coords());
    if (rows.rows() != static_cast<Eigen::Index>(f.state_idx.size()))
      throw PluginError(type.instance + " (plugin '" + type.plugin + "'): B of feature #" + std::to_string(f.id) +
                        " has " + std::to_string(rows.rows()) + " rows for its " + std::to_string(f.state_idx.size()) +
                        " estimator rows");
    for (std::size_t i = 0; i < f.state_idx.size(); ++i)
      U.row(f.state_idx[i]) = rows.row(static_cast<Eigen::Index>(i));
  }
  const Eigen::MatrixXd U_kept = U(Eigen::all, kept);
  guarded(config_.estimator.instance, *estimator_lib_, "set_unobservable",
          [&] { estimator_->set_unobservable(U_kept); });
}

// ---- Phase 1: predict ------------------------------------------------------

void Slam::predict(const DataStep& data) {
  const double dt = started_ ? data.t - t_ : 0.0;
  if (!started_) dead_reckoning_pose_ = x_r_;  // the baseline starts where the run starts
  started_ = true;
  t_ = data.t;
  step_motion_Q_.resize(0, 0);
  if (data.odometry.size() == 0) {
    if (problem_) problem_->motion(data.odometry, dt, trajectory_.size());
    return;
  }
  require_finite(data.odometry, "odometry increment", config_.source.instance, *source_lib_);
  // The increment's own covariance, when the source measured it (e.g. laser
  // odometry's scan match), replaces the motion model's C_d in eq. 26.
  const Eigen::MatrixXd& C_data = data.odometry_covariance;
  if (C_data.size() > 0) {
    if (C_data.rows() != data.odometry.size() || C_data.cols() != data.odometry.size())
      throw PluginError(config_.source.instance + " (plugin '" + config_.source.plugin + "'): odometry_covariance is " +
                        std::to_string(C_data.rows()) + " x " + std::to_string(C_data.cols()) + " for an increment of " +
                        std::to_string(data.odometry.size()) + " values");
    require_finite(C_data, "odometry_covariance", config_.source.instance, *source_lib_);
  }
  if (problem_) problem_->motion(data.odometry, dt, trajectory_.size(), C_data);
  MotionPrediction pred = guarded(config_.motion.instance, *motion_lib_, "predict",
                                        [&] { return motion_->predict(x_r_, data.odometry, dt); });
  const int k = static_cast<int>(dofs_.size());
  if (pred.J_rr.rows() != k || pred.J_rr.cols() != k || pred.J_rd.rows() != k ||
      pred.J_rd.cols() != pred.C_d.rows() || pred.C_d.rows() != pred.C_d.cols())
    throw PluginError(config_.motion.instance + " (plugin '" + config_.motion.plugin +
                      "'): predict returned matrices of inconsistent sizes");
  require_finite(pred.pose, "predicted pose", config_.motion.instance, *motion_lib_);
  require_finite(pred.J_rr, "J_rr", config_.motion.instance, *motion_lib_);
  require_finite(pred.J_rd, "J_rd", config_.motion.instance, *motion_lib_);
  require_finite(pred.C_d, "C_d", config_.motion.instance, *motion_lib_);
  if (C_data.size() > 0) {
    if (C_data.rows() != pred.C_d.rows())
      throw PluginError(config_.source.instance + " (plugin '" + config_.source.plugin +
                        "'): odometry_covariance is " + std::to_string(C_data.rows()) + " x " +
                        std::to_string(C_data.cols()) + " but motion model " + config_.motion.instance + " has " +
                        std::to_string(pred.C_d.rows()) + " x " + std::to_string(pred.C_d.cols()));
    pred.C_d = C_data;
  }

  // The dead-reckoning baseline: the same increment through the same model, never updated.
  const Pose6 dead_reckoning = guarded(config_.motion.instance, *motion_lib_, "predict", [&] {
    return motion_->predict(dead_reckoning_pose_, data.odometry, dt).pose;
  });
  require_finite(dead_reckoning, "dead-reckoning pose", config_.motion.instance, *motion_lib_);
  dead_reckoning_pose_ = dead_reckoning;
  ++odometry_steps_;

  const Pose6 delta = pose_difference(pred.pose, x_r_);
  path_distance_ += delta.head<3>().norm() + kRotationWeightMetresPerRadian * delta.tail<3>().norm();
  x_r_ = pred.pose;
  const Eigen::MatrixXd Q = pred.J_rd * pred.C_d * pred.J_rd.transpose();  // eq. 26
  step_motion_Q_ = Q;
  guarded(config_.estimator.instance, *estimator_lib_, "predict", [&] { estimator_->predict(pred.J_rr, Q); });
  if (considered_) considered_->predict(pred.J_rr);
}

// A sensor whose mount the data records (a camera calibration file) must be
// configured with that mount: the configuration repeats it (the SDK keeps
// sensors and data sources apart), and a copy that disagrees would silently
// bend every measurement.
void Slam::check_recorded_mounts() const {
  const std::vector<RecordedMount> recorded =
      guarded(config_.source.instance, *source_lib_, "recorded_mounts", [&] { return source_->recorded_mounts(); });
  auto text = [](const Pose6& m) {
    std::ostringstream s;
    const double deg = 180.0 / std::numbers::pi;
    s << "[" << m[kX] << ", " << m[kY] << ", " << m[kZ] << ", " << m[kTheta] * deg << ", " << m[kPhi] * deg << ", "
      << m[kPsi] * deg << "]";
    return s.str();
  };
  for (const RecordedMount& r : recorded) {
    for (const SensorSlot& sensor : sensors_) {
      if (sensor.config.channel != r.channel) continue;
      const Pose6 d = sensor.config.mount - r.mount;
      bool same = d.head<3>().cwiseAbs().maxCoeff() <= 1e-6;
      for (int a = kTheta; a <= kPsi; ++a) same = same && std::abs(wrap_angle(d[a])) <= 1e-6;
      if (!same)
        throw ConfigError(config_.file.string() + ": sensors." + sensor.config.name + ".mount " +
                          text(sensor.config.mount) + " (x y z m, theta phi psi deg) differs from the mount " +
                          text(r.mount) + " that " + r.origin + " records for channel '" + r.channel + "'");
    }
  }
}

SensorView Slam::sensor_view(int sensor_index, double t) const {
  SensorView view;
  view.t = t;
  view.sensor = sensor_index;
  Mat6 J_sr;
  view.x_ms = compound(x_r_, sensors_[sensor_index].config.mount, &J_sr);  // eq. 17
  const Eigen::MatrixXd J = columns(J_sr, dofs_);
  view.C_ms = J * checked_marginal(robot_idx_) * J.transpose();
  view.path_distance = path_distance_;
  return view;
}

// Every sensor on the reading's channel extracts from it (one camera can feed
// a line extractor and a point extractor), one after the other, each with its
// own association and update.
void Slam::process_reading(const SensorReading& reading, std::vector<ReadingWork>& work) {
  ++stats_.readings;
  bool known = false;
  for (std::size_t i = 0; i < sensors_.size(); ++i) {
    if (sensors_[i].config.channel != reading.channel) continue;
    known = true;
    process_sensor_reading(reading, static_cast<int>(i), work);
  }
  if (!known && stats_.unknown_channel_readings++ == 0)
    log_->warn("reading on channel '", reading.channel,
               "' has no sensor in the configuration; such readings are skipped (counted in the summary)");
}

void Slam::process_sensor_reading(const SensorReading& reading, int sensor_index, std::vector<ReadingWork>& work) {
  const SensorSlot& sensor = sensors_[sensor_index];
  ReadingWork w;
  w.sensor = sensor_index;
  w.t = reading.t;
  auto t0 = Clock::now();
  guarded(sensor.config.extractor.instance, *sensor.library, "extract",
          [&] { sensor.extractor->extract(reading, w.measurements); });
  for (const Measurement& m : w.measurements) {
    require_finite(m.v, "measurement vector", sensor.config.extractor.instance, *sensor.library);
    require_finite(m.C_v, "measurement covariance", sensor.config.extractor.instance, *sensor.library);
  }
  stats_.measurements += static_cast<std::int64_t>(w.measurements.size());
  const double extract_seconds = seconds_since(t0);
  stats_.seconds_extract += extract_seconds;
  t0 = Clock::now();
  associate(sensor, sensor_index, w.measurements, w);
  stats_.seconds_associate += seconds_since(t0);
  record_health(sensor_index, w, extract_seconds);

  t0 = Clock::now();
  if (problem_)
    for (const Match& m : w.matches)
      if (features_[m.feature].feature->mspace_dim() > 0)
        problem_->observed(features_[m.feature], w.measurements[m.measurement], sensor_index, m.candidate.innovation,
                           m.candidate.C_eta, m.candidate.J_state);
  update(w.matches);
  stats_.seconds_update += seconds_since(t0);
  if (!w.matches.empty() && !localizing()) associator_.map_changed();  // the update moved features
  work.push_back(std::move(w));
}

// Association (ICRA §IV, "Prediction"): Mahalanobis gating, then nearest
// neighbour or joint compatibility, and which measurements may start new
// features — all in association.cpp.
void Slam::associate(const SensorSlot& sensor, int sensor_index, const std::vector<Measurement>& meas,
                     ReadingWork& work) {
  Mat6 J_sr;
  const Pose6 x_ms = compound(x_r_, sensor.config.mount, &J_sr);  // eq. 17
  AssociationView map{features_, types_, [this](const std::vector<int>& rows) { return state_covariance(rows); },
                      robot_idx_, step_, {}};
  if (config_.association.reentry_joint_test)
    map.travel_unseen = [this](const MapFeature& mf) { return path_distance_ - mf.last_seen_path; };
  AssociationResult result = associator_.associate(map, sensor, x_ms, columns(J_sr, dofs_), meas);
  for (Candidate& c : result.matches) {
    Match match;
    match.feature = c.feature;
    match.sensor = sensor_index;
    match.measurement = c.measurement;
    match.candidate = std::move(c);
    work.matches.push_back(std::move(match));
  }
  stats_.matched += static_cast<std::int64_t>(work.matches.size());
  work.may_create = std::move(result.may_create);
  check_matches_against_ground_truth(work);
}

// With ground truth (generated worlds): is each match the object it claims
// to be? After every update the matched features' coordinates are taken into
// the true frame through the robot's pose (remember_truth_images): where the
// object the robot saw then truly lies. A later match is checked against
// that place brought back into the current estimate through the robot's pose
// now — where the feature would be if it were the same object, whatever the
// robot's error or the map's distortion since — by the innovation moved to
// first order (δx_p = B Δx_f, the feature's columns of J, eq. 30), gated by
// the measurement's noise plus 0.2 m and 2° of the robot's pose (the map's
// local distortion, a feature seen partly hidden) at 99.9 %: two objects some
// metres apart differ by D² in the hundreds, and with 0.1 m and 1° one
// generated world had five verdicts that its final map contradicts (D² 18–47;
// README, "Wrong matches, counted against the ground truth"). Planar robots
// only (the motions are planar). A counter for tests and the summary; the run
// does not act on it.
void Slam::check_matches_against_ground_truth(const ReadingWork& w) {
  if (!robot_truth_ || !planar_robot()) return;
  const Pose6& truth = *robot_truth_;
  // The truth-to-estimate motion now: q ↦ R(θ_est − θ_gt)(q − t_gt) + t_est.
  const PlanarMotion back{wrap_angle(x_r_[kTheta] - truth[kTheta]),
                          Eigen::Vector2d(x_r_[kX] - truth[kX], x_r_[kY] - truth[kY]),
                          Eigen::Vector2d(truth[kX], truth[kY])};
  const auto k = static_cast<Eigen::Index>(dofs_.size());
  Eigen::VectorXd allowance(k);
  for (Eigen::Index i = 0; i < k; ++i)
    allowance[i] = dofs_[static_cast<std::size_t>(i)] == kTheta ? std::pow(2.0 * std::numbers::pi / 180.0, 2) : 0.04;
  for (const Match& m : w.matches) {
    const MapFeature& f = features_[static_cast<std::size_t>(m.feature)];
    const Candidate& c = m.candidate;
    const int dim = f.feature->mspace_dim();
    if (c.tentative || dim == 0 || f.truth_image.size() == 0 || c.J_state.cols() != k + dim) continue;
    const Eigen::VectorXd x_f = f.feature->coords();
    if (f.truth_image.size() != x_f.size()) continue;
    const Eigen::VectorXd moved = back.apply(f.feature->layout(), f.truth_image) - x_f;
    const Eigen::MatrixXd B = guarded(types_[static_cast<std::size_t>(f.type)].instance,
                                      *types_[static_cast<std::size_t>(f.type)].library, "B", [&] { return f.feature->B(); });
    if (B.rows() != dim || B.cols() != x_f.size()) continue;
    const Eigen::VectorXd eta = c.innovation.eta + c.J_state.rightCols(dim) * (B * moved);
    const Eigen::MatrixXd J_r = c.J_state.leftCols(k);
    const Eigen::MatrixXd S = c.C_eta + J_r * allowance.asDiagonal() * J_r.transpose();
    const Eigen::LDLT<Eigen::MatrixXd> ldlt(S);
    if (ldlt.info() != Eigen::Success) continue;
    const double d2 = eta.dot(ldlt.solve(eta));
    const double unseen = path_distance_ - f.last_seen_path;
    const bool long_unseen = unseen > config_.association.loop_min_gap_path;
    const bool wrong = d2 > chi2_quantile(0.999, static_cast<int>(eta.size()));
    ++stats_.matches_checked;
    stats_.matches_long_unseen += long_unseen ? 1 : 0;
    stats_.matches_wrong += wrong ? 1 : 0;
    stats_.matches_wrong_long_unseen += wrong && long_unseen ? 1 : 0;
    if (wrong) wrong_matches_.push_back({step_, f.id, f.last_seen_step});
    if (wrong)
      log_->debug("step ", step_, ": ground truth: the match with #", f.id, " (last seen ", unseen,
                  " m of travel ago, gate D² ", c.d2, ") is another object: D² ", d2,
                  " where the truth puts the object it was");
  }
}

bool Slam::planar_robot() const {
  return std::all_of(dofs_.begin(), dofs_.end(), [](int d) { return d == kX || d == kY || d == kTheta; });
}

void Slam::remember_truth_images() {
  // At the end of the step: after the loop closing and the re-linearisation, which may move the robot relative to
  // the features it has just seen.
  if (robot_truth_ && planar_robot() && !matched_this_step_.empty()) {
    const Pose6& truth = *robot_truth_;
    const PlanarMotion to_truth{wrap_angle(truth[kTheta] - x_r_[kTheta]),
                                Eigen::Vector2d(truth[kX] - x_r_[kX], truth[kY] - x_r_[kY]),
                                Eigen::Vector2d(x_r_[kX], x_r_[kY])};
    std::sort(matched_this_step_.begin(), matched_this_step_.end());
    for (MapFeature& f : features_)  // (by id: pruning tentative features since the update moved the indices)
      if (f.feature->mspace_dim() > 0 &&
          std::binary_search(matched_this_step_.begin(), matched_this_step_.end(), f.id))
        f.truth_image = to_truth.apply(f.feature->layout(), f.feature->coords());
  }
  matched_this_step_.clear();
}

// The health report of the sensor (sensor_health.hpp): counts, and the NIS of
// the measurements its update will use; new warnings go to the log at once.
void Slam::record_health(int sensor_index, const ReadingWork& w, double extract_seconds) {
  SensorHealth& health = health_[static_cast<std::size_t>(sensor_index)];
  health.record_reading(static_cast<std::int64_t>(w.measurements.size()), static_cast<std::int64_t>(w.matches.size()),
                        extract_seconds);
  for (const Match& match : w.matches) {
    const MapFeature& f = features_[match.feature];
    if (f.feature->mspace_dim() == 0) continue;
    std::vector<int> idx = robot_idx_;
    idx.insert(idx.end(), f.state_idx.begin(), f.state_idx.end());
    const Candidate& c = match.candidate;
    health.record_update({w.measurements[match.measurement].kind, c.innovation.eta, c.J_state,
                          state_covariance(idx), c.C_eta, static_cast<int>(robot_idx_.size()),
                          robot_truth_ ? robot_error(*robot_truth_, x_r_, dofs_) : Eigen::VectorXd()});
  }
  for (const std::string& warning : health.take_new_warnings()) log_->warn("step ", step_, ": ", warning);
  for (const std::string& note : health.take_new_notes()) log_->info("step ", step_, ": ", note);
}

std::vector<SensorHealthReport> Slam::sensor_health() const {
  std::vector<SensorHealthReport> out;
  for (const SensorHealth& h : health_) out.push_back(h.report());
  return out;
}

// ---- Phase 2: update -------------------------------------------------------

void Slam::update(std::vector<Match>& matches) {
  std::vector<LinearizedObservation> obs;
  for (const Match& match : matches) {
    const MapFeature& mf = features_[match.feature];
    if (mf.feature->mspace_dim() == 0) continue;  // tentative: dense information only
    const Candidate& c = match.candidate;
    LinearizedObservation o;
    o.eta = c.innovation.eta;
    o.C_eta = c.C_eta;
    o.idx = robot_idx_;
    o.idx.insert(o.idx.end(), mf.state_idx.begin(), mf.state_idx.end());
    o.J = c.J_state;
    obs.push_back(std::move(o));
  }
  if (obs.empty()) return;
  if (config_.association.loop_closing && !localizing()) {  // a read-only map closes no loops
    std::vector<std::pair<int, const Candidate*>> matched;
    for (const Match& match : matches) matched.emplace_back(match.feature, &match.candidate);
    note_anchor(matched);
  }
  stats_.updates += static_cast<std::int64_t>(obs.size());
  const Eigen::VectorXd dx = localizing() ? consider_update(obs) : estimator_update(obs, "update");

  if (log_->enabled(LogLevel::Debug)) {
    std::string used;
    for (const Match& match : matches) {
      const MapFeature& mf = features_[match.feature];
      if (mf.feature->mspace_dim() == 0) continue;
      used += " #" + std::to_string(mf.id) + "(dim " + std::to_string(mf.feature->mspace_dim()) +
              ", d2 " + std::to_string(match.candidate.d2) + ")";
    }
    log_->debug("step ", step_, ": update with", used, "; robot correction ",
                dx.head(static_cast<Eigen::Index>(dofs_.size())).transpose());
  }
  apply_correction(dx);
  if (robot_truth_)
    for (const Match& match : matches) matched_this_step_.push_back(features_[match.feature].id);
}

Eigen::VectorXd Slam::estimator_update(const std::vector<LinearizedObservation>& obs, const char* what) {
  const Eigen::VectorXd dx =
      guarded(config_.estimator.instance, *estimator_lib_, what, [&] { return estimator_->update(obs); });
  const int dim = estimator_->dim();
  if (dx.size() != dim)
    throw PluginError(config_.estimator.instance + " (plugin '" + config_.estimator.plugin + "', library '" +
                      estimator_lib_->path.string() + "'): " + what + " returned a state perturbation of size " +
                      std::to_string(dx.size()) + " for a state of " + std::to_string(dim) + " rows");
  require_finite(dx, "state perturbation", config_.estimator.instance, *estimator_lib_);
  // The rows this update touched: the covariance there must still be
  // positive definite (covariance_health.hpp).
  std::vector<int> touched;
  for (const LinearizedObservation& o : obs) touched.insert(touched.end(), o.idx.begin(), o.idx.end());
  std::sort(touched.begin(), touched.end());
  touched.erase(std::unique(touched.begin(), touched.end()), touched.end());
  const std::string warning = covariance_health_.check_block(checked_marginal(touched), step_);
  if (!warning.empty()) log_->warn(config_.estimator.instance, " (plugin '", config_.estimator.plugin, "'): ", warning);
  return dx;
}

Eigen::MatrixXd Slam::checked_marginal(const std::vector<int>& idx) const {
  const Eigen::MatrixXd C =
      guarded(config_.estimator.instance, *estimator_lib_, "marginal", [&] { return estimator_->marginal(idx); });
  const auto n = static_cast<Eigen::Index>(idx.size());
  if (C.rows() != n || C.cols() != n)
    throw PluginError(config_.estimator.instance + " (plugin '" + config_.estimator.plugin + "', library '" +
                      estimator_lib_->path.string() + "'): marginal returned a " + std::to_string(C.rows()) + " x " +
                      std::to_string(C.cols()) + " matrix for " + std::to_string(n) + " state rows");
  require_finite(C, "the covariance (marginal)", config_.estimator.instance, *estimator_lib_);
  return C;
}

CovarianceFigures Slam::covariance_figures_now() const {
  std::vector<int> all(static_cast<std::size_t>(estimator_->dim()));
  std::iota(all.begin(), all.end(), 0);
  return covariance_figures(checked_marginal(all));
}

void Slam::apply_correction(const Eigen::VectorXd& dx) {
  for (std::size_t i = 0; i < dofs_.size(); ++i) x_r_[dofs_[i]] += dx[static_cast<Eigen::Index>(i)];
  for (int a = kTheta; a <= kPsi; ++a) x_r_[a] = wrap_angle(x_r_[a]);
  if (problem_) problem_->moved(dx);
  if (localizing()) return;  // dx holds the robot only: the map is read-only
  // One δx_p vector per M-space dimension, reused from feature to feature:
  // this loop visits every feature in the estimator after every update.
  std::vector<Eigen::VectorXd> by_dim;
  for (MapFeature& mf : features_) {  // eq. 24: x_f += B̃ δx_p
    if (mf.state_idx.empty()) continue;
    const std::size_t dim = mf.state_idx.size();
    if (by_dim.size() <= dim) by_dim.resize(dim + 1);
    Eigen::VectorXd& dx_p = by_dim[dim];
    dx_p.resize(static_cast<Eigen::Index>(dim));
    for (std::size_t j = 0; j < dim; ++j) dx_p[static_cast<Eigen::Index>(j)] = dx[mf.state_idx[j]];
    const FeatureTypeSlot& type = types_[mf.type];
    guarded(type.instance, *type.library, "apply_perturbation", [&] { mf.feature->apply_perturbation(dx_p); });
  }
}

// ---- Phase 3: add dense information ----------------------------------------

void Slam::add_dense_information(std::vector<ReadingWork>& work) {
  if (localizing()) return;  // the map is read-only: no evidence added, no features created
  for (ReadingWork& w : work) {
    const SensorView view = sensor_view(w.sensor, w.t);  // after the update
    for (const Match& match : w.matches) {
      MapFeature& mf = features_[match.feature];
      const FeatureTypeSlot& type = types_[mf.type];
      guarded(type.instance, *type.library, "add_dense_information",
              [&] { mf.feature->add_dense_information(w.measurements[match.measurement], view); });
      mf.last_seen_step = step_;
      if (path_distance_ - mf.last_seen_path > config_.association.loop_min_gap_path) mf.seen_since_path = path_distance_;
      mf.last_seen_path = path_distance_;
      mf.last_sensor = w.sensor;
      mf.last_seen_t = w.t;
      ++mf.times_matched;
    }
    const SensorSlot& sensor = sensors_[w.sensor];
    for (std::size_t mi = 0; mi < w.measurements.size(); ++mi) {
      if (!w.may_create[mi]) continue;
      const Measurement& m = w.measurements[mi];
      for (int type_index : sensor.feeds) {  // the first fed type that accepts it
        const FeatureTypeSlot& type = types_[type_index];
        std::unique_ptr<Feature> created =
            guarded(type.instance, *type.library, "create", [&] { return type.type->create(m, view); });
        if (!created) continue;
        MapFeature mf;
        mf.id = next_feature_id_++;
        mf.type = type_index;
        mf.feature = type.adopt(std::move(created), mf.id);
        mf.created_step = step_;
        mf.last_seen_step = step_;
        mf.created_path = mf.last_seen_path = mf.seen_since_path = path_distance_;
        mf.last_sensor = w.sensor;
        mf.last_seen_t = w.t;
        guarded(type.instance, *type.library, "add_dense_information",
                [&] { mf.feature->add_dense_information(m, view); });
        if (mf.feature->mspace_dim() != 0)
          throw PluginError(type.instance + " (plugin '" + type.plugin +
                            "'): create() must return a feature of M-space dimension 0");
        if (log_->enabled(LogLevel::Debug))
          log_->debug("step ", step_, ": new tentative ", type.instance, " #", mf.id, " at ",
                      mf.feature->coords().transpose());
        features_.push_back(std::move(mf));
        ++stats_.created;
        break;
      }
    }
  }
}

// ---- Phase 4: extend -------------------------------------------------------

void Slam::extend(const std::vector<int>& touched) {
  // One view per (sensor, reading time): every feature a reading touched
  // shares it, and nothing below changes the robot's pose or covariance (an
  // augmentation adds rows), so it is computed once, not once per feature.
  std::vector<SensorView> views;
  for (int fi : touched) {
    MapFeature& mf = features_[fi];
    const FeatureTypeSlot& type = types_[mf.type];
    const int old_dim = mf.feature->mspace_dim();
    std::optional<Extension> ext;
    // Touched features were observed in this step, so the current pose of
    // the sensor that saw them last is the view of their newest evidence.
    auto known = std::find_if(views.begin(), views.end(), [&](const SensorView& v) {
      return v.sensor == mf.last_sensor && v.t == mf.last_seen_t;
    });
    if (known == views.end()) known = views.insert(views.end(), sensor_view(mf.last_sensor, mf.last_seen_t));
    const SensorView view = *known;
    if (problem_ && old_dim > 0) problem_->before_extend(mf);
    ext = guarded(type.instance, *type.library, "extend", [&] { return mf.feature->extend(view); });
    if (!ext) continue;
    const std::string who = type.instance + " (plugin '" + type.plugin + "')";
    const int n = ext->new_dims;
    if (n <= 0 || mf.feature->mspace_dim() != old_dim + n)
      throw PluginError(who + ": extend() reported " + std::to_string(n) + " new dimensions but the feature went from " +
                        std::to_string(old_dim) + " to " + std::to_string(mf.feature->mspace_dim()));
    if (ext->sensor < 0 || ext->sensor >= static_cast<int>(sensors_.size()))
      throw PluginError(who + ": extend() names sensor " + std::to_string(ext->sensor) + ", which does not exist");
    if (ext->C_new.rows() != n || ext->C_new.cols() != n ||
        (ext->J_sensor.size() > 0 && (ext->J_sensor.rows() != n || ext->J_sensor.cols() != 6)) ||
        (ext->J_own.size() > 0 && (ext->J_own.rows() != n || ext->J_own.cols() != old_dim)))
      throw PluginError(who + ": extend() returned matrices of the wrong size");
    require_finite(ext->C_new, "extension covariance", type.instance, *type.library);
    require_finite(ext->J_sensor, "extension J_sensor", type.instance, *type.library);
    require_finite(ext->J_own, "extension J_own", type.instance, *type.library);

    // δx_new = J_sensor δx_ms + J_own δx_p,old + w with δx_ms = J_sr δx_r (eq. 20).
    StateAugmentation aug;
    aug.C_new = ext->C_new;
    aug.J = Eigen::MatrixXd::Zero(n, 0);
    if (ext->J_sensor.size() > 0) {
      Mat6 J_sr;
      compound(x_r_, sensors_[ext->sensor].config.mount, &J_sr);
      aug.idx = robot_idx_;
      aug.J = ext->J_sensor * columns(J_sr, dofs_);
    }
    if (ext->J_own.size() > 0) {
      aug.idx.insert(aug.idx.end(), mf.state_idx.begin(), mf.state_idx.end());
      Eigen::MatrixXd J(n, aug.J.cols() + old_dim);
      J << aug.J, ext->J_own;
      aug.J = J;
    }
    const int first =
        guarded(config_.estimator.instance, *estimator_lib_, "augment", [&] { return estimator_->augment(aug); });
    if (problem_) problem_->extended(mf, aug, first);
    for (int i = 0; i < n; ++i) mf.own_idx.push_back(first + i);  // new own dims precede shared groups
    rebuild_state_idx(mf);
    ++stats_.extended;
  }
}

void Slam::rebuild_state_idx(MapFeature& mf) const {
  mf.state_idx = mf.own_idx;
  for (const auto& [block, id] : mf.shared) {
    const auto it = std::find_if(shared_.begin(), shared_.end(), [id = id](const SharedCoordinate& c) { return c.id == id; });
    mf.state_idx.insert(mf.state_idx.end(), it->state_idx.begin(), it->state_idx.end());
  }
}

// Removes estimator rows and renumbers every index the kernel keeps.
void Slam::remove_state_rows(std::vector<int> rows) {
  if (rows.empty()) return;
  std::sort(rows.begin(), rows.end());
  guarded(config_.estimator.instance, *estimator_lib_, "remove", [&] { estimator_->remove(rows); });
  if (problem_) problem_->removed(rows);
  const auto renumber = [&](std::vector<int>& idx) {
    for (int& i : idx) i -= static_cast<int>(std::lower_bound(rows.begin(), rows.end(), i) - rows.begin());
  };
  for (SharedCoordinate& c : shared_) renumber(c.state_idx);
  for (MapFeature& mf : features_) {
    renumber(mf.own_idx);
    rebuild_state_idx(mf);
  }
}

// ---- Shared coordinates (T-RO §VI) ------------------------------------------

// After extension, every block of a touched feature that may be shared is
// compared with the blocks of the same kind of the other features in the
// estimator; the first pair closer than join_distance whose features agree on
// a common value becomes one shared coordinate.
void Slam::join_shared_coordinates(const std::vector<int>& touched) {
  const double max_d2 = config_.association.join_distance * config_.association.join_distance;
  for (int a : touched) {
    const Feature& fa = *features_[a].feature;
    if (fa.mspace_dim() == 0) continue;
    const CoordLayout& la = fa.layout();
    for (int ba = 0; ba < la.num_blocks(); ++ba) {
      if (la.kind(ba) == BlockKind::Scalar || features_[a].shared.count(ba) || !fa.can_share(ba)) continue;
      for (std::size_t b = 0; b < features_.size(); ++b) {
        const MapFeature& mb = features_[b];
        if (static_cast<int>(b) == a || mb.feature->mspace_dim() == 0) continue;
        const Feature& fb = *mb.feature;
        const CoordLayout& lb = fb.layout();
        bool joined = false;
        for (int bb = 0; bb < lb.num_blocks() && !joined; ++bb) {
          if (lb.kind(bb) != la.kind(ba) || mb.shared.count(bb) || !fb.can_share(bb)) continue;
          const int size = block_size(la.kind(ba));
          const double d2 =
              (fa.coords().segment(la.offset(ba), size) - fb.coords().segment(lb.offset(bb), size)).squaredNorm();
          if (d2 <= max_d2) joined = try_join(a, ba, static_cast<int>(b), bb);
        }
        if (joined) break;
      }
    }
  }
}

// Joins block ba of feature a with block bb of feature b. The new estimator
// rows are linear in the old ones:
//   shared point  δc   = J_a B̃_a δp_a + J_b B̃_b δp_b   (from the proposal)
//   own dims      δq_a = T_a δp_a,  δq_b = T_b δp_b     (from share_block)
// so they are added with zero extra noise and the old own rows removed.
bool Slam::try_join(int a, int ba, int b, int bb) {
  MapFeature& ma = features_[a];
  MapFeature& mb = features_[b];
  const FeatureTypeSlot& ta = types_[ma.type];
  const FeatureTypeSlot& tb = types_[mb.type];
  const std::optional<JoinProposal> proposal = guarded(ta.instance, *ta.library, "propose_join", [&] {
    return ma.feature->propose_join(ba, *mb.feature, bb);
  });
  if (!proposal) return false;
  const int k = block_size(ma.feature->layout().kind(ba));
  const std::string who = ta.instance + " (plugin '" + ta.plugin + "')";
  if (proposal->value.size() != k || proposal->J_this.rows() != k ||
      proposal->J_this.cols() != ma.feature->layout().size() || proposal->J_other.rows() != k ||
      proposal->J_other.cols() != mb.feature->layout().size())
    throw PluginError(who + ": propose_join returned matrices of the wrong size");
  require_finite(proposal->value, "join value", ta.instance, *ta.library);
  require_finite(proposal->J_this, "join J_this", ta.instance, *ta.library);
  require_finite(proposal->J_other, "join J_other", ta.instance, *ta.library);

  // Everything below is linear in the old perturbations of both features.
  const std::vector<int> old_a = ma.state_idx, old_b = mb.state_idx;
  std::vector<int> idx = old_a;
  for (int i : old_b)
    if (std::find(idx.begin(), idx.end(), i) == idx.end()) idx.push_back(i);
  const auto column = [&](int state_index) {
    return static_cast<Eigen::Index>(std::find(idx.begin(), idx.end(), state_index) - idx.begin());
  };
  Eigen::MatrixXd J_corner = Eigen::MatrixXd::Zero(k, static_cast<Eigen::Index>(idx.size()));
  const Eigen::MatrixXd Ja = proposal->J_this * ma.feature->B_dual();
  const Eigen::MatrixXd Jb = proposal->J_other * mb.feature->B_dual();
  for (std::size_t j = 0; j < old_a.size(); ++j) J_corner.col(column(old_a[j])) += Ja.col(static_cast<Eigen::Index>(j));
  for (std::size_t j = 0; j < old_b.size(); ++j) J_corner.col(column(old_b[j])) += Jb.col(static_cast<Eigen::Index>(j));

  const int old_dim_a = ma.feature->mspace_dim(), old_dim_b = mb.feature->mspace_dim();
  if (problem_) problem_->before_join(ma, mb);
  const Eigen::MatrixXd T_a =
      guarded(ta.instance, *ta.library, "share_block", [&] { return ma.feature->share_block(ba, proposal->value); });
  const Eigen::MatrixXd T_b =
      guarded(tb.instance, *tb.library, "share_block", [&] { return mb.feature->share_block(bb, proposal->value); });
  const auto check = [&](const MapFeature& m, const FeatureTypeSlot& t, const Eigen::MatrixXd& T, int old_dim) {
    int shared_after = k;  // the new shared block plus those shared before
    for (const auto& entry : m.shared) shared_after += block_size(m.feature->layout().kind(entry.first));
    if (T.cols() != old_dim || m.feature->mspace_dim() != T.rows() + shared_after)
      throw PluginError(t.instance + " (plugin '" + t.plugin + "'): share_block returned T of size " +
                        std::to_string(T.rows()) + "x" + std::to_string(T.cols()) + " for a feature of dimension " +
                        std::to_string(old_dim) + " -> " + std::to_string(m.feature->mspace_dim()));
    require_finite(T, "share_block T", t.instance, *t.library);
  };
  check(ma, ta, T_a, old_dim_a);
  check(mb, tb, T_b, old_dim_b);

  auto augment = [&](const std::vector<int>& on, const Eigen::MatrixXd& J) {
    StateAugmentation aug;
    aug.idx = on;
    aug.J = J;
    aug.C_new = Eigen::MatrixXd::Zero(J.rows(), J.rows());
    return guarded(config_.estimator.instance, *estimator_lib_, "augment", [&] { return estimator_->augment(aug); });
  };
  SharedCoordinate corner;
  corner.id = next_shared_id_++;
  corner.kind = ma.feature->layout().kind(ba);
  const int first_corner = augment(idx, J_corner);
  for (int i = 0; i < k; ++i) corner.state_idx.push_back(first_corner + i);
  corner.members = {{ma.id, ba}, {mb.id, bb}};
  std::vector<int> obsolete = ma.own_idx;
  obsolete.insert(obsolete.end(), mb.own_idx.begin(), mb.own_idx.end());
  ma.own_idx.clear();
  mb.own_idx.clear();
  if (T_a.rows() > 0) {
    const int first = augment(old_a, T_a);
    for (int i = 0; i < T_a.rows(); ++i) ma.own_idx.push_back(first + i);
  }
  if (T_b.rows() > 0) {
    const int first = augment(old_b, T_b);
    for (int i = 0; i < T_b.rows(); ++i) mb.own_idx.push_back(first + i);
  }
  ma.shared[ba] = corner.id;
  mb.shared[bb] = corner.id;
  shared_.push_back(corner);
  if (problem_) {  // the join is a change of variables of the problem
    rebuild_state_idx(ma);
    rebuild_state_idx(mb);
    problem_->joined(ma, mb, obsolete);
  }
  remove_state_rows(obsolete);  // also rebuilds every state_idx
  ++stats_.joined;
  log_->debug("step ", step_, ": ", ta.instance, " #", ma.id, " block ", ba, " and ", tb.instance, " #", mb.id,
              " block ", bb, " now share coordinate ", corner.id, " at ", proposal->value.transpose());
  return true;
}

// Tentative features (dimension 0, never in the estimator) that are not seen
// again within tentative_max_age steps were most likely clutter.
void Slam::prune_tentative() {
  const std::int64_t max_age = config_.association.tentative_max_age;
  const auto stale = [&](const MapFeature& mf) {
    return mf.feature->mspace_dim() == 0 && step_ - mf.last_seen_step > max_age;
  };
  const auto before = features_.size();
  features_.erase(std::remove_if(features_.begin(), features_.end(), stale), features_.end());
  stats_.pruned += static_cast<std::int64_t>(before - features_.size());
}

std::vector<StampedPose> Slam::dead_reckoning_evaluated() const {
  if (ground_truth_sensor_ < 0) return dead_reckoning_;
  std::vector<StampedPose> out = dead_reckoning_;
  for (StampedPose& p : out) p.pose = compound(p.pose, sensors_[ground_truth_sensor_].config.mount);
  return out;
}

std::string Slam::odometry_description() const {
  std::string text = "source plugin '" + config_.source.plugin + "'";
  const Params& params = config_.source.params;
  if (params.has("odometry") && std::holds_alternative<std::string>(params.values().at("odometry")))
    text += ", odometry: " + params.get_string("odometry");
  return text;
}

void Slam::record(const DataStep& data) {
  if (trajectory_.capacity() == 0) {
    // Room for the steps the source announces (at most 10 million): the four
    // per-step records then never move while they grow (docs/performance.md,
    // fifth pass: the moves were half of a long run's page faults).
    const std::size_t steps = std::min<std::size_t>(size_hint(), 10'000'000);
    trajectory_.reserve(steps);
    dead_reckoning_.reserve(steps);
    evaluated_.reserve(steps);
    record_path_.reserve(steps);
  }
  trajectory_.push_back({data.t, x_r_, kAllPoseCoords});
  dead_reckoning_.push_back({data.t, dead_reckoning_pose_, kAllPoseCoords});
  record_path_.push_back(path_distance_);
  // The frame the ground truth refers to: the robot, or a sensor on it
  // (e.g. a GPS antenna mounted with the laser), x_r ⊕ x_rs (eq. 17).
  Mat6 J_sr = Mat6::Identity();
  Pose6 x_eval = x_r_;
  if (ground_truth_sensor_ >= 0) x_eval = compound(x_r_, sensors_[ground_truth_sensor_].config.mount, &J_sr);
  evaluated_.push_back({data.t, x_eval, kAllPoseCoords});
  if (!data.ground_truth) return;
  ground_truth_.push_back({data.t, *data.ground_truth, data.ground_truth_known});
  if (pose_search_) return;  // the pose is in the run's own frame until it is found in the map

  // NEES over the coordinates the ground truth knows and the filter estimates.
  const Eigen::MatrixXd J = columns(J_sr, dofs_);
  const Eigen::MatrixXd P6 = J * checked_marginal(robot_idx_) * J.transpose();
  std::vector<int> rows;
  for (int i = 0; i < 6; ++i)
    if ((data.ground_truth_known & (1u << i)) && P6(i, i) > 0.0) rows.push_back(i);
  if (rows.empty()) return;
  const Pose6 err = pose_difference(x_eval, *data.ground_truth);
  Eigen::VectorXd e(static_cast<Eigen::Index>(rows.size()));
  Eigen::MatrixXd P(e.size(), e.size());
  for (std::size_t i = 0; i < rows.size(); ++i) {
    e[static_cast<Eigen::Index>(i)] = err[rows[i]];
    for (std::size_t j = 0; j < rows.size(); ++j)
      P(static_cast<Eigen::Index>(i), static_cast<Eigen::Index>(j)) = P6(rows[i], rows[j]);
  }
  const Eigen::LDLT<Eigen::MatrixXd> ldlt(P);
  if (ldlt.info() == Eigen::Success && (ldlt.vectorD().array() > 0.0).all()) {
    stats_.nees.push_back(e.dot(ldlt.solve(e)));
    stats_.nees_dof = static_cast<int>(rows.size());
  }
}

}  // namespace mspace::kernel
