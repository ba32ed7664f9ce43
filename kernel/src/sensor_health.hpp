// sensor_health.hpp — a health report per sensor, so that a silent or
// inconsistent sensor is never silent in the log or the summary.
//
// For every sensor the kernel counts readings, measurements, matched
// measurements and the time its extractor takes, and, for every measurement
// used in an estimator update, its normalised innovation squared
//   NIS = ηᵀ S⁻¹ η,   S = J_η,state C_state J_η,stateᵀ + J_ηv C_v J_ηvᵀ  (T-RO eqs. 29–30)
// at association time (before the update of its reading). Only measurements
// inside the gate (probability p) are used, so for a consistent filter the
// NIS of an m-row measurement has the truncated mean
//   E[χ²_m | χ²_m ≤ q] = m · F_{m+2}(q) / F_m(q),   q = F_m⁻¹(p)
// (F_m the χ² CDF with m degrees of freedom; E[X·1{X ≤ q}] = m·F_{m+2}(q)).
// The report gives the ratio of the observed to that expected sum: ≈ 1 when
// the measurement noise and the robot's uncertainty are right, ≫ 1 when the
// filter is overconfident (noise set too small), ≪ 1 when the noise is set
// larger than the data shows. The ratio is a figure to tune the extractor's
// noise from (e.g. pixel_sigma ≈ its current value · √ratio when the
// measurement noise dominates S).
//
// Warnings (each raised once, in the log when it happens and in the summary):
//   * the sensor produced no measurement in its first `silent_span` readings,
//     or no measurement of it matched a feature in `silent_span` readings that
//     had measurements;
//   * persistently overconfident updates: the NIS ratio of kPersistentWindows
//     consecutive windows of `nis_window` updates each beyond kNisRatioHigh.
// Persistently small NIS (each window below kNisRatioLow) is a note, not a
// warning: noise set larger on purpose, to cover errors correlated from
// reading to reading, shows the same way.
#pragma once

#include <cstdint>
#include <string>
#include <vector>

namespace mspace {
class StateWriter;
class StateReader;
}  // namespace mspace

namespace mspace::kernel {

struct SensorHealthReport {
  std::string sensor;
  std::int64_t readings = 0;
  std::int64_t measurements = 0;
  std::int64_t matched = 0;
  std::int64_t updates = 0;            ///< measurements used in estimator updates
  double extract_seconds = 0.0;
  double nis_ratio = 0.0;              ///< observed / expected NIS over the run (0 without updates)
  double mean_nis_per_row = 0.0;       ///< observed mean NIS per innovation row
  double expected_nis_per_row = 0.0;   ///< its expectation for a consistent filter, under the gate
  std::vector<std::string> warnings;
  std::vector<std::string> notes;  ///< NIS persistently small
};

class SensorHealth {
 public:
  /// NIS ratios beyond these over a window of updates raise a warning.
  /// A consistent filter's window ratio is 1 ± ≈ 0.1 (200 updates of 1–3
  /// rows); the gate truncates what an overconfident one shows (innovations
  /// beyond it start features instead), so the high bound is modest.
  static constexpr double kNisRatioHigh = 1.5;
  static constexpr double kNisRatioLow = 0.2;
  /// Consecutive windows beyond the same bound before the warning.
  static constexpr int kPersistentWindows = 3;

  SensorHealth(std::string sensor, std::string extractor_hint, std::int64_t silent_span, int nis_window,
               double gate_probability);

  /// One reading: how many measurements the extractor produced, how many matched.
  void record_reading(std::int64_t measurements, std::int64_t matched, double extract_seconds);
  /// One measurement used in an update: its NIS and number of innovation rows.
  void record_update(double nis, int rows);

  /// Warnings raised since the last call (for the log).
  std::vector<std::string> take_new_warnings();
  /// Notes made since the last call (for the log).
  std::vector<std::string> take_new_notes();
  SensorHealthReport report() const;

  /// Checkpoints: every counter, sum, window and warning, as arrays named
  /// "<prefix>…"; restore() reads them back (std::invalid_argument when one is
  /// missing or malformed). The constructor's settings are not saved.
  void save(StateWriter& out, const std::string& prefix) const;
  void restore(const StateReader& in, const std::string& prefix);

 private:
  void warn(std::string text);
  double expected_nis(int rows);

  SensorHealthReport r_;
  std::string extractor_hint_;
  std::int64_t silent_span_;
  int nis_window_;
  double gate_probability_;
  std::int64_t readings_since_match_ = 0;
  bool warned_silent_ = false, warned_unmatched_ = false, warned_high_ = false, warned_low_ = false;
  double nis_sum_ = 0.0, expected_sum_ = 0.0, rows_sum_ = 0.0;
  double window_nis_ = 0.0, window_expected_ = 0.0;
  int window_count_ = 0;
  int windows_out_ = 0, last_side_ = 0;
  double window_ratio_sum_ = 0.0;
  std::vector<double> expected_by_rows_;  ///< cache, by row count
  std::vector<std::string> new_warnings_, new_notes_;
};

}  // namespace mspace::kernel
