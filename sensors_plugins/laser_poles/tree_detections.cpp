// tree_detections.cpp — see tree_detections.hpp.
#include "tree_detections.hpp"

#include "pole_scene.hpp"

#include <Eigen/Core>
#include <numbers>
#include <random>
#include <stdexcept>
#include <string>

namespace mspace::tree_detections {
namespace {

constexpr double kDegree = std::numbers::pi / 180.0;

std::string where(const SensorReading& reading) {
  return "tree_detections: reading on channel '" + reading.channel + "' at t = " + std::to_string(reading.t);
}

}  // namespace

std::vector<ParamSpec> TreeDetectionsExtractor::param_specs() {
  return {
      param_double("range_sigma", 0.1, "range noise (m)", 1e-6),
      param_double("bearing_sigma_deg", 0.5, "bearing noise (deg)", 1e-6),
      param_double("diameter_sigma", 0.1, "diameter noise, constant part (m)", 1e-6),
      param_double("diameter_sigma_per_m", 0.0, "diameter noise per metre of range (m/m)", 0.0),
      param_double("min_range", 0.0, "closer detections are dropped (m)", 0.0),
      param_double("max_range", 75.0, "farther detections are dropped (m)", 0.0),
      param_double("min_diameter", 0.0, "thinner trunks are dropped (m)", 0.0),
      param_double("max_diameter", 2.0, "thicker trunks are dropped (m)", 0.0),
  };
}

TreeDetectionsExtractor::TreeDetectionsExtractor(const PluginArgs& args) {
  const Params& p = args.params;
  config_.range_sigma = p.get_double("range_sigma");
  config_.bearing_sigma = p.get_double("bearing_sigma_deg") * kDegree;
  config_.diameter_sigma = p.get_double("diameter_sigma");
  config_.diameter_sigma_per_m = p.get_double("diameter_sigma_per_m");
  config_.min_range = p.get_double("min_range");
  config_.max_range = p.get_double("max_range");
  config_.min_diameter = p.get_double("min_diameter");
  config_.max_diameter = p.get_double("max_diameter");
  if (config_.min_range > config_.max_range || config_.min_diameter > config_.max_diameter)
    throw std::invalid_argument("tree_detections: a minimum exceeds its maximum");
}

void TreeDetectionsExtractor::extract(const SensorReading& reading, std::vector<Measurement>& out) {
  const Eigen::MatrixXd& rows = reading.values;
  if (rows.size() == 0) return;
  if (rows.cols() != 3) {
    throw std::runtime_error(where(reading) + ": rows must be (range, bearing, diameter), got " +
                             std::to_string(rows.cols()) + " columns");
  }
  for (Eigen::Index i = 0; i < rows.rows(); ++i) {
    if (!rows.row(i).allFinite()) throw std::runtime_error(where(reading) + ": row " + std::to_string(i) + " is not finite");
    const double range = rows(i, 0), diameter = rows(i, 2);
    if (range < config_.min_range || range > config_.max_range || diameter < config_.min_diameter ||
        diameter > config_.max_diameter)
      continue;
    const double sigma_d = config_.diameter_sigma + config_.diameter_sigma_per_m * range;
    Measurement m;
    m.kind = kRangeBearingDiameter;
    m.v = rows.row(i).transpose();
    m.C_v = Eigen::Vector3d(config_.range_sigma * config_.range_sigma, config_.bearing_sigma * config_.bearing_sigma,
                            sigma_d * sigma_d)
                .asDiagonal();
    out.push_back(std::move(m));
  }
}

std::optional<SensorReading> TreeDetectionsExtractor::sample_reading(std::uint64_t seed) const {
  std::mt19937_64 rng(seed);
  auto uniform = [&rng](double lo, double hi) { return std::uniform_real_distribution<double>(lo, hi)(rng); };
  SensorReading reading;
  reading.channel = "laser";
  reading.values.resize(std::uniform_int_distribution<int>(1, 8)(rng), 3);
  for (Eigen::Index i = 0; i < reading.values.rows(); ++i)
    reading.values.row(i) << uniform(2, 40), uniform(-std::numbers::pi / 2, std::numbers::pi / 2), uniform(0.1, 1.0);
  return reading;
}

std::optional<SampleScene> TreeDetectionsExtractor::sample_scene(std::uint64_t seed) const {
  SampleScene scene;
  scene.reading.channel = "laser";
  scene.x_ms = laser_poles::sample_planar_pose(seed);
  const std::vector<laser_poles::Trunk> trunks = laser_poles::sample_trunks(seed);
  scene.reading.values.resize(static_cast<Eigen::Index>(trunks.size()), 3);
  for (std::size_t i = 0; i < trunks.size(); ++i) {
    scene.reading.values.row(static_cast<Eigen::Index>(i)) << trunks[i].range, trunks[i].bearing, trunks[i].diameter;
    scene.truth.push_back(laser_poles::trunk_shape(trunks[i], scene.x_ms));
  }
  return scene;
}

}  // namespace mspace::tree_detections
