// carmen_reader.cpp — see carmen_reader.hpp.
#include "carmen_reader.hpp"

#include <algorithm>
#include <cerrno>
#include <cmath>
#include <cstdlib>
#include <fstream>
#include <numbers>
#include <sstream>
#include <stdexcept>
#include <unordered_map>

namespace mspace::carmen_log {
namespace {

/// A problem with one line; read_log adds "file:line: ".
struct LineError : std::runtime_error {
  using std::runtime_error::runtime_error;
};

double median_of(std::vector<double> v) {
  const auto mid = v.begin() + static_cast<long>(v.size() / 2);
  std::nth_element(v.begin(), mid, v.end());
  return *mid;
}

std::vector<std::string> split(const std::string& line) {
  std::vector<std::string> tokens;
  std::istringstream in(line);
  for (std::string token; in >> token;) tokens.push_back(token);
  return tokens;
}

/// A token as a finite number, or a LineError naming the field.
double parse_number(const std::string& token, const char* what) {
  char* end = nullptr;
  errno = 0;
  const double value = std::strtod(token.c_str(), &end);
  if (end == token.c_str() || *end != '\0' || errno == ERANGE || !std::isfinite(value))
    throw LineError(std::string(what) + " is '" + token + "', not a finite number");
  return value;
}

/// Reads the tokens of one line in order, as numbers, naming the field in errors.
class Fields {
 public:
  explicit Fields(const std::vector<std::string>& tokens) : tokens_(tokens) {}

  double number(const char* what) {
    if (next_ >= tokens_.size()) throw LineError(std::string("line ends before ") + what);
    return parse_number(tokens_[next_++], what);
  }
  int count(const char* what) {
    const double value = number(what);
    if (value < 0.0 || value != std::floor(value) || value > 100000.0)
      throw LineError(std::string(what) + " is not a valid count");
    return static_cast<int>(value);
  }
  Pose2 pose(const char* what) {
    Pose2 p;
    for (int i = 0; i < 3; ++i) p[i] = number(what);
    return p;
  }
  void skip(std::size_t n, const char* what) {
    if (next_ + n > tokens_.size()) throw LineError(std::string("line ends before ") + what);
    next_ += n;
  }
  std::size_t remaining() const { return tokens_.size() - next_; }
  /// A CARMEN message ends with `host logger_timestamp` after its own time
  /// stamp: more than those two fields is a line run together with another.
  void expect_host_and_logger_time() const {
    if (remaining() > 2)
      throw LineError(std::to_string(remaining() - 2) + " extra field(s) after the time stamp, host and logger time "
                      "stamp: lines run together?");
  }

