// range_bearing.hpp — the `range_bearing` extractor: rows of (range, bearing)
// or (range, bearing, elevation) become point measurements.
//
// Each row of a SensorReading's `values` is one detected object, in metres and
// radians in the sensor frame:
//   2 columns: (r, b)     — a planar sensor (e.g. a laser scanner): a
//                           Measurement of kind "range_bearing" with
//                           v = (r, b) and C_v = diag(σr², σb²);
//   3 columns: (r, b, e)  — a 3-D sensor: kind "range_bearing_elevation" with
//                           v = (r, b, e) and C_v = diag(σr², σb², σe²).
//
// Planar sensors. A 2-D sensor measures no elevation, and its measurement
// says so: it has two rows. A point feature fed only planar measurements
// stays in its M-space of dimension 2 (x, y; the height outside it), and
// extends to 3 if a 3-D sensor ever measures its elevation.
// `elevation_sigma_deg` is used for 3-column rows only.
//
// Rows with a range outside [min_range, max_range] are dropped. A reading
// with non-finite numbers or a column count other than 2 or 3 is an error
// (std::runtime_error naming the channel, the time stamp and the row).
#pragma once

#include <cstdint>
#include <optional>
#include <vector>

#include "mspace/extractor.hpp"
#include "mspace/params.hpp"
#include "mspace/plugin.hpp"

namespace mspace::range_bearing {

/// The measurement kinds this extractor produces: 3-column rows, 2-column rows.
inline constexpr const char* kMeasurementKind = "range_bearing_elevation";
inline constexpr const char* kPlanarMeasurementKind = "range_bearing";

/// The extractor's settings, with angles already converted to radians.
struct RangeBearingConfig {
  double range_sigma = 0.05;     ///< σr (m)
  double bearing_sigma = 0.0;    ///< σb (rad)
  double elevation_sigma = 0.0;  ///< σe (rad), for 3-column rows
  double min_range = 0.0;        ///< shorter readings are dropped (m)
  double max_range = 0.0;        ///< longer readings are dropped (m)
};

class RangeBearingExtractor : public Extractor {
 public:
  /// The declared parameters: range_sigma, bearing_sigma_deg,
  /// elevation_sigma_deg, min_range, max_range.
  static std::vector<ParamSpec> param_specs();

  /// Reads the parameters; throws std::invalid_argument when a standard
  /// deviation is not positive or min_range > max_range.
  explicit RangeBearingExtractor(const PluginArgs& args);

  void extract(const SensorReading& reading, std::vector<Measurement>& out) override;

  /// Conformance (mspace/scene.hpp): 1–6 points at 2–20 m all around a
  /// sensor, as (r, b, e) rows of a tilted 3-D sensor (even seeds) or as
  /// (r, b) rows of a planar one whose scan plane holds the points (odd
  /// seeds), with the points.
  std::optional<SampleScene> sample_scene(std::uint64_t seed) const override;

  const RangeBearingConfig& config() const { return config_; }

 private:
  RangeBearingConfig config_;
  Logger* log_;
};

}  // namespace mspace::range_bearing
