// tree_detections.hpp — the `tree_detections` extractor: a pass-through for
// trunks found by an external detector (ACFR's detectTreesI16 in the Victoria
// Park data set), when the raw scans are not available.
//
// Each row of a reading's `values` is one trunk (range m, bearing rad in the
// sensor frame, diameter m) and becomes a "range_bearing_diameter"
// measurement with C_v = diag(σ_r², σ_b², σ_d²), where
//   σ_d = diameter_sigma + diameter_sigma_per_m · range
// (a detector that measures the diameter from the angular width of a trunk
// errs by about one beam spacing times the range). Rows outside
// [min_range, max_range] or [min_diameter, max_diameter] are dropped.
#pragma once

#include <cstdint>
#include <optional>
#include <vector>

#include "mspace/extractor.hpp"
#include "mspace/params.hpp"

namespace mspace::tree_detections {

inline constexpr const char* kRangeBearingDiameter = "range_bearing_diameter";

struct TreeDetectionsConfig {
  double range_sigma = 0.1;            ///< m
  double bearing_sigma = 0.01;         ///< rad
  double diameter_sigma = 0.1;         ///< m
  double diameter_sigma_per_m = 0.0;   ///< m per m of range
  double min_range = 0.0, max_range = 75.0;      ///< m
  double min_diameter = 0.0, max_diameter = 2.0;  ///< m
};

class TreeDetectionsExtractor final : public Extractor {
 public:
  static std::vector<ParamSpec> param_specs();
  explicit TreeDetectionsExtractor(const PluginArgs& args);
  explicit TreeDetectionsExtractor(const TreeDetectionsConfig& config) : config_(config) {}

  /// Throws std::runtime_error naming channel, time and row for a reading
  /// that is not N × 3 or holds non-finite numbers.
  void extract(const SensorReading& reading, std::vector<Measurement>& out) override;

  /// Conformance: 1–8 trunks at 2–40 m, ±90°, diameters 0.1–1 m.
  std::optional<SensorReading> sample_reading(std::uint64_t seed) const override;
  /// Conformance with a feature type: the trunks of pole_scene.hpp as rows.
  std::optional<SampleScene> sample_scene(std::uint64_t seed) const override;

  const TreeDetectionsConfig& config() const { return config_; }

 private:
  TreeDetectionsConfig config_;
};

}  // namespace mspace::tree_detections
