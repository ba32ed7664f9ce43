// carmen_log.cpp — see carmen_log.hpp.
#include "carmen_log.hpp"

#include <algorithm>
#include <numbers>
#include <stdexcept>

#include "mspace/pose.hpp"
#include "scan_matcher.hpp"

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

}  // namespace

/// Replaces every scan's odometry pose by laser odometry: the increment from
/// the previous scan is the point-to-line ICP match of the two scans, seeded
/// with the wheel-odometry increment (which is kept where the match fails).
void CarmenLogSource::scan_match_odometry(const Params& params, Logger& log) {
  scan_matching::MatchOptions options;
  options.max_correspondence = params.get_double("scan_match_max_correspondence");
  const double max_range = params.get_double("scan_match_max_range");
  std::vector<double> residuals;
  std::size_t kept_seed = 0;
  std::vector<Pose2> matched(log_.scans.size());
  matched[0] = log_.scans[0].odometry;
  auto points_of = [&](const Scan& s) { return scan_matching::scan_to_points(s.ranges, s.bearings, max_range); };
  for (std::size_t i = 1; i < log_.scans.size(); ++i) {
    const Scan& previous = log_.scans[i - 1];
    const Scan& current = log_.scans[i];
    const Eigen::Vector3d seed = odometry_increment(previous.odometry, current.odometry);
    const scan_matching::ReferenceScan reference(points_of(previous), options);
    const scan_matching::MatchResult m = reference.match(points_of(current), seed);
    if (m.ok) {
      residuals.push_back(m.rms);
    } else {
      ++kept_seed;
      log.debug("scan ", i, " (", file_, ":", current.line, "): scan match failed (", m.pairs,
                " pairs, rms ", m.rms, " m); wheel odometry kept");
    }
    matched[i] = apply_increment(matched[i - 1], m.ok ? m.increment : seed);
  }
  for (std::size_t i = 0; i < log_.scans.size(); ++i) log_.scans[i].odometry = matched[i];
  double median = 0.0;
  if (!residuals.empty()) {
    std::nth_element(residuals.begin(), residuals.begin() + static_cast<long>(residuals.size() / 2), residuals.end());
    median = residuals[residuals.size() / 2];
  }
  log.info("laser odometry: ", residuals.size(), " of ", log_.scans.size() - 1,
           " increments scan-matched (median residual ", median * 1000.0, " mm), ", kept_seed,
           " kept the wheel odometry");
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
      param_double("no_return_range", 81.0, "ranges at or beyond this (m) mean no return", 0.0),
      param_double("flaser_fov_deg", 180.0, "field of view of FLASER scans (deg)", 1.0, 360.0),
      param_double("time_offset", 0.0, "added to every time stamp (s), e.g. 976052857.337 for intel.gfs.log"),
      param_string("on_malformed", "error",
                   "a malformed line is an error naming file and line, or is skipped, logged and counted",
                   {"error", "skip"}),
      param_string("odometry", "wheel",
                   "the odometry increments: the log's wheel odometry, or laser odometry (point-to-line ICP "
                   "between consecutive scans, seeded with the wheel odometry, which is kept where a match fails)",
                   {"wheel", "scan_matched"}),
      param_double("scan_match_max_range", 30.0, "beams at or beyond this range (m) are not used by the scan matcher",
                   1.0),
      param_double("scan_match_max_correspondence", 0.5,
                   "largest distance (m) between paired points in the first ICP iteration (it shrinks to 0.1 m): "
                   "at least the wheel odometry's error between two scans",
                   0.05, 5.0),
      param_bool("ground_truth", true, "deliver the corrected poses as ground truth when the file has them"),
      param_string("initial_pose", "ground_truth",
                   "start at the first scan's ground truth (else its odometry), its odometry pose, or zero",
                   {"ground_truth", "odometry", "zero"}),
  };
}

CarmenLogSource::CarmenLogSource(const PluginArgs& args)
    : file_(args.params.get_string("file")),
      channel_(args.params.get_string("channel")),
      use_ground_truth_(args.params.get_bool("ground_truth")),
      log_out_(args.logger) {
  Logger& log = args.log();
  log_ = read_log(args.params.get_string("file"), options_from(args.params));
  if (log_.scans.empty()) throw std::runtime_error(args.params.get_string("file") + ": no laser scans in the file");
  if (log_.skipped > 0)
    log.warn("skipped ", log_.skipped, " malformed line(s); the first: ", log_.first_problem);
  if (log_.format == Format::Carmen && log_.variant == Variant::GMapping)
    log.warn("GMapping-written log: odometry comes from its ODOM lines, which GMapping re-anchored (not raw odometry)");
  log.info("read ", log_.scans.size(), " scans from ", args.params.get_string("file"));
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
  if (next_ > 0) step.odometry = odometry_increment(log_.scans[next_ - 1].odometry, scan.odometry);
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
