// carmen_reader.cpp — see carmen_reader.hpp.
#include "carmen_reader.hpp"

#include <cerrno>
#include <cmath>
#include <cstdlib>
#include <fstream>
#include <numbers>
#include <sstream>
#include <stdexcept>

namespace mspace::carmen_log {
namespace {

/// A problem with one line; read_log adds "file:line: ".
struct LineError : std::runtime_error {
  using std::runtime_error::runtime_error;
};

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

 private:
  const std::vector<std::string>& tokens_;
  std::size_t next_ = 1;  // token 0 is the message name or, for the table, read by the caller
};

std::vector<double> read_ranges(Fields& f, int n, double no_return) {
  std::vector<double> ranges(static_cast<std::size_t>(n));
  for (double& r : ranges) {
    r = f.number("a range");
    if (r < 0.0) throw LineError("negative range");
    if (r >= no_return) r = 0.0;
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
  scan.ranges = read_ranges(f, n, o.no_return_range);
  scan.bearings = centred_bearings(n, std::numbers::pi);
  return scan;
}

struct CarmenState {
  std::optional<Pose2> last_odom;  ///< newest ODOM line (GMapping variant)
};

/// FLASER n ranges x y θ odom_x odom_y odom_θ t host logger_t.
Scan parse_flaser(Fields& f, const ReaderOptions& o, Variant variant, const CarmenState& state) {
  Scan scan;
  const int n = f.count("the number of ranges");
  if (n < 2) throw LineError("fewer than 2 ranges");
  scan.ranges = read_ranges(f, n, o.no_return_range);
  scan.bearings = centred_bearings(n, o.flaser_fov);
  const Pose2 laser_pose = f.pose("the laser pose");
  const Pose2 odom_pose = f.pose("the odometry pose");
  scan.t = f.number("the time stamp") + o.time_offset;
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
  Scan scan;
  f.number("the laser type");
  const double start = f.number("the start angle");
  f.number("the field of view");
  const double resolution = f.number("the angular resolution");
  const double max_range = f.number("the maximum range");
  f.skip(2, "accuracy and remission mode");
  const int n = f.count("the number of ranges");
  if (n < 2) throw LineError("fewer than 2 ranges");
  scan.ranges = read_ranges(f, n, std::min(o.no_return_range, max_range));
  scan.bearings.resize(static_cast<std::size_t>(n));
  for (int i = 0; i < n; ++i) scan.bearings[static_cast<std::size_t>(i)] = start + i * resolution;
  const int m = f.count("the number of remissions");
  f.skip(static_cast<std::size_t>(m), "the remissions");
  f.pose("the laser pose");
  scan.odometry = f.pose("the robot pose");
  f.skip(5, "velocities and safety distances");
  scan.t = f.number("the time stamp") + o.time_offset;
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
        out.scans.push_back(parse_table_line(tokens, options));
      } else {
        Fields f(tokens);
        if (tokens[0] == "FLASER") {
          out.scans.push_back(parse_flaser(f, options, out.variant, state));
        } else if (tokens[0] == "ROBOTLASER1") {
          out.scans.push_back(parse_robotlaser(f, options));
        } else if (tokens[0] == "ODOM") {
          state.last_odom = f.pose("the odometry pose");
          f.skip(3, "the velocities");
          f.number("the time stamp");
          continue;
        } else {
          continue;  // a message type this reader does not use
        }
      }
      out.scans.back().line = line_no;
    } catch (const LineError& e) {
      const std::string problem = file.string() + ":" + std::to_string(line_no) + ": " + e.what();
      if (!options.skip_malformed) throw std::runtime_error(problem);
      if (out.skipped++ == 0) out.first_problem = problem;
    }
  }
  return out;
}

}  // namespace mspace::carmen_log