 private:
  const std::vector<std::string>& tokens_;
  std::size_t next_ = 1;  // token 0 is the message name or, for the table, read by the caller
};

/// The raw ranges (no-return values are resolved once the whole log is read).
std::vector<double> read_ranges(Fields& f, int n) {
  std::vector<double> ranges(static_cast<std::size_t>(n));
  for (double& r : ranges) {
    r = f.number("a range");
    if (r < 0.0) throw LineError("negative range");
  }
  return ranges;
}

/// Beam bearings of a scan of n beams over `fov` centred on the x axis (see header).
std::vector<double> centred_bearings(int n, double fov) {
  const double step = n % 2 == 0 ? fov / n : fov / std::max(1, n - 1);
  std::vector<double> bearings(static_cast<std::size_t>(n));
  for (int i = 0; i < n; ++i) bearings[static_cast<std::size_t>(i)] = -fov / 2.0 + i * step;
  return bearings;
}

Scan parse_table_line(const std::vector<std::string>& tokens, const ReaderOptions& o) {
  Scan scan;
  scan.t = parse_number(tokens[0], "the time stamp") + o.time_offset;  // Fields starts at token 1
  Fields f(tokens);
  scan.odometry = f.pose("the odometry pose");
  scan.ground_truth = f.pose("the corrected pose");
  const int n = static_cast<int>(f.remaining());
  if (n < 2) throw LineError("fewer than 2 ranges");
  scan.ranges = read_ranges(f, n);
  scan.bearings = centred_bearings(n, std::numbers::pi);
  return scan;
}

struct CarmenState {
  std::optional<Pose2> last_odom;  ///< newest ODOM line (GMapping variant)
  std::vector<std::pair<double, Pose2>> odom_since_scan;  ///< ODOM lines (t, pose) since the last scan (CLF)
};

/// FLASER n ranges x y θ odom_x odom_y odom_θ t host logger_t.
Scan parse_flaser(Fields& f, const ReaderOptions& o, Variant variant, const CarmenState& state) {
  Scan scan;
  const int n = f.count("the number of ranges");
  if (n < 2) throw LineError("fewer than 2 ranges");
  scan.ranges = read_ranges(f, n);
  scan.bearings = centred_bearings(n, o.flaser_fov);
  const Pose2 laser_pose = f.pose("the laser pose");
  const Pose2 odom_pose = f.pose("the odometry pose");
  scan.t = f.number("the time stamp") + o.time_offset;
  f.expect_host_and_logger_time();
  if (variant == Variant::GMapping) {
    if (!state.last_odom) throw LineError("GMapping log: FLASER before any ODOM line");
    scan.odometry = *state.last_odom;
    scan.ground_truth = laser_pose;
  } else {
    scan.odometry = odom_pose;
  }
  return scan;
}

/// ROBOTLASER1 (see header): the robot pose is the odometry.
Scan parse_robotlaser(Fields& f, const ReaderOptions& o) {
  (void)o;
  Scan scan;
  f.number("the laser type");
  const double start = f.number("the start angle");
  f.number("the field of view");
  const double resolution = f.number("the angular resolution");
  scan.max_range = f.number("the maximum range");
  if (!(scan.max_range > 0.0)) throw LineError("the maximum range is not positive");
  f.skip(2, "accuracy and remission mode");
  const int n = f.count("the number of ranges");
  if (n < 2) throw LineError("fewer than 2 ranges");
  scan.ranges = read_ranges(f, n);
  scan.bearings.resize(static_cast<std::size_t>(n));
  for (int i = 0; i < n; ++i) scan.bearings[static_cast<std::size_t>(i)] = start + i * resolution;
  const int m = f.count("the number of remissions");
  f.skip(static_cast<std::size_t>(m), "the remissions");
  const Pose2 laser = f.pose("the laser pose");
  scan.odometry = f.pose("the robot pose");
  // The laser in the robot's frame: R(θ_r)ᵀ (p_l − p_r), θ_l − θ_r.
  const double c = std::cos(scan.odometry[2]), sn = std::sin(scan.odometry[2]);
  const double dx = laser[0] - scan.odometry[0], dy = laser[1] - scan.odometry[1];
  scan.laser_offset = Pose2(c * dx + sn * dy, -sn * dx + c * dy,
                            std::remainder(laser[2] - scan.odometry[2], 2.0 * std::numbers::pi));
  f.skip(5, "velocities and safety distances");
  scan.t = f.number("the time stamp") + o.time_offset;
  f.expect_host_and_logger_time();
  return scan;
}

bool starts_with_number(const std::string& token) {
  char* end = nullptr;
  std::strtod(token.c_str(), &end);
  return end != token.c_str();
}

/// First non-comment token of the file, to tell the formats apart; also
/// whether the file has NEFF lines (GMapping's writer).
void sniff(const std::filesystem::path& file, bool& numeric_first, bool& has_neff) {
  std::ifstream in(file);
  numeric_first = false;
  has_neff = false;
  bool first_seen = false;
  for (std::string line; std::getline(in, line);) {
    const std::vector<std::string> tokens = split(line);
    if (tokens.empty() || tokens[0][0] == '#') continue;
    if (!first_seen) {
      numeric_first = starts_with_number(tokens[0]);
      first_seen = true;
      if (numeric_first) return;
    }
    if (tokens[0] == "NEFF") {
      has_neff = true;
      return;
    }
  }
}

/// "file:line".
std::string where(const std::filesystem::path& file, int line) { return file.string() + ":" + std::to_string(line); }

std::string number_text(double v) {
  std::ostringstream s;
  s << v;
  return s.str();
}

/// The no-return value the ranges show: the largest value that at least 1 %
/// of all ranges (and 20 at least) have exactly, with fewer than 0.1 % of the ranges (other than
/// such values) above it. Real surfaces give a spread of values; a sensor's
/// no-return code is one value, repeated, at the top of the distribution.
void detect_no_return(const LogContents& log, LaserFacts& facts) {
  std::unordered_map<double, std::size_t> counts;
  std::size_t total = 0;
  for (const Scan& s : log.scans)
    for (double r : s.ranges) {
      ++counts[r];
      ++total;
    }
  if (total == 0) return;
  std::vector<std::pair<double, std::size_t>> values(counts.begin(), counts.end());
  std::sort(values.begin(), values.end(), [](const auto& a, const auto& b) { return a.first > b.first; });
  const double frequent = 0.01 * static_cast<double>(total), above_limit = 0.001 * static_cast<double>(total);
  std::size_t above = 0;
  for (const auto& [value, count] : values) {
    if (static_cast<double>(above) >= above_limit) break;
    if (static_cast<double>(count) >= frequent && count >= 20 && value > 0.0) {
      facts.detected_no_return = value;
      facts.detected_fraction = static_cast<double>(count) / static_cast<double>(total);
      return;
    }
    above += count;
  }
}

/// Line of the first scan with a range exactly `value`.
int first_line_with(const LogContents& log, double value) {
  for (const Scan& s : log.scans)
    if (std::find(s.ranges.begin(), s.ranges.end(), value) != s.ranges.end()) return s.line;
  return 0;
}

double param_number(const LogContents& log, const std::string& name, const std::filesystem::path& file,
                    bool& found) {
  const auto it = log.params.find(name);
  found = it != log.params.end();
  if (!found) return 0.0;
  char* end = nullptr;
  const double v = std::strtod(it->second.value.c_str(), &end);
  if (end == it->second.value.c_str() || *end != '\0' || !std::isfinite(v))
    throw std::runtime_error(where(file, it->second.line) + ": PARAM " + name + " is '" + it->second.value +
                             "', not a number");
  return v;
}

bool same_offset(const Pose2& a, const Pose2& b) {
  return (a.head<2>() - b.head<2>()).norm() <= 0.01 &&
         std::abs(std::remainder(a[2] - b[2], 2.0 * std::numbers::pi)) <= 0.5 * std::numbers::pi / 180.0;
}

std::string offset_text(const Pose2& o) {
  std::ostringstream s;
  s << "[" << o[0] << ", " << o[1] << ", " << o[2] * 180.0 / std::numbers::pi << "°]";
  return s.str();
}

/// Fills log.laser (see the header) and turns no-return values and error
/// codes into 0.
void resolve_laser(LogContents& log, const ReaderOptions& o, const std::filesystem::path& file) {
  LaserFacts& facts = log.laser;
  detect_no_return(log, facts);
  bool has_param_max = false;
  const double param_max = param_number(log, "robot_front_laser_max", file, has_param_max);
  const int param_max_line = has_param_max ? log.params.at("robot_front_laser_max").line : 0;
  std::vector<double> fields;
  int field_line = 0;
  for (const Scan& s : log.scans)
    if (s.max_range > 0.0) {
      fields.push_back(s.max_range);
      if (field_line == 0) field_line = s.line;
    }

  if (o.no_return_range <= 0.0) {
    // From the log: the detected value, else the PARAM, else the ROBOTLASER1 field.
    if (facts.detected_no_return) {
      facts.no_return = *facts.detected_no_return;
      facts.no_return_origin = where(file, first_line_with(log, facts.no_return)) + ": detected (" +
                               number_text(100.0 * facts.detected_fraction) + " % of the ranges are exactly " +
                               number_text(facts.no_return) + ", none larger)";
    } else if (has_param_max) {
      facts.no_return = param_max;
      facts.no_return_origin = where(file, param_max_line) + ": PARAM robot_front_laser_max";
    } else if (!fields.empty()) {
      facts.no_return = median_of(fields);
      facts.no_return_origin = where(file, field_line) + ": ROBOTLASER1 maximum range";
    } else {
      facts.no_return = 81.0;
      facts.no_return_origin = "default (the log records no maximum range and no range value dominates)";
    }
  } else {
    facts.no_return = o.no_return_range;
    facts.no_return_origin = "configured (no_return_range)";
    if (facts.detected_no_return && *facts.detected_no_return < o.no_return_range * (1.0 - 1e-9)) {
      const double v = *facts.detected_no_return;
      const std::string problem =
          where(file, first_line_with(log, v)) + ": no_return_range is " + number_text(o.no_return_range) + " but " +
          number_text(100.0 * facts.detected_fraction) + " % of the ranges are exactly " + number_text(v) +
          " and none larger: " + number_text(v) +
          " is this log's no-return value, and read as a range it draws walls where nothing was seen (set "
          "no_return_range: " + number_text(v) + ", or 0 to take it from the log)";
      if (facts.detected_fraction >= 0.05) throw std::runtime_error(problem);
      facts.warnings.push_back(problem);
    }
    if (has_param_max && std::abs(param_max - o.no_return_range) > 0.01 * o.no_return_range)
      facts.warnings.push_back(where(file, param_max_line) + ": PARAM robot_front_laser_max is " +
                               number_text(param_max) + " but no_return_range is " + number_text(o.no_return_range));
  }

  // Error codes: values repeated exactly (≥ 3 times) within 1 % below the
  // no-return value (SICK reports dazzle and similar faults there).
  std::map<double, std::size_t> near_top;
  for (const Scan& s : log.scans)
    for (double r : s.ranges)
      if (r < facts.no_return && r >= 0.99 * facts.no_return) ++near_top[r];
  for (const auto& [value, count] : near_top)
    if (count >= 3) {
      facts.error_codes.push_back(value);
      facts.error_code_ranges += count;
    }

  for (Scan& s : log.scans)
    for (double& r : s.ranges) {
      const bool code = std::binary_search(facts.error_codes.begin(), facts.error_codes.end(), r);
      if (r >= facts.no_return || code || (s.max_range > 0.0 && r >= s.max_range)) r = 0.0;
    }

  // The laser's offset on the robot.
  std::vector<double> ox, oy, oth;
  int offset_line = 0;
  for (const Scan& s : log.scans)
    if (s.laser_offset) {
      ox.push_back((*s.laser_offset)[0]);
      oy.push_back((*s.laser_offset)[1]);
      oth.push_back((*s.laser_offset)[2]);
      if (offset_line == 0) offset_line = s.line;
    }
  bool has_px = false, has_py = false, has_pth = false;
  const double px = param_number(log, "robot_frontlaser_offset", file, has_px);
  const double py = param_number(log, "robot_frontlaser_side_offset", file, has_py);
  const double pth = param_number(log, "robot_frontlaser_angular_offset", file, has_pth);
  std::optional<Pose2> param_offset;
  std::string param_origin;
  if (has_px || has_py || has_pth) {
    param_offset = Pose2(px, py, pth);
    const char* name = has_px ? "robot_frontlaser_offset" : has_py ? "robot_frontlaser_side_offset"
                                                                    : "robot_frontlaser_angular_offset";
    param_origin = where(file, log.params.at(name).line) + " (PARAM robot_frontlaser_*offset)";
  }
  bool from_poses = false;
  if (!ox.empty()) {
    facts.offset = Pose2(median_of(ox), median_of(oy), median_of(oth));
    facts.offset_origin = where(file, offset_line) + " (ROBOTLASER1 laser pose in the robot pose's frame, median)";
    from_poses = true;
    std::size_t off = 0;
    for (std::size_t i = 0; i < ox.size(); ++i)
      if (!same_offset(Pose2(ox[i], oy[i], oth[i]), *facts.offset)) ++off;
    if (off > ox.size() / 100)
      facts.warnings.push_back(facts.offset_origin + ": the laser pose differs from the median offset " +
                               offset_text(*facts.offset) + " in " + std::to_string(off) + " of " +
                               std::to_string(ox.size()) + " scans");
    if (param_offset && same_offset(*param_offset, *facts.offset)) {
      // Logged poses carry a few significant digits only (1e-4 m at 100 m):
      // the exact PARAM value is what a configuration will repeat.
      facts.offset = param_offset;
    } else {
      // Rounded to 1 mm and 0.01° so that a configuration can state it exactly.
      const double deg = 180.0 / std::numbers::pi;
      facts.offset = Pose2(std::round((*facts.offset)[0] * 1000.0) / 1000.0,
                           std::round((*facts.offset)[1] * 1000.0) / 1000.0,
                           std::round((*facts.offset)[2] * deg * 100.0) / 100.0 / deg);
    }
    if (param_offset && !same_offset(*param_offset, *facts.offset))
      facts.warnings.push_back(param_origin + ": the PARAM offset " + offset_text(*param_offset) +
                               " differs from the offset of the ROBOTLASER1 poses " + offset_text(*facts.offset) +
                               " (" + facts.offset_origin + "); the poses are used");
  } else if (param_offset) {
    facts.offset = param_offset;
    facts.offset_origin = param_origin;
  }
  if (o.laser_offset && facts.offset && !same_offset(*o.laser_offset, *facts.offset)) {
    const std::string problem = facts.offset_origin + ": the log records the laser at " +
                                offset_text(*facts.offset) + " on the robot, but laser_offset is " +
                                offset_text(*o.laser_offset);
    if (from_poses) throw std::runtime_error(problem);
    facts.warnings.push_back(problem);
  }
}

}  // namespace

Eigen::Vector3d odometry_increment(const Pose2& from, const Pose2& to) {
  const double c = std::cos(from[2]), s = std::sin(from[2]);
  const double dx = to[0] - from[0], dy = to[1] - from[1];
  return {c * dx + s * dy, -s * dx + c * dy, std::remainder(to[2] - from[2], 2.0 * std::numbers::pi)};
}

LogContents read_log(const std::filesystem::path& file, const ReaderOptions& options) {
  std::ifstream in(file);
  if (!in) throw std::runtime_error(file.string() + ": cannot open the log file");
  LogContents out;
  bool numeric_first = false, has_neff = false;
  sniff(file, numeric_first, has_neff);
  out.format = options.format != Format::Auto ? options.format : numeric_first ? Format::Table : Format::Carmen;
  out.variant = options.variant != Variant::Auto ? options.variant : has_neff ? Variant::GMapping : Variant::Clf;

  CarmenState state;
  std::string line;
  for (int line_no = 1; std::getline(in, line); ++line_no) {
    const std::vector<std::string> tokens = split(line);
    if (tokens.empty() || tokens[0][0] == '#') continue;
    try {
      if (out.format == Format::Table) {
        Scan scan = parse_table_line(tokens, options);
        // Every line of the table is one scan of the same laser: a line with
        // another number of ranges is cut short or run together, not a scan
        // of another width spread over the same field of view.
        if (!out.scans.empty() && scan.ranges.size() != out.scans.front().ranges.size())
          throw LineError(std::to_string(scan.ranges.size()) + " ranges where the first scan (line " +
                          std::to_string(out.scans.front().line) + ") has " +
                          std::to_string(out.scans.front().ranges.size()) + ": a truncated or merged line");
        out.scans.push_back(std::move(scan));
      } else {
        Fields f(tokens);
        if (tokens[0] == "FLASER") {
          out.scans.push_back(parse_flaser(f, options, out.variant, state));
        } else if (tokens[0] == "ROBOTLASER1") {
          out.scans.push_back(parse_robotlaser(f, options));
        } else if (tokens[0] == "PARAM") {
          if (tokens.size() < 3) throw LineError("PARAM without a name and a value");
          out.params.emplace(tokens[1], LogParam{tokens[2], line_no});
          continue;
        } else if (tokens[0] == "ODOM") {
          const Pose2 pose = f.pose("the odometry pose");
          f.skip(3, "the velocities");
          const double t = f.number("the time stamp") + options.time_offset;
          f.expect_host_and_logger_time();
          state.last_odom = pose;
          if (out.variant == Variant::Clf) state.odom_since_scan.emplace_back(t, pose);
          continue;
        } else {
          continue;  // a message type this reader does not use
        }
      }
      out.scans.back().line = line_no;
      // The wheels' path since the previous scan: the ODOM poses stamped
      // strictly between the two scans (others are late or early messages).
      if (out.variant == Variant::Clf && out.format == Format::Carmen) {
        Scan& scan = out.scans.back();
        if (out.scans.size() >= 2) {
          const double after = out.scans[out.scans.size() - 2].t;
          for (const auto& [t, pose] : state.odom_since_scan)
            if (t > after && t < scan.t) scan.odometry_between.push_back(pose);
        }
        state.odom_since_scan.clear();
      }
      if (out.scans.size() >= 2) {
        const Scan& previous = out.scans[out.scans.size() - 2];
        if (out.scans.back().t <= previous.t) {
          const bool repeated = out.scans.back().t == previous.t;
          const std::string t = std::to_string(out.scans.back().t), t0 = std::to_string(previous.t);
          out.scans.pop_back();
          throw LineError("time stamp " + t + " s is " + (repeated ? "that of" : "before") + " the previous scan's " +
                          t0 + " s (line " + std::to_string(previous.line) +
                          (repeated ? "): a repeated scan" : "): time goes backwards"));
        }
      }
    } catch (const LineError& e) {
      const std::string problem = file.string() + ":" + std::to_string(line_no) + ": " + e.what();
      if (!options.skip_malformed) throw std::runtime_error(problem);
      if (out.skipped++ == 0) out.first_problem = problem;
    }
  }
  resolve_laser(out, options, file);
  return out;
}

}  // namespace mspace::carmen_log
