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
//
// Noise from data (issue 12): the same statistics per measurement kind
// (Measurement::kind, e.g. "bearing", "ceiling_line"), and the factor k on
// the extractor's σ that would make them consistent. S splits into the
// state's part and the measurement's, S = A + R with A = J_η,state P Jᵀ and
// R = J_ηv C_v J_ηvᵀ; σ scaled by k scales R by α = k², so
//   NIS(α) = ηᵀ (A + α R)⁻¹ η,
// and k = √α* where Σ NIS(α*) = Σ E[NIS] over the kind's updates. With
// S = L Lᵀ and L⁻¹ R L⁻ᵀ = U D Uᵀ (0 ≤ d_i ≤ 1), A + α R = L U (I + (α − 1) D) Uᵀ Lᵀ,
// so NIS(α) = Σ_i z_i² / (1 + (α − 1) d_i) with z = Uᵀ L⁻¹ η: one small
// eigen-decomposition per update, then NIS(α) on a grid of α for free.
// That k trusts the filter's state covariance. With the robot's true pose
// known (ground truth of every estimated pose coordinate) the robot's error
// e_r = x_true − x̂_r is taken out of each innovation with what the filter
// correlates with it in the feature's error (the Gaussian conditional):
//   η' = η + J_r e_r + J_f P_fr P_rr⁻¹ e_r,
//   S' = J_f (P_ff − P_fr P_rr⁻¹ P_rf) J_fᵀ + R   (J_r, J_f: eq. 30's robot and feature columns),
// and k is solved for again: the noise the measurements show once the
// robot's error (e.g. an odometry bias the motion model does not have) no
// longer counts. Measured on the simulated run with σ set 2× and 0.7× the
// truth: k = 0.46 and 1.29 (0.47 and 1.31 given the true pose) against the
// true 0.5 and 1.43 (tests/run/test_sim_run.cpp).
#pragma once

#include <Eigen/Core>
#include <array>
#include <cstdint>
#include <map>
#include <string>
#include <optional>
#include <vector>

#include "mspace/pose.hpp"
#include "mspace/source.hpp"
namespace mspace {
class StateWriter;
class StateReader;
}  // namespace mspace

namespace mspace::kernel {

/// Innovation statistics of one measurement kind of a sensor (see the file comment).
struct KindNisReport {
  std::string kind;
  std::int64_t updates = 0;
  std::int64_t rows = 0;         ///< innovation rows over those updates
  double nis_ratio = 0.0;        ///< observed / expected NIS
  double mean_nis = 0.0;         ///< per update
  double expected_nis = 0.0;     ///< per update, for a consistent filter under the gate
  /// k: the extractor's σ × k makes the NIS its expectation; `beyond` is −1
  /// or +1 when k lies below or above the range searched (k is then that end).
  double sigma_scale = 0.0;
  int sigma_scale_beyond = 0;
  /// The same with the robot's true pose (updates with ground truth only).
  std::int64_t true_pose_updates = 0;
  double nis_ratio_true_pose = 0.0;
  double sigma_scale_true_pose = 0.0;
  int sigma_scale_true_pose_beyond = 0;
};

/// One measurement used in an update, for the statistics per kind.
struct UpdateInnovation {
  std::string kind;
  Eigen::VectorXd eta;      ///< η (m rows)
  Eigen::MatrixXd J_state;  ///< ∂η/∂state over the robot's k columns, then the feature's (eq. 30)
  Eigen::MatrixXd P;        ///< the estimator's covariance of those columns
  Eigen::MatrixXd R;        ///< J_ηv C_v J_ηvᵀ
  int robot_columns = 0;    ///< k
  /// x_true − x̂ over the robot's columns, when the ground truth knows them (else empty).
  Eigen::VectorXd robot_error;
};

/// The robot's true pose of a data step, when its ground truth is the robot's
/// (no evaluation.ground_truth_sensor) and knows every estimated coordinate.
std::optional<Pose6> robot_truth(const DataStep& data, int ground_truth_sensor, const std::vector<int>& dofs);
/// x_true − x̂ over the estimated pose coordinates `dofs` (angles wrapped).
Eigen::VectorXd robot_error(const Pose6& truth, const Pose6& estimate, const std::vector<int>& dofs);

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
  std::vector<KindNisReport> kinds;  ///< per measurement kind, by name
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
  /// The same with what the statistics per kind need (its NIS is ηᵀ S⁻¹ η).
  void record_update(const UpdateInnovation& u);

  /// The σ factors searched: k from kScaleMin to kScaleMax, kScaleSteps per decade.
  static constexpr double kScaleMin = 0.01, kScaleMax = 100.0;
  static constexpr int kScaleSteps = 20;
  static constexpr int kScaleGrid = 4 * kScaleSteps + 1;

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

  /// Sums of one kind: the observed NIS at each α = k² of the grid, and the expected.
  struct NisSums {
    std::int64_t updates = 0, rows = 0;
    double nis = 0.0, expected = 0.0;
    std::array<double, kScaleGrid> at_scale{};
  };
  struct KindSums {
    NisSums filter, true_pose;
  };
  std::map<std::string, KindSums> kinds_;
  std::vector<std::string> new_warnings_, new_notes_;
};

}  // namespace mspace::kernel
