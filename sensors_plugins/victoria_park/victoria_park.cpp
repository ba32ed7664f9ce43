// victoria_park.cpp — see victoria_park.hpp.
#include "victoria_park.hpp"

#include <algorithm>
#include <cstdlib>
#include <numbers>
#include <stdexcept>
#include <utility>

#include "numeric_table.hpp"

namespace mspace::victoria_park {
namespace {

double seconds_from_vehicle_ms(double t_ms) { return (t_ms - kClockOriginMs) / 1000.0; }

/// "" when t may follow the previous time stamp of the same file, else the
/// problem: time going backwards, or (unless `repeat_allowed`) a repeated time
/// stamp, naming the previous record's line.
std::string time_order_problem(double t, double previous, int previous_line, bool repeat_allowed = false) {
  const std::string before = " (line " + std::to_string(previous_line) + ": " + std::to_string(previous) + " s)";
  if (t < previous) return "time " + std::to_string(t) + " s goes backwards" + before;
  if (t == previous && !repeat_allowed) return "time " + std::to_string(t) + " s repeats the previous record's" + before;
  return {};
}

}  // namespace

std::vector<DeadReckoningSample> read_dead_reckoning(const std::filesystem::path& file,
                                                     records::MalformedRecords& malformed) {
  std::vector<DeadReckoningSample> out;
  int previous_line = 0;
  for (const NumericRow& row : read_numeric_table(file, 3, "time_ms speed_mps steering_rad", malformed)) {
    const DeadReckoningSample s{seconds_from_vehicle_ms(row.values[0]), row.values[1], row.values[2]};
    std::string problem = out.empty() ? "" : time_order_problem(s.t, out.back().t, previous_line);
    if (problem.empty() && std::abs(s.steering) >= std::numbers::pi / 2) problem = "steering angle beyond ±90°";
    if (!problem.empty()) {
      malformed.report(file.string(), row.line, problem);
      continue;
    }
    out.push_back(s);
    previous_line = row.line;
  }
  return out;
}

std::vector<GpsFix> read_gps(const std::filesystem::path& file) {
  records::MalformedRecords strict;  // ground truth: never skipped (records.hpp)
  std::vector<GpsFix> out;
  int previous_line = 0;
  for (const NumericRow& row : read_numeric_table(file, 3, "time_ms x_m y_m", strict)) {
    const GpsFix fix{seconds_from_vehicle_ms(row.values[0]), row.values[1], row.values[2]};
    if (!out.empty()) {
      const std::string problem = time_order_problem(fix.t, out.back().t, previous_line);
      if (!problem.empty()) fail_at(file, row.line, problem);
    }
    out.push_back(fix);
    previous_line = row.line;
  }
  return out;
}

std::vector<Scan> read_detections(const std::filesystem::path& file, records::MalformedRecords& malformed) {
  std::vector<Scan> out;
  std::vector<Eigen::Vector3d> rows;  // of the scan being read
  int previous_line = 0;
  auto close_scan = [&] {
    if (rows.empty()) return;
    Scan& scan = out.back();
    scan.detections.resize(static_cast<Eigen::Index>(rows.size()), 3);
    for (std::size_t i = 0; i < rows.size(); ++i) scan.detections.row(static_cast<Eigen::Index>(i)) = rows[i];
    rows.clear();
  };
  for (const NumericRow& row :
       read_numeric_table(file, 4, "t_s range_m bearing_rad diameter_m", malformed)) {
    const double t = row.values[0], range = row.values[1], bearing = row.values[2], diameter = row.values[3];
    // Consecutive lines with one time stamp are the trunks of one scan.
    std::string problem = out.empty() ? "" : time_order_problem(t, out.back().t, previous_line, true);
    if (problem.empty() && (range <= 0.0 || diameter <= 0.0)) problem = "range and diameter must be positive";
    if (problem.empty() && (bearing < 0.0 || bearing > std::numbers::pi)) problem = "bearing outside [0, pi]";
    if (!problem.empty()) {
      malformed.report(file.string(), row.line, problem);
      continue;
    }
    if (out.empty() || t != out.back().t) {
      close_scan();
      out.push_back(Scan{t, {}});
    }
    // The file's bearing is 0 at the vehicle's right, π/2 straight ahead.
    rows.emplace_back(range, bearing - std::numbers::pi / 2, diameter);
    previous_line = row.line;
  }
  close_scan();
  return out;
}

std::string expand_environment(const std::string& text) {
  std::string out;
  std::size_t pos = 0;
  while (true) {
    const std::size_t start = text.find("${", pos);
    if (start == std::string::npos) break;
    const std::size_t end = text.find('}', start);
    if (end == std::string::npos) throw std::invalid_argument("unterminated '${' in '" + text + "'");
    out += text.substr(pos, start - pos);
    const std::string inner = text.substr(start + 2, end - start - 2);
    const std::size_t dash = inner.find(":-");
    const std::string var = inner.substr(0, dash);
    const char* value = std::getenv(var.c_str());
    if (value != nullptr && *value != '\0') {
      out += value;
    } else if (dash != std::string::npos) {
      out += inner.substr(dash + 2);
    } else {
      throw std::invalid_argument("environment variable '" + var + "' is not set (in '" + text + "')");
    }
    pos = end + 1;
  }
  return out + text.substr(pos);
}

// ---------------------------------------------------------------- VictoriaParkSource

std::vector<GpsFix> without_isolated_fixes(const std::vector<GpsFix>& fixes, double max_gap) {
  std::vector<GpsFix> kept;
  kept.reserve(fixes.size());
  for (std::size_t i = 0; i < fixes.size(); ++i) {
    const bool before = i > 0 && fixes[i].t - fixes[i - 1].t <= max_gap;
    const bool after = i + 1 < fixes.size() && fixes[i + 1].t - fixes[i].t <= max_gap;
    if (before || after) kept.push_back(fixes[i]);
  }
  return kept;
}

std::vector<ParamSpec> VictoriaParkSource::param_specs() {
  return {
      param_string("data_dir", "${MSPACE_DATA:-../shared/datasets}/victoria_park",
                   "the data set folder (holding text/ and rfs_slam/); relative paths are relative to the "
                   "working directory"),
      param_string("channel", "laser", "channel of the tree-detection readings"),
      param_double("gps_isolated_gap", 2.0,
                   "GPS fixes with no other fix within this many seconds are not used as ground truth (the "
                   "failing unit's jumps are there, one 141 m off); 0 keeps every fix",
                   0.0),
      records::on_malformed_param(),
  };
}

VictoriaParkSource::VictoriaParkSource(const PluginArgs& args)
    : VictoriaParkSource(expand_environment(args.params.get_string("data_dir")),
                         args.params.get_string("channel"), args.params.get_double("gps_isolated_gap"),
                         args.params.get_string("on_malformed")) {
  if (malformed_.skipped() > 0)
    args.log().warn("victoria_park: skipped ", malformed_.skipped(), " malformed record(s); the first: ",
                    malformed_.first_problem());
  args.log().info("victoria_park: ", dr_.size(), " dead-reckoning samples, ", scans_.size(), " scans, ",
                  gps_.size(), " GPS fixes (", isolated_fixes_, " isolated ones left out), ", times_.size(),
                  " steps");
}

VictoriaParkSource::VictoriaParkSource(const std::filesystem::path& data_dir, std::string channel,
                                       double isolated_gap, const std::string& on_malformed)
    : channel_(std::move(channel)), malformed_(on_malformed) {
  if (!std::filesystem::is_directory(data_dir)) {
    throw std::runtime_error("victoria_park: data directory '" + data_dir.string() + "' does not exist (working " +
                             "directory " + std::filesystem::current_path().string() + ")");
  }
  dr_ = read_dead_reckoning(data_dir / "text" / "aa3_dr.txt", malformed_);
  gps_ = read_gps(data_dir / "text" / "aa3_gpsx.txt");
  if (isolated_gap > 0.0) {
    const std::size_t all = gps_.size();
    gps_ = without_isolated_fixes(gps_, isolated_gap);
    isolated_fixes_ = all - gps_.size();
  }
  scans_ = read_detections(data_dir / "rfs_slam" / "measurements.dat", malformed_);
  merge_times();
}

void VictoriaParkSource::merge_times() {
  times_.clear();
  times_.reserve(dr_.size() + gps_.size() + scans_.size());
  for (const auto& s : dr_) times_.push_back(s.t);
  for (const auto& f : gps_) times_.push_back(f.t);
  for (const auto& s : scans_) times_.push_back(s.t);
  std::sort(times_.begin(), times_.end());
  times_.erase(std::unique(times_.begin(), times_.end()), times_.end());
}

bool VictoriaParkSource::next(DataStep& step) {
  if (step_ >= times_.size()) return false;
  const double t = times_[step_++];
  step = DataStep{};
  step.t = t;
  // The controls held since the previous step move the vehicle up to t.
  if (held_dr_ >= 0) {
    const DeadReckoningSample& s = dr_[static_cast<std::size_t>(held_dr_)];
    step.odometry = Eigen::Vector2d(s.speed, s.steering);
  }
  while (next_dr_ < dr_.size() && dr_[next_dr_].t <= t) held_dr_ = static_cast<long>(next_dr_++);

  if (next_scan_ < scans_.size() && scans_[next_scan_].t == t) {
    SensorReading reading;
    reading.channel = channel_;
    reading.t = t;
    reading.values = scans_[next_scan_++].detections;
    step.readings.push_back(std::move(reading));
  }
  if (next_gps_ < gps_.size() && gps_[next_gps_].t == t) {
    const GpsFix& fix = gps_[next_gps_++];
    step.ground_truth = make_pose2d(fix.x, fix.y, 0.0);
    step.ground_truth_known = static_cast<std::uint8_t>((1u << kX) | (1u << kY));
  }
  return true;
}

}  // namespace mspace::victoria_park
