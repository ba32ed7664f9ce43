// carmen_log.cpp — see carmen_log.hpp.
#include "carmen_log.hpp"

#include <algorithm>
#include <cmath>
#include <fstream>
#include <numbers>
#include <optional>
#include <sstream>
#include <stdexcept>

#include "mspace/pose.hpp"
#include "mspace/records.hpp"
#include "scan_matcher.hpp"
#include "wheel_check.hpp"

namespace mspace::carmen_log {
namespace {

Pose6 to_pose6(const Pose2& p) { return make_pose2d(p[0], p[1], p[2]); }

ReaderOptions options_from(const Params& params) {
  ReaderOptions o;
  const std::string& format = params.get_string("format");
  o.format = format == "table" ? Format::Table : format == "carmen" ? Format::Carmen : Format::Auto;
  const std::string& variant = params.get_string("variant");
  o.variant = variant == "clf" ? Variant::Clf : variant == "gmapping" ? Variant::GMapping : Variant::Auto;
  o.no_return_range = params.get_double("no_return_range");
  const std::vector<double>& offset = params.get_list("laser_offset");
  if (offset.size() == 3) o.laser_offset = Eigen::Vector3d(offset[0], offset[1], offset[2] * std::numbers::pi / 180.0);
  else if (!offset.empty())
    throw std::invalid_argument("laser_offset must be empty (from the log) or [x, y, theta_deg], got " +
                                std::to_string(offset.size()) + " values");
  o.flaser_fov = params.get_double("flaser_fov_deg") * std::numbers::pi / 180.0;
  o.time_offset = params.get_double("time_offset");
  o.skip_malformed = params.get_string("on_malformed") == "skip";
  return o;
}

/// Pose b expressed by pose a and an increment (dx, dy, dθ) in a's frame.
Pose2 apply_increment(const Pose2& a, const Eigen::Vector3d& d) {
  const double c = std::cos(a[2]), s = std::sin(a[2]);
  return {a[0] + c * d[0] - s * d[1], a[1] + s * d[0] + c * d[1], std::remainder(a[2] + d[2], 2.0 * std::numbers::pi)};
}

struct TumPose {
  double t = 0.0;
  Pose2 pose = Pose2::Zero();
};

/// Reads a TUM trajectory `t x y z qx qy qz qw` (planar: x, y and the yaw of
/// the quaternion); '#' lines and empty lines are skipped. Throws
/// "file:line: problem" for a malformed line or time stamps that go backwards.
std::vector<TumPose> read_tum(const std::string& file, double time_offset) {
  std::ifstream in(file);
  if (!in) throw std::runtime_error(file + ": cannot open the ground-truth file");
  std::vector<TumPose> poses;
  std::string line;
  for (int line_no = 1; std::getline(in, line); ++line_no) {
    const auto first = line.find_first_not_of(" \t\r");
    if (first == std::string::npos || line[first] == '#') continue;
    std::istringstream fields(line);
    double t, x, y, z, qx, qy, qz, qw;
    std::string extra;
    const std::string where = file + ":" + std::to_string(line_no) + ": ";
    if (!(fields >> t >> x >> y >> z >> qx >> qy >> qz >> qw) || (fields >> extra) ||
        !std::isfinite(t + x + y + z + qx + qy + qz + qw))
      throw std::runtime_error(where + "expected 8 finite numbers `t x y z qx qy qz qw` (TUM)");
    const double norm = std::sqrt(qx * qx + qy * qy + qz * qz + qw * qw);
    if (std::abs(norm - 1.0) > 1e-3) throw std::runtime_error(where + "the quaternion is not of unit length");
    if (!poses.empty() && t + time_offset < poses.back().t)
      throw std::runtime_error(where + "time stamps go backwards");
    if (!poses.empty() && t + time_offset == poses.back().t)
      throw std::runtime_error(where + "the time stamp repeats the previous pose's");
    // Yaw of the rotation (the z-y-x Euler angle about z).
    const double yaw = std::atan2(2.0 * (qw * qz + qx * qy), 1.0 - 2.0 * (qy * qy + qz * qz));
    poses.push_back({t + time_offset, Pose2(x, y, yaw)});
  }
  if (poses.empty()) throw std::runtime_error(file + ": no poses in the ground-truth file");
  return poses;
}

/// The pose at time t, linear between the two poses around it (angle along
/// the shorter way) when they are at most max_gap apart; none otherwise.
std::optional<Pose2> pose_at(const std::vector<TumPose>& poses, double t, double max_gap) {
  const auto later =
      std::lower_bound(poses.begin(), poses.end(), t, [](const TumPose& p, double value) { return p.t < value; });
  if (later == poses.end()) return std::nullopt;
  if (later->t == t) return later->pose;
  if (later == poses.begin()) return std::nullopt;
  const TumPose& a = *std::prev(later);
  const TumPose& b = *later;
  if (b.t - a.t > max_gap) return std::nullopt;
  const double u = (t - a.t) / (b.t - a.t);
  Pose2 p = a.pose + u * (b.pose - a.pose);
  p[2] = std::remainder(a.pose[2] + u * std::remainder(b.pose[2] - a.pose[2], 2.0 * std::numbers::pi),
                        2.0 * std::numbers::pi);
  return p;
}

}  // namespace

/// Replaces every scan's ground truth by the poses of a TUM file at the scan
/// times (see the `ground_truth` parameter).
void CarmenLogSource::ground_truth_from_file(const Params& params, const std::string& file, Logger& log) {
  const std::vector<TumPose> poses = read_tum(file, params.get_double("time_offset"));
  const double max_gap = params.get_double("ground_truth_max_gap");
  std::size_t with = 0;
  for (Scan& scan : log_.scans) {
    scan.ground_truth = pose_at(poses, scan.t, max_gap);
    if (scan.ground_truth) ++with;
  }
  log.info("ground truth from ", file, ": ", poses.size(), " poses, ", with, " of ", log_.scans.size(),
           " scans lie between two of them at most ", max_gap, " s apart");
  if (with == 0)
    throw std::runtime_error(file + ": no scan time of " + file_ +
                             " lies between two ground-truth poses (wrong file or time base?)");
}

/// Replaces every scan's odometry pose by laser odometry: the increment from
/// the previous scan is the scan match of the two scans for the laser at
/// mount_ on the robot (LaserOdometry: robot motion x_rs ⊕ d_laser ⊖ x_rs),
/// seeded with the wheel-odometry increment, which is kept where the match
/// fails. Matched increments keep the match's covariance for DataStep.
void CarmenLogSource::scan_match_odometry(const Params& params, Logger& log) {
  scan_matching::MatchOptions options;
  options.max_correspondence = params.get_double("scan_match_max_correspondence");
  options.seed_sigma_xy = params.get_double("scan_match_seed_sigma_xy");
  options.seed_sigma_theta = params.get_double("scan_match_seed_sigma_theta_deg") * std::numbers::pi / 180.0;
  options.seed_gate = params.get_double("scan_match_seed_gate");
  options.free_space_margin = params.get_double("scan_match_free_space_margin");
  options.local_map_weight = params.get_double("scan_match_local_map_weight");
  const bool drop_moving = params.get_bool("scan_match_drop_moving");
  const bool with_covariance = params.get_bool("scan_match_covariance");
  const double limit = params.get_double("scan_match_max_range");
  const double max_range = limit > 0.0 ? std::min(limit, log_.laser.no_return) : log_.laser.no_return;
  const scan_matching::LaserOdometry odometry(mount_, options);
  scan_matching::LocalMapOptions local_options;
  local_options.scans = static_cast<int>(params.get_int("scan_match_local_map"));
  local_options.key_distance = params.get_double("scan_match_key_distance");
  scan_matching::LocalMap local_map(odometry, local_options);
  std::vector<double> residuals;
  std::size_t correlative = 0, disagreed = 0;
  Eigen::Vector3d previous_increment = Eigen::Vector3d::Zero();  // robot motion from scan i − 2 to i − 1
  const std::size_t n = log_.scans.size();
  std::vector<Pose2> matched(n);
  std::vector<Eigen::Vector3d> wheel(n, Eigen::Vector3d::Zero()), laser(n, Eigen::Vector3d::Zero());
  std::vector<scan_matching::IncrementSource> source(n, scan_matching::IncrementSource::failed);
  std::vector<double> times(n);
  for (std::size_t i = 0; i < n; ++i) times[i] = log_.scans[i].t;
  scan_matching::WheelCheckOptions check_options;
  check_options.gate = params.get_double("scan_match_wheel_gate");
  check_options.gap_factor = params.get_double("scan_match_gap_factor");
  const std::vector<bool> gaps = scan_matching::logging_gaps(times, check_options.gap_factor);
  covariances_.assign(n, Eigen::Matrix3d::Zero());
  std::vector<Eigen::Matrix3d> match_covariance(n, Eigen::Matrix3d::Zero());  // per scan i: of the match to it
  matched[0] = log_.scans[0].odometry;
  auto points_of = [&](const Scan& s) { return scan_matching::scan_to_points(s.ranges, s.bearings, max_range); };
  local_map.add(0, points_of(log_.scans[0]), matched[0]);
  for (std::size_t i = 1; i < n; ++i) {
    const Scan& previous = log_.scans[i - 1];
    const Scan& current = log_.scans[i];
    const Eigen::Vector3d seed = odometry_increment(previous.odometry, current.odometry);
    wheel[i] = laser[i] = seed;
    if (gaps[i]) {  // scans too far apart in time: the wheels, and the local map starts again
      source[i] = scan_matching::IncrementSource::gap;
      previous_increment = seed;
      matched[i] = apply_increment(matched[i - 1], seed);
      local_map.clear();
      local_map.add(i, points_of(current), matched[i]);
      log.debug("scan ", i, " (", file_, ":", current.line, "): ", times[i] - times[i - 1],
                " s after the previous scan (a logging gap): wheel odometry kept");
      continue;
    }
    // The previous scan as the reference; with scan_match_drop_moving, its
    // points that the scan before it did not see there (things that moved)
    // are dropped, the increment between the two being the one just matched.
    const scan_matching::ReferenceScan reference =
        drop_moving && i >= 2 && !gaps[i - 1]
            ? odometry.reference(points_of(previous), points_of(log_.scans[i - 2]), previous_increment)
            : scan_matching::ReferenceScan(points_of(previous), options);
    // With scan_match_local_map, the last key scans join the match (placed
    // by the laser odometry so far); a failed match breaks that chain.
    const scan_matching::ScanPoints current_points = points_of(current);
    const scan_matching::OdometryResult r =
        odometry.match(reference, current_points, seed, local_map.placed(i - 1, matched[i - 1]));
    previous_increment = laser[i] = r.increment;
    matched[i] = apply_increment(matched[i - 1], r.increment);
    if (r.match.ok) local_map.add(i, current_points, matched[i]);
    else local_map.clear();
    disagreed += r.match.disagreed ? 1 : 0;
    if (r.match.ok) {
      source[i] = scan_matching::IncrementSource::matched;
      residuals.push_back(r.match.rms);
      match_covariance[i] = r.covariance;
      if (with_covariance) covariances_[i] = r.covariance;
      correlative += r.match.correlative ? 1 : 0;
    } else {
      log.debug("scan ", i, " (", file_, ":", current.line, "): scan match failed (", r.match.pairs, " pairs of ",
                r.match.overlap, " overlapping points, rms ", r.match.rms, " m); wheel odometry kept");
    }
  }
  // The wheels' veto (wheel_check.hpp): matches they contradict beyond
  // their spread, as measured on this log, fall back to the wheels.
  // Per increment from here: entry i − 1 is the increment to scan i.
  wheel.erase(wheel.begin());
  laser.erase(laser.begin());
  source.erase(source.begin());
  wheel_check_ = scan_matching::check_against_wheels(wheel, laser, source, check_options);
  const scan_matching::WheelCheckResult& check = wheel_check_;
  // The increments that fall back to the wheels are not laser odometry: the
  // motion noise configured for it does not describe them. With
  // scan_match_wheel_model they are corrected for the wheels' scale, turn
  // scale and drift, and carry the wheels' own noise, both measured against
  // the matched increments of this log (WheelModel), sub-step by sub-step
  // along the odometry logged between the two scans. Across a logging gap
  // with no odometry logged inside, the path is unknown: the net increment
  // is kept as the wheels gave it, its path taken as at least the median
  // speed times the gap's duration, and the drift that path may have caused
  // added to the heading's variance.
  const bool use_model = params.get_bool("scan_match_wheel_model");
  std::vector<std::vector<Eigen::Vector3d>> wheel_steps(n);  // per increment to scan i: the wheels' sub-steps
  for (std::size_t i = 1; i < n; ++i) {
    Pose2 from = log_.scans[i - 1].odometry;
    for (const Pose2& p : log_.scans[i].odometry_between) {
      wheel_steps[i].push_back(odometry_increment(from, p));
      from = p;
    }
    wheel_steps[i].push_back(odometry_increment(from, log_.scans[i].odometry));
  }
  if (use_model) wheel_model_ = scan_matching::fit_wheel_model(wheel, laser, check, check_options);
  const scan_matching::WheelModel& model = wheel_model_;
  double speed = 0.0;  // median path per second while moving (m/s)
  {
    std::vector<double> speeds;
    for (std::size_t i = 1; i < n; ++i) {
      const double dt = times[i] - times[i - 1], path = model.path_of(wheel[i - 1]);
      if (!gaps[i] && dt > 0.0 && path > 0.01) speeds.push_back(path / dt);
    }
    if (!speeds.empty()) {
      std::nth_element(speeds.begin(), speeds.begin() + static_cast<long>(speeds.size() / 2), speeds.end());
      speed = speeds[speeds.size() / 2];
    }
  }
  // With scan_match_fuse_wheels, a match the wheels contradict is not thrown
  // away when the two agree within both their covariances (the veto's spread
  // is the same in every direction; a match along a corridor is weak along
  // it and strong across): it is combined with the corrected wheels
  // (combine_increments; the match's covariance is its own, calibrated to
  // NEES 3, the wheels' the wheel model's).
  fuse_wheels_ = params.get_bool("scan_match_fuse_wheels");
  const bool fuse = fuse_wheels_ && model.used > 0;
  for (std::size_t i = 1; i < n; ++i) {
    const bool kept = check.source[i - 1] == scan_matching::IncrementSource::matched;
    Eigen::Vector3d increment = laser[i - 1];
    if (!kept) {
      covariances_[i].setZero();
      increment = wheel[i - 1];
      std::optional<scan_matching::CombinedIncrement> combined;
      if (fuse && check.source[i - 1] == scan_matching::IncrementSource::inconsistent && !match_covariance[i].isZero())
        combined = scan_matching::combine_increments(model.correct_along(wheel_steps[i]),
                                                     model.covariance_along(wheel_steps[i]), laser[i - 1],
                                                     match_covariance[i], check_options.gate);
      if (combined) {
        increment = combined->increment;
        covariances_[i] = combined->covariance;
        wheel_check_.source[i - 1] = scan_matching::IncrementSource::fused;
      } else if (model.used > 0 && (!gaps[i] || wheel_steps[i].size() > 1)) {
        increment = model.correct_along(wheel_steps[i]);
        covariances_[i] = model.covariance_along(wheel_steps[i]);
      } else if (model.used > 0) {
        const double path = std::max(model.path_of(increment), speed * (times[i] - times[i - 1]));
        covariances_[i] = model.covariance(increment, path);
        covariances_[i](2, 2) +=
            std::pow((std::abs(model.bias_per_m) + std::sqrt(model.parameter_covariance(2, 2))) * path, 2);
      }
    }
    if (gaps[i] && !covariances_[i].isZero())
      log.debug("scan ", i, " (", file_, ":", log_.scans[i].line, "): across the logging gap the wheel increment ",
                increment.transpose(), " carries sigma ", std::sqrt(covariances_[i](0, 0)), " m, ",
                std::sqrt(covariances_[i](1, 1)), " m, ", std::sqrt(covariances_[i](2, 2)) * 180.0 / std::numbers::pi,
                " deg (", wheel_steps[i].size(), " wheel steps)");
    if (check.source[i - 1] == scan_matching::IncrementSource::inconsistent)
      log.debug("scan ", i, " (", file_, ":", log_.scans[i].line, "): scan match ", laser[i - 1].transpose(),
                " contradicts the wheel odometry ", wheel[i - 1].transpose(), " (chi2 ", check.chi2[i - 1],
                "): wheel odometry kept");
    log_.scans[i].odometry = apply_increment(log_.scans[i - 1].odometry, increment);
  }
  if (model.used > 0)
    log.info("wheel odometry measured against ", model.used, " matched increments: scale ", 100.0 * model.scale,
             " %, turn scale ", 100.0 * model.turn_scale, " %, drift ", model.bias_per_m * 180.0 / std::numbers::pi,
             " deg/m, spread after correction ", model.sigma_xy * 1000.0, " mm and ",
             model.sigma_theta * 180.0 / std::numbers::pi,
             " deg per sqrt(m); the increments that fall back to the wheels are corrected and carry that noise");
  else if (use_model)
    log.warn("laser odometry: fewer than 20 matched increments to measure the wheel odometry against; the "
             "increments that fall back to the wheels keep the motion model's noise");
  double median = 0.0;
  if (!residuals.empty()) {
    std::nth_element(residuals.begin(), residuals.begin() + static_cast<long>(residuals.size() / 2), residuals.end());
    median = residuals[residuals.size() / 2];
  }
  using scan_matching::IncrementSource;
  const std::size_t kept = check.count(IncrementSource::matched), failed = check.count(IncrementSource::failed),
                    gap = check.count(IncrementSource::gap), inconsistent = check.count(IncrementSource::inconsistent);
  const std::size_t fused = check.count(IncrementSource::fused);
  log.info("laser odometry: ", kept + fused, " of ", n - 1, " increments scan-matched (median residual ",
           median * 1000.0, " mm, ", correlative, " after a correlative search, ", disagreed,
           " replaced by a tight match from the wheels",
           fuse ? ", " + std::to_string(fused) + " combined with the wheels by their covariances" : std::string(),
           "); the wheel odometry kept for ", failed, " failed matches, ", gap,
           " increments across logging gaps and ", inconsistent,
           " matches the wheels contradict (spread measured on this log: ", check.sigma_xy * 1000.0, " mm and ",
           check.sigma_theta * 180.0 / std::numbers::pi, " deg per sqrt(m), gate chi2 ", check_options.gate, ")");
  if ((failed + inconsistent) * 20 > n)
    log.warn("laser odometry: ", failed + inconsistent, " of ", n - 1,
             " increments fell back to the wheel odometry (more than 5 %): check no_return_range, laser_offset and "
             "scan_match_max_range");
}

std::vector<ParamSpec> CarmenLogSource::param_specs() {
  return {
      required(param_string("file", "",
                            "the log: a CARMEN log (CLF or GMapping-written) or the Intel merged table, e.g. "
                            "${MSPACE_DATA:-../shared/datasets}/intel_lab/intel_910_scans.txt")),
      param_string("format", "auto", "file format (auto: a table if the first data line starts with a number)",
                   {"auto", "table", "carmen"}),
      param_string("variant", "auto",
                   "CARMEN log flavour: clf (raw odometry in FLASER), gmapping (FLASER pose = corrected pose, "
                   "odometry from ODOM lines); auto = gmapping when the log has NEFF lines",
                   {"auto", "clf", "gmapping"}),
      param_string("channel", "laser", "channel of the laser readings"),
      param_double("no_return_range", 0.0,
                   "ranges at or beyond this (m) mean no return; 0: from the log (the value many ranges have "
                   "exactly with nothing above, else PARAM robot_front_laser_max, else the ROBOTLASER1 maximum "
                   "range). A value the data contradicts is a warning, or an error when >= 5 % of the ranges sit "
                   "exactly at one value below it",
                   0.0),
      param_list("laser_offset", {},
                 "the laser's pose on the robot [x, y, theta_deg] for laser odometry; empty: from the log "
                 "(ROBOTLASER1 laser vs robot pose, else PARAM robot_frontlaser_*offset), else zero. The log's "
                 "offset is reported as the recorded mount of `channel`, so sensors.<name>.mount must agree"),
      param_double("flaser_fov_deg", 180.0, "field of view of FLASER scans (deg)", 1.0, 360.0),
      param_double("time_offset", 0.0, "added to every time stamp (s), e.g. 976052857.337 for intel.gfs.log"),
      records::on_malformed_param(),
      param_string("odometry", "wheel",
                   "the odometry increments: the log's wheel odometry, or laser odometry (point-to-line ICP "
                   "between consecutive scans, seeded with the wheel odometry, which is kept where a match fails; "
                   "with scan_match_covariance each matched increment carries its covariance)",
                   {"wheel", "scan_matched"}),
      param_double("scan_match_max_range", 0.0,
                   "beams at or beyond this range (m) are not used by the scan matcher (0: every return)", 0.0),
      param_double("scan_match_max_correspondence", 0.5,
                   "largest distance (m) between paired points in the first ICP iteration (it shrinks to 0.1 m): "
                   "at least the wheel odometry's error between two scans",
                   0.05, 5.0),
      param_double("scan_match_seed_sigma_xy", 0.1,
                   "the wheel odometry's translation error per scan (m, 1 σ): the scan matcher's prior on the seed "
                   "(0.1 m: a weak prior, for poor odometry) and the scale of scan_match_seed_gate",
                   1e-4),
      param_double("scan_match_seed_sigma_theta_deg", 5.73,
                   "the wheel odometry's heading error per scan (deg, 1 σ), as scan_match_seed_sigma_xy", 1e-3),
      param_double("scan_match_seed_gate", 0.0,
                   "χ² bound (3 dof) on a match's difference from the seed in units of the seed sigmas: a match "
                   "further from the wheel odometry (pulled by something moving) is replaced by a tight match from "
                   "the seed, or by the seed (16.27: 0.1 %); 0: no check. Only with seed sigmas the odometry meets",
                   0.0),
      param_bool("scan_match_drop_moving", false,
                 "drop points of the reference scan that the scan before it did not see there (moving people, "
                 "doors) before matching the next scan to it"),
      param_int("scan_match_local_map", 0,
                "key scans of the laser odometry's local map that each scan is matched against besides the "
                "previous one (0: the previous scan alone); a scan becomes a key scan "
                "scan_match_key_distance m (or 20 deg) from the last, keys over 5 m away are left out",
                0, 50),
      param_double("scan_match_key_distance", 0.5, "m between key scans of scan_match_local_map", 0.0),
      param_double("scan_match_local_map_weight", 1.0,
                   "weight of a key scan's residuals against the previous scan's (the keys are placed by the "
                   "laser odometry so far, whose error they carry)",
                   0.0, 1.0),
      param_bool("scan_match_covariance", false,
                 "hand each matched increment's covariance (from the match's information and residual, calibrated "
                 "to NEES 3 on simulated buildings) to the run in DataStep::odometry_covariance, where it replaces "
                 "the motion model's noise; false: the motion model's noise for every increment"),
      param_double("scan_match_wheel_gate", 25.90,
                   "chi2 bound (3 dof) on a match's difference from the wheel odometry, in units of the spread "
                   "of that difference measured on the whole log (robust, per sqrt(m) of path): a match beyond "
                   "it falls back to the wheels and is counted (25.90: 1e-5 for a Gaussian); 0: no check",
                   0.0),
      param_bool("scan_match_fuse_wheels", false,
                 "a match the wheels contradict (scan_match_wheel_gate) is combined with the corrected wheel "
                 "increment by their covariances (the match's and the wheel model's) when the two agree within "
                 "them — a match weak along a corridor keeps what it measured across — instead of being dropped; "
                 "needs scan_match_wheel_model"),
      param_bool("scan_match_wheel_model", true,
                 "increments that fall back to the wheels (failed or vetoed matches, logging gaps) are corrected "
                 "for the wheels' scale, turn scale and drift per metre and carry the wheels' own noise (a random "
                 "walk over the path; across a gap the path is at least the median speed times its duration), all "
                 "measured against this log's matched increments; false: the raw wheel increments with the motion "
                 "model's noise"),
      param_double("scan_match_gap_factor", 10.0,
                   "an increment spanning more than this many times the log's median time between scans "
                   "crosses a logging gap: not matched, the wheel odometry kept and counted; 0: no gap check",
                   0.0),
      param_double("scan_match_free_space_margin", 0.0,
                   "points of the current scan that the previous or a key scan saw through, its beams ending more "
                   "than this (m) beyond them, are taken to be moving and left out of the match (0: off)",
                   0.0),
      param_string("ground_truth", "log",
                   "ground truth: `log` = the corrected poses of the log when it has them (table, GMapping log), "
                   "`none`, or a TUM file `t x y z qx qy qz qw` (time base of the log, time_offset added) whose "
                   "poses are interpolated at the scan times (true/false: log/none)"),
      param_double("ground_truth_max_gap", 0.5,
                   "a scan gets ground truth from the TUM file only between two poses at most this far apart (s)",
                   0.0),
      param_string("initial_pose", "ground_truth",
                   "start at the first scan's ground truth (else its odometry), its odometry pose, or zero",
                   {"ground_truth", "odometry", "zero"}),
  };
}

CarmenLogSource::CarmenLogSource(const PluginArgs& args)
    : CarmenLogSource(args, read_log(args.params.get_string("file"), options_from(args.params))) {}

CarmenLogSource::CarmenLogSource(const PluginArgs& args, LogContents contents)
    : file_(args.params.get_string("file")),
      log_(std::move(contents)),
      channel_(args.params.get_string("channel")),
      log_out_(args.logger) {
  const std::string& ground_truth = args.params.get_string("ground_truth");
  use_ground_truth_ = ground_truth != "none" && ground_truth != "false";
  Logger& log = args.log();
  if (log_.scans.empty()) throw std::runtime_error(args.params.get_string("file") + ": no laser scans in the file");
  if (log_.skipped > 0)
    log.warn("skipped ", log_.skipped, " malformed line(s); the first: ", log_.first_problem);
  if (log_.format == Format::Carmen && log_.variant == Variant::GMapping)
    log.warn("GMapping-written log: odometry comes from its ODOM lines, which GMapping re-anchored (not raw odometry)");
  log.info("read ", log_.scans.size(), " scans from ", args.params.get_string("file"), "; no return at ",
           log_.laser.no_return, " m (", log_.laser.no_return_origin, ")");
  for (const std::string& w : log_.laser.warnings) log.warn(w);
  if (!log_.laser.error_codes.empty())
    log.info(log_.laser.error_code_ranges, " ranges at ", log_.laser.error_codes.size(),
             " error code value(s) just below the no-return value read as no return");
  const ReaderOptions reader = options_from(args.params);
  if (reader.laser_offset) {
    mount_ = *reader.laser_offset;
  } else if (log_.laser.offset) {
    mount_ = *log_.laser.offset;
    log.info("laser offset on the robot ", mount_.transpose(), " (", log_.laser.offset_origin, ")");
  }
  if (use_ground_truth_ && ground_truth != "log" && ground_truth != "true")
    ground_truth_from_file(args.params, ground_truth, log);
  if (args.params.get_string("odometry") == "scan_matched") scan_match_odometry(args.params, log);

  const Scan& first = log_.scans.front();
  const std::string& start = args.params.get_string("initial_pose");
  if (start == "ground_truth" && first.ground_truth) initial_pose_ = to_pose6(*first.ground_truth);
  else if (start != "zero") initial_pose_ = to_pose6(first.odometry);
}

bool CarmenLogSource::next(DataStep& step) {
  if (next_ >= log_.scans.size()) {
    if (log_.skipped > 0 && log_out_ != nullptr)
      log_out_->warn("end of data: ", log_.skipped, " malformed line(s) were skipped");
    return false;
  }
  const Scan& scan = log_.scans[next_];
  step = DataStep{};
  step.t = scan.t;
  if (next_ > 0) {
    step.odometry = odometry_increment(log_.scans[next_ - 1].odometry, scan.odometry);
    if (next_ < covariances_.size() && !covariances_[next_].isZero()) step.odometry_covariance = covariances_[next_];
  }
  if (use_ground_truth_ && scan.ground_truth) step.ground_truth = to_pose6(*scan.ground_truth);

  SensorReading reading;
  reading.channel = channel_;
  reading.t = scan.t;
  reading.values.resize(static_cast<Eigen::Index>(scan.ranges.size()), 2);
  for (std::size_t i = 0; i < scan.ranges.size(); ++i) {
    reading.values(static_cast<Eigen::Index>(i), 0) = scan.ranges[i];
    reading.values(static_cast<Eigen::Index>(i), 1) = scan.bearings[i];
  }
  step.readings.push_back(std::move(reading));
  ++next_;
  return true;
}

}  // namespace mspace::carmen_log

