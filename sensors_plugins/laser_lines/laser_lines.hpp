// laser_lines.hpp — the `laser_lines` extractor: one planar laser scan →
// "line_segment2d" measurements (mspace/measurements/line_segment2d.hpp), by the
// split-and-merge method of line_extraction.hpp.
//
// Input: a SensorReading whose `values` has one row per beam in beam order,
// (range, bearing) in m and rad, range 0 for no return (what `carmen_log`
// delivers). A reading with another column count or non-finite numbers is an
// error naming the channel and time.
#pragma once

#include <cstdint>
#include <optional>
#include <vector>

#include "line_extraction.hpp"
#include "mspace/extractor.hpp"
#include "mspace/params.hpp"
#include "mspace/state.hpp"

namespace mspace::laser_lines {

/// The Measurement of one segment: v = (ρ, α, s_a, s_b), C_v, inliers as
/// dense (2 × N), end flags.
Measurement to_measurement(const Segment& segment);

class LaserLinesExtractor final : public Extractor {
 public:
  static std::vector<ParamSpec> param_specs();
  explicit LaserLinesExtractor(const PluginArgs& args);
  explicit LaserLinesExtractor(const LineConfig& config) : config_(config), sigma_in_use_(config.range_sigma) {}

  void extract(const SensorReading& reading, std::vector<Measurement>& out) override;

  /// Conformance with a feature type (mspace/scene.hpp): a noise-free 360°
  /// scan (0.5° steps) from inside a rectangular room, 4–10 m a side, turned
  /// at random; the four walls are the true shapes (their ends are corners).
  std::optional<SampleScene> sample_scene(std::uint64_t seed) const override;

  const LineConfig& config() const { return config_; }

  // Run-time state (checkpoints): the recent segments' noise estimates.
  bool has_state() const override { return true; }
  void save_state(StateWriter& out) const override;
  void restore_state(const StateReader& in, int version) override;

 private:
  void learn_range_noise(const std::vector<Segment>& segments);

  LineConfig config_;
  bool sigma_from_data_ = false;
  /// The σ the next scan's breakpoints are found with: range_sigma, or with
  /// range_sigma_from_data the measured median where that is larger.
  double sigma_in_use_ = 0.0;
  RangeNoiseTracker noise_;
  Logger* log_ = nullptr;
  bool reported_ = false;
};

}  // namespace mspace::laser_lines
