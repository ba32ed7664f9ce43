// range_bearing.cpp — see range_bearing.hpp.
#include "range_bearing.hpp"

#include <Eigen/Core>
#include <charconv>
#include <cmath>
#include <numbers>
#include <random>
#include <stdexcept>
#include <string>

#include "mspace/pose.hpp"

namespace mspace::range_bearing {
namespace {

double deg_to_rad(double deg) { return deg * std::numbers::pi / 180.0; }

/// Shortest text that reads back as the same double (time stamps need all
/// their digits, "12.5" should not print as "12.500000").
std::string format_number(double x) {
  char buf[64];
  const auto result = std::to_chars(buf, buf + sizeof buf, x);
  return std::string(buf, result.ptr);
}

/// "channel 'laser', t = 12.5 s, row 3: " — the prefix of every error.
std::string where(const SensorReading& reading, Eigen::Index row) {
  return "range_bearing: channel '" + reading.channel + "', t = " + format_number(reading.t) +
         " s, row " + std::to_string(row) + ": ";
}

void check_columns(const SensorReading& reading) {
  const Eigen::Index cols = reading.values.cols();
  if (reading.values.rows() > 0 && cols != 2 && cols != 3) {
    throw std::runtime_error(where(reading, 0) + std::to_string(cols) +
                             " columns, expected 2 (range, bearing) or 3 (range, bearing, "
                             "elevation)");
  }
}

void check_finite(const SensorReading& reading, Eigen::Index row) {
  if (!reading.values.row(row).allFinite()) {
    std::string values;
    for (Eigen::Index c = 0; c < reading.values.cols(); ++c) {
      values += (c == 0 ? "" : ", ") + format_number(reading.values(row, c));
    }
    throw std::runtime_error(where(reading, row) + "non-finite value in (" + values + ")");
  }
}

double positive(const Params& params, const char* name) {
  const double value = params.get_double(name);
  if (!(value > 0.0)) {
    throw std::invalid_argument(std::string("range_bearing: parameter '") + name +
                                "' must be > 0 (it is " + format_number(value) + ")");
  }
  return value;
}

}  // namespace

std::vector<ParamSpec> RangeBearingExtractor::param_specs() {
  return {
      param_double("range_sigma", 0.05, "range noise standard deviation (m), > 0", 0.0, 100.0),
      param_double("bearing_sigma_deg", 1.0, "bearing noise standard deviation (deg), > 0", 0.0,
                   180.0),
      param_double("elevation_sigma_deg", 2.0,
                   "elevation noise standard deviation (deg), > 0; used for 3-column readings only "
                   "(2-column readings come from a planar sensor and measure no elevation)",
                   0.0, 90.0),
      param_double("min_range", 0.1, "readings closer than this are dropped (m)", 0.0),
      param_double("max_range", 30.0, "readings farther than this are dropped (m)", 0.0),
  };
}

RangeBearingExtractor::RangeBearingExtractor(const PluginArgs& args) : log_(&args.log()) {
  const Params& p = args.params;
  config_.range_sigma = positive(p, "range_sigma");
  config_.bearing_sigma = deg_to_rad(positive(p, "bearing_sigma_deg"));
  config_.elevation_sigma = deg_to_rad(positive(p, "elevation_sigma_deg"));
  config_.min_range = p.get_double("min_range");
  config_.max_range = p.get_double("max_range");
  if (config_.min_range > config_.max_range) {
    throw std::invalid_argument("range_bearing: min_range (" + format_number(config_.min_range) +
                                ") is larger than max_range (" + format_number(config_.max_range) +
                                ")");
  }
}

void RangeBearingExtractor::extract(const SensorReading& reading, std::vector<Measurement>& out) {
  check_columns(reading);
  const bool planar = reading.values.cols() == 2;
  const Eigen::Index size = planar ? 2 : 3;
  const Eigen::Vector3d variances(config_.range_sigma * config_.range_sigma,
                                  config_.bearing_sigma * config_.bearing_sigma,
                                  config_.elevation_sigma * config_.elevation_sigma);
  int dropped = 0;
  for (Eigen::Index row = 0; row < reading.values.rows(); ++row) {
    check_finite(reading, row);
    const double range = reading.values(row, 0);
    if (range < config_.min_range || range > config_.max_range) {
      ++dropped;
      continue;
    }
    Measurement m;
    // A planar sensor measures (r, b) and no elevation (see the header).
    m.kind = planar ? kPlanarMeasurementKind : kMeasurementKind;
    m.v = reading.values.row(row).transpose();
    m.C_v = variances.head(size).asDiagonal();
    out.push_back(std::move(m));
  }
  if (dropped > 0) {
    log_->debug("channel '", reading.channel, "' t=", reading.t, ": dropped ", dropped, " of ",
                reading.values.rows(), " readings outside [", config_.min_range, ", ",
                config_.max_range, "] m");
  }
}

std::optional<SampleScene> RangeBearingExtractor::sample_scene(std::uint64_t seed) const {
  std::mt19937_64 rng(seed);
  auto uniform = [&rng](double lo, double hi) { return std::uniform_real_distribution<double>(lo, hi)(rng); };
  const bool planar = seed % 2 == 1;
  constexpr double kPi = std::numbers::pi;
  SampleScene scene;
  scene.reading.channel = "mspace_check";
  scene.x_ms = planar ? make_pose(uniform(-20, 20), uniform(-20, 20), uniform(0, 2), uniform(-kPi, kPi), 0, 0)
                      : make_pose(uniform(-20, 20), uniform(-20, 20), uniform(0, 2), uniform(-kPi, kPi),
                                  uniform(-0.3, 0.3), uniform(-0.3, 0.3));
  const int n = std::uniform_int_distribution<int>(1, 6)(rng);
  scene.reading.values.resize(n, planar ? 2 : 3);
  for (int i = 0; i < n; ++i) {
    const double r = uniform(std::max(2.0, config_.min_range), std::min(20.0, config_.max_range));
    const double b = uniform(-kPi, kPi), e = planar ? 0.0 : uniform(-0.6, 0.6);
    // The convention of this extractor (see the header): bearing b
    // anticlockwise from the sensor's x axis, elevation e above its x–y plane.
    const Eigen::Vector3d p_s(r * std::cos(e) * std::cos(b), r * std::cos(e) * std::sin(b), r * std::sin(e));
    scene.reading.values(i, 0) = r;
    scene.reading.values(i, 1) = b;
    if (!planar) scene.reading.values(i, 2) = e;
    TrueShape point;
    point.kind = TrueShape::Kind::Point;
    point.a = rotation(scene.x_ms) * p_s + scene.x_ms.head<3>();
    scene.truth.push_back(point);
  }
  return scene;
}

}  // namespace mspace::range_bearing