namespace mspace::carmen_log {

std::vector<std::pair<std::string, double>> CarmenLogSource::figures() const {
  if (wheel_check_.source.empty()) return {};
  using scan_matching::IncrementSource;
  std::vector<std::pair<std::string, double>> out;
  out.emplace_back("laser_odometry_increments", static_cast<double>(wheel_check_.source.size()));
  for (const IncrementSource s :
       {IncrementSource::matched, IncrementSource::failed, IncrementSource::gap, IncrementSource::inconsistent})
    out.emplace_back(std::string("laser_odometry_") + scan_matching::to_string(s),
                     static_cast<double>(wheel_check_.count(s)));
  if (fuse_wheels_) out.emplace_back("laser_odometry_fused", static_cast<double>(wheel_check_.count(IncrementSource::fused)));
  out.emplace_back("laser_odometry_wheel_spread_m_per_sqrt_m", wheel_check_.sigma_xy);
  out.emplace_back("laser_odometry_wheel_spread_deg_per_sqrt_m", wheel_check_.sigma_theta * 180.0 / std::numbers::pi);
  if (wheel_model_.used > 0) {
    out.emplace_back("wheel_scale_error", wheel_model_.scale);
    out.emplace_back("wheel_turn_scale_error", wheel_model_.turn_scale);
    out.emplace_back("wheel_drift_deg_per_m", wheel_model_.bias_per_m * 180.0 / std::numbers::pi);
  }
  return out;
}

std::vector<RecordedMount> CarmenLogSource::recorded_mounts() const {
  if (!log_.laser.offset) return {};
  const Pose2& o = *log_.laser.offset;
  return {RecordedMount{channel_, make_pose2d(o[0], o[1], o[2]), log_.laser.offset_origin}};
}

}  // namespace mspace::carmen_log
