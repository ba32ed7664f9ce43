// laser.cpp — see laser.hpp.
#include "laser.hpp"

#include <cmath>
#include <cstdlib>
#include <functional>
#include <map>
#include <numbers>
#include <sstream>
#include <stdexcept>

namespace mspace::sim_building {
namespace {

constexpr double kDeg = std::numbers::pi / 180.0;

/// Centred start angle for n beams at resolution res: the middle beam(s) straddle 0.
double centred(int n, double res) { return -0.5 * (n - 1) * res; }

LaserSpec make(const std::string& name, const std::string& format, int beams, double res, double max_range,
               double no_return, double mount_x, double interval) {
  LaserSpec s;
  s.preset = name;
  s.format = format;
  s.beams = beams;
  s.resolution_deg = res;
  s.start_deg = centred(beams, res);
  s.max_range = max_range;
  s.no_return = no_return;
  s.mount_x = mount_x;
  s.interval = interval;
  return s;
}

struct Preset {
  std::string name, description;
  std::function<LaserSpec()> make;
};

const std::vector<Preset>& presets() {
  static const std::vector<Preset> list = {
      {"plain",
       "FLASER, 180 beams of 1° from −90° (the Intel data set's layout), 50 m, no return 81.83, "
       "laser at the robot centre, 5 Hz",
       [] {
         LaserSpec s = make("plain", "flaser", 180, 1.0, 50.0, 81.83, 0.0, 0.2);
         s.start_deg = -90.0;  // even beam count: −90°, −89°, …, 89° (the FLASER convention)
         s.error_code_probability = 0.0;
         return s;
       }},
      {"sick181",
       "ROBOTLASER1, 181 beams of 1° (−90°…90°), 50 m, no return 81.83 with SICK error codes, "
       "laser 0.22 m ahead, 5 Hz",
       [] { return make("sick181", "robotlaser1", 181, 1.0, 50.0, 81.83, 0.22, 0.2); }},
      {"sick_interleaved",
       "ROBOTLASER1, 181 beams of 1° whose start alternates among 4 angles 0.25° apart, "
       "no return 81.83, laser 0.22 m ahead, 10 Hz (dense)",
       [] {
         LaserSpec s = make("sick_interleaved", "robotlaser1", 181, 1.0, 50.0, 81.83, 0.22, 0.1);
         s.interleave = 4;
         s.interleave_step_deg = 0.25;
         return s;
       }},
      {"sick360",
       "ROBOTLASER1, 360 beams of 0.5°, 40 m, no return 50.0 (another driver's code) with error "
       "codes below it, laser 0.22 m ahead, 2 Hz",
       [] { return make("sick360", "robotlaser1", 360, 0.5, 40.0, 50.0, 0.22, 0.5); }},
      {"lms541", "ROBOTLASER1, 541 beams of 0.5° (270°), 20 m, no return 50.0, laser 0.22 m ahead, 10 Hz",
       [] { return make("lms541", "robotlaser1", 541, 0.5, 20.0, 50.0, 0.22, 0.1); }},
      {"hokuyo1080",
       "ROBOTLASER1, 1080 beams of 0.25° (270°), 30 m, no return 50.0, σ 1.5 cm, "
       "laser 0.22 m ahead, 10 Hz",
       [] {
         LaserSpec s = make("hokuyo1080", "robotlaser1", 1080, 0.25, 30.0, 50.0, 0.22, 0.1);
         s.range_sigma = 0.015;
         return s;
       }},
      {"short8",
       "ROBOTLASER1, 181 beams of 1°, 8 m (an old SICK in cm mode), no return 81.83, laser 0.22 m "
       "ahead, 5 Hz",
       [] { return make("short8", "robotlaser1", 181, 1.0, 8.0, 81.83, 0.22, 0.2); }},
      {"sparse",
       "ROBOTLASER1, 181 beams of 1°, 50 m, no return 81.83, laser 0.22 m ahead, one scan every "
       "1.5 s and 3 % chance per scan of a 2–6 s gap",
       [] {
         LaserSpec s = make("sparse", "robotlaser1", 181, 1.0, 50.0, 81.83, 0.22, 1.5);
         s.gap_probability = 0.03;
         return s;
       }},
      {"robotlaser_logged",
       "ROBOTLASER1 logged as on a real robot: 181 beams of 1° whose start alternates among 4 angles "
       "0.25° apart, 12 % of the beams without return, SICK error codes, laser 0.22 m ahead, a scan every "
       "0.6 s ± 50 % and 0.2 % chance per scan of a 1–4 minute gap",
       [] {
         LaserSpec s = make("robotlaser_logged", "robotlaser1", 181, 1.0, 50.0, 81.83, 0.22, 0.6);
         s.interleave = 4;
         s.interleave_step_deg = 0.25;
         s.dropout_probability = 0.12;
         s.interval_jitter = 0.5;
         s.gap_probability = 0.002;
         s.gap_min = 60.0;
         s.gap_max = 240.0;
         return s;
       }},
  };
  return list;
}

double parse_double(const std::string& key, const std::string& text) {
  char* end = nullptr;
  const double v = std::strtod(text.c_str(), &end);
  if (text.empty() || end != text.c_str() + text.size() || !std::isfinite(v))
    throw std::invalid_argument("laser parameter " + key + ": '" + text + "' is not a finite number");
  return v;
}

int parse_int(const std::string& key, const std::string& text) {
  const double v = parse_double(key, text);
  if (v != std::floor(v) || std::abs(v) > 1e6)
    throw std::invalid_argument("laser parameter " + key + ": '" + text + "' is not an integer");
  return static_cast<int>(v);
}

void require(bool ok, const std::string& what) {
  if (!ok) throw std::invalid_argument("laser: " + what);
}

}  // namespace

double LaserSpec::bearing(int i, long k) const {
  const long slot = interleave > 1 ? k % interleave : 0;
  return (start_deg + static_cast<double>(slot) * interleave_step_deg + i * resolution_deg) * kDeg;
}

std::string LaserSpec::describe() const {
  std::ostringstream o;
  o << "preset = " << preset << "\nformat = " << format << "\nbeams = " << beams
    << "\nresolution_deg = " << resolution_deg << "\nstart_deg = " << start_deg << "\ninterleave = " << interleave
    << "\ninterleave_step_deg = " << interleave_step_deg << "\nmax_range = " << max_range
    << "\nno_return = " << no_return << "\nerror_code_probability = " << error_code_probability
    << "\ndropout_probability = " << dropout_probability
    << "\nrange_sigma = " << range_sigma << "\nmount_x = " << mount_x << "\nmount_y = " << mount_y
    << "\nmount_theta_deg = " << mount_theta_deg << "\ninterval = " << interval
    << "\ninterval_jitter = " << interval_jitter << "\ngap_probability = " << gap_probability
    << "\ngap_min = " << gap_min << "\ngap_max = " << gap_max << "\nodom_interval = " << odom_interval << "\n";
  return o.str();
}

std::vector<std::pair<std::string, std::string>> laser_presets() {
  std::vector<std::pair<std::string, std::string>> out;
  for (const Preset& p : presets()) out.emplace_back(p.name, p.description);
  return out;
}

LaserSpec laser_preset(const std::string& name) {
  std::string choices;
  for (const Preset& p : presets()) {
    if (p.name == name) return p.make();
    choices += (choices.empty() ? "" : ", ") + p.name;
  }
  throw std::invalid_argument("unknown laser preset '" + name + "' (choices: " + choices + ")");
}

void set_laser_param(LaserSpec& s, const std::string& key_value) {
  const auto eq = key_value.find('=');
  if (eq == std::string::npos) throw std::invalid_argument("laser parameter '" + key_value + "': expected key=value");
  const std::string key = key_value.substr(0, eq), value = key_value.substr(eq + 1);
  const std::map<std::string, double*> doubles = {{"resolution_deg", &s.resolution_deg},
                                                  {"start_deg", &s.start_deg},
                                                  {"interleave_step_deg", &s.interleave_step_deg},
                                                  {"max_range", &s.max_range},
                                                  {"no_return", &s.no_return},
                                                  {"error_code_probability", &s.error_code_probability},
                                                  {"dropout_probability", &s.dropout_probability},
                                                  {"range_sigma", &s.range_sigma},
                                                  {"mount_x", &s.mount_x},
                                                  {"mount_y", &s.mount_y},
                                                  {"mount_theta_deg", &s.mount_theta_deg},
                                                  {"interval", &s.interval},
                                                  {"interval_jitter", &s.interval_jitter},
                                                  {"gap_probability", &s.gap_probability},
                                                  {"gap_min", &s.gap_min},
                                                  {"gap_max", &s.gap_max},
                                                  {"odom_interval", &s.odom_interval}};
  if (auto it = doubles.find(key); it != doubles.end()) {
    *it->second = parse_double(key, value);
  } else if (key == "beams") {
    // A new beam count keeps the scan centred (set start_deg after beams to move it).
    s.beams = parse_int(key, value);
    s.start_deg = s.format == "flaser" && s.beams % 2 == 0 ? -0.5 * s.beams * s.resolution_deg
                                                           : centred(s.beams, s.resolution_deg);
  } else if (key == "interleave") {
    s.interleave = parse_int(key, value);
  } else if (key == "format") {
    if (value != "robotlaser1" && value != "flaser")
      throw std::invalid_argument("laser parameter format: '" + value + "' (choices: robotlaser1, flaser)");
    s.format = value;
  } else {
    std::string keys = "beams, interleave, format";
    for (const auto& [k, unused] : doubles) keys += ", " + k;
    throw std::invalid_argument("unknown laser parameter '" + key + "' (keys: " + keys + ")");
  }
}

void validate(const LaserSpec& s) {
  require(s.beams >= 2 && s.beams <= 10000, "beams must be in [2, 10000]");
  require(s.resolution_deg >= 0.05 && s.resolution_deg <= 2.0, "resolution_deg must be in [0.05, 2]");
  require(s.interleave >= 1 && s.interleave <= 16, "interleave must be in [1, 16]");
  require(s.interleave_step_deg >= 0.0 && s.interleave_step_deg * (s.interleave - 1) < s.resolution_deg + 1e-9,
          "interleave offsets must stay within one resolution step");
  require((s.beams - 1) * s.resolution_deg + s.interleave_step_deg * (s.interleave - 1) <= 360.0 + 1e-9,
          "beams × resolution exceeds 360°");
  require(s.max_range > 0.5 && s.max_range <= 100.0, "max_range must be in (0.5, 100] m");
  require(s.no_return >= s.max_range, "no_return (" + std::to_string(s.no_return) + ") must be at least max_range (" +
                                          std::to_string(s.max_range) +
                                          "): a real return must never read as the no-return code");
  require(s.error_code_probability >= 0.0 && s.error_code_probability <= 0.5,
          "error_code_probability must be in [0, 0.5]");
  require(s.dropout_probability >= 0.0 && s.dropout_probability <= 0.9, "dropout_probability must be in [0, 0.9]");
  require(s.range_sigma >= 0.0 && s.range_sigma <= 1.0, "range_sigma must be in [0, 1] m");
  require(std::hypot(s.mount_x, s.mount_y) <= 0.5, "the laser must be mounted within 0.5 m of the robot centre");
  require(s.interval >= 0.01 && s.interval <= 10.0, "interval must be in [0.01, 10] s");
  require(s.interval_jitter >= 0.0 && s.interval_jitter < 1.0, "interval_jitter must be in [0, 1)");
  require(s.gap_probability >= 0.0 && s.gap_probability <= 0.5, "gap_probability must be in [0, 0.5]");
  require(s.gap_min >= 0.0 && s.gap_min <= s.gap_max && s.gap_max <= 600.0, "need 0 <= gap_min <= gap_max <= 600 s");
  require(s.odom_interval >= 0.01 && s.odom_interval <= 1.0, "odom_interval must be in [0.01, 1] s");
  require(s.format == "robotlaser1" || s.format == "flaser", "format must be robotlaser1 or flaser");
  if (s.format == "flaser") {
    // What carmen_reader assumes for FLASER (n even: −n·res/2 + i·res; n odd: −(n−1)·res/2 + i·res).
    const double expected = s.beams % 2 == 0 ? -0.5 * s.beams * s.resolution_deg : centred(s.beams, s.resolution_deg);
    require(std::abs(s.start_deg - expected) < 1e-9 && s.interleave == 1,
            "FLASER carries no angles: the scan must be centred as readers assume (start_deg " +
                std::to_string(expected) + ") and not interleaved; use format=robotlaser1");
    require(s.mount_x == 0.0 && s.mount_y == 0.0 && s.mount_theta_deg == 0.0,
            "FLASER: mount the laser at the robot centre (the offset is not in the message); use robotlaser1");
  }
}

}  // namespace mspace::sim_building
