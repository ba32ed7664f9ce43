// wheel_check.hpp — laser odometry never trusted beyond what the wheels allow
// (issue 18): every scan-matched increment is compared with the wheel
// odometry's increment over the same scans, and one the wheels contradict
// beyond their measured uncertainty, or one across a logging gap, falls back
// to the wheel increment, flagged.
//
// A wrong scan match (two corridors that look alike, a person dragging the
// match, scans minutes apart) can be off by metres while each match alone
// looks fine (many pairs, small residual). The wheels drift, but over one
// increment their error is small and grows with the path driven. So:
//
//  * Logging gap: an increment whose time span exceeds gap_factor × the
//    log's median span between scans is not matched: the two scans were
//    taken far apart, and relating them is loop closing, not odometry.
//
//  * Consistency: for increment i with wheel motion w_i and matched motion
//    m_i (both (dx, dy, dθ) in the previous robot frame), the difference
//    e_i = m_i − w_i (angle wrapped) is scaled by the increment's path
//    proxy L_i = |w_i,xy| + ρ |w_i,θ| + L̄ (ρ = turn_length, metres per
//    radian of turning in place; L̄ the median L over the log, so that a
//    robot standing still keeps a tolerance): the wheel error's variance
//    grows with the path (a random walk), σ_i² = s² L_i. The scales s_xy,
//    s_θ are measured from the log itself, robustly, as the medians of the
//    normalised differences over the matched increments:
//      s_xy = median(|e_xy| / √L) / √(2 ln 2)   (median of a 2-D Rayleigh = σ √(2 ln 2))
//      s_θ  = median(|e_θ| / √L) / 0.6745        (median of |N(0, σ²)| = 0.6745 σ)
//    — the spread of wheel error and matcher error together, as this log
//    has them (Intel's wheels: centimetres; a simulator's: millimetres). The
//    median stays right with up to half of the matches wrong. Then
//      χ²_i = |e_xy|² / (s_xy² L_i) + e_θ² / (s_θ² L_i)
//    above `gate` (χ² with 3 degrees of freedom) marks the increment
//    inconsistent. Floors keep s from vanishing on perfect simulated data:
//    s_xy ≥ floor_xy / √L̄ and s_θ ≥ floor_θ / √L̄ (the matcher's own
//    resolution over a median increment).
//
// The result says, per increment, what was kept and why; the caller replaces
// the fallbacks' increments (and drops their covariance) and counts them.
#pragma once

#include <Eigen/Core>
#include <cstddef>
#include <optional>
#include <vector>

namespace mspace::scan_matching {

struct WheelCheckOptions {
  /// χ² bound (3 dof) on a match's difference from the wheels in units of
  /// their measured spread: 25.90 = 1e-5 beyond it for a Gaussian; wheel
  /// slips are heavier-tailed, so a match the wheels contradict this much
  /// is wrong far more often than the wheels are. 0: no consistency check.
  double gate = 25.90;
  /// An increment spanning more than this × the median span between scans
  /// crosses a logging gap (0: no gap check).
  double gap_factor = 10.0;
  double turn_length = 1.0;  ///< m of path a radian of turn counts for (the path proxy L)
  double floor_xy = 0.002;   ///< m: smallest translation spread over a median increment
  double floor_theta = 0.001;  ///< rad: smallest heading spread over a median increment
};

enum class IncrementSource {
  matched,       ///< the scan match was kept
  failed,        ///< the matcher itself gave up (too few pairs, large residual): wheels
  gap,           ///< across a logging gap: wheels, not matched
  inconsistent,  ///< the wheels contradict the match beyond their spread: wheels
  fused,         ///< contradicted by the spread, but within both covariances: the two combined (scan_match_fuse_wheels)
};

/// Name for logs and summaries ("matched", "failed", "gap", "inconsistent", "fused").
const char* to_string(IncrementSource source);

/// Which increments span a logging gap: `times` are the scan times; entry i
/// (i ≥ 1) is for the increment from scan i − 1 to i (entry 0 false).
std::vector<bool> logging_gaps(const std::vector<double>& times, double gap_factor);

struct WheelCheckResult {
  std::vector<IncrementSource> source;  ///< per increment, as given, failed/gap kept, inconsistent added
  std::vector<double> chi2;             ///< per increment: χ² of its difference (0 for non-matched)
  double sigma_xy = 0.0;     ///< s_xy (m/√m) measured
  double sigma_theta = 0.0;  ///< s_θ (rad/√m) measured
  double median_path = 0.0;  ///< L̄ (m)
  std::size_t count(IncrementSource s) const;
};

/// Two estimates of one increment combined by their covariances — the
/// corrected wheels w with C_w and a match m with C_m (robot frame):
///   e = m − w (θ wrapped),  S = C_m + C_w,
///   increment w + C_w S⁻¹ e,  covariance C_w − C_w S⁻¹ C_w,
/// so each decides where it is the stronger (a match along a corridor is weak
/// along it, strong across). Nothing when eᵀS⁻¹e exceeds `gate`: the two
/// disagree beyond both covariances (scan_match_fuse_wheels).
struct CombinedIncrement {
  Eigen::Vector3d increment;
  Eigen::Matrix3d covariance;
};
std::optional<CombinedIncrement> combine_increments(const Eigen::Vector3d& w, const Eigen::Matrix3d& C_w,
                                                    const Eigen::Vector3d& m, const Eigen::Matrix3d& C_m, double gate);

/// Checks matched increments against the wheels (see the file comment).
/// `wheel` and `matched` are robot increments, `source` says which of them
/// were matched (entries that are not `matched` are passed through).
WheelCheckResult check_against_wheels(const std::vector<Eigen::Vector3d>& wheel,
                                      const std::vector<Eigen::Vector3d>& matched,
                                      const std::vector<IncrementSource>& source, const WheelCheckOptions& options);

/// What the laser odometry teaches about the wheels, for the increments that
/// must fall back to them (failed matches, logging gaps, vetoed matches).
///
/// Systematic errors, fitted by least squares (weights 1/L, the random-walk
/// variance model above) over the matched increments the check kept:
///   m_xy ≈ (1 + k_s) w_xy                 translation scale (wheel radius)
///   m_θ  ≈ (1 + k_t) w_θ + b · w_x        turn scale (wheel base) and a
///                                         heading drift per metre driven
///                                         (unequal wheels)
/// — the three errors that dominate differential-drive odometry (Borenstein
/// and Feng's UMBmark names the same ones). `correct` removes them.
///
/// Noise: what the correction leaves, e = m − correct(w), as a random walk
/// in distance driven d and angle turned |θ| (wheels err differently on the
/// two: a turn in place scrubs the tyres), with a floor for the matcher's
/// own error:
///   Var(e_x) = Var(e_y) = a_xy d + c_xy |θ| + f_xy,   Var(e_θ) = a_θ d + c_θ |θ| + f_θ,
/// the rates fitted to the squared residuals by non-negative least squares
/// (the method of moments: a variance is a mean of squares). A long
/// increment is composed from sub-steps — the odometry messages logged
/// between the two scans when there are any, else K equal steps of about
/// L̄ — each with its own d_j, |θ_j|, plus the floor once, propagated in the
/// increment's own frame. So a logging gap gets the
/// lateral uncertainty its heading uncertainty causes (σ_lateral ∝ L^{3/2}),
/// not only σ ∝ √L; and the systematic correction is applied to each
/// sub-step, where the drift and turn scale act (on a gap's net increment
/// they would not: the robot may have turned round and come back).
struct WheelModel {
  double scale = 0.0;        ///< k_s
  double turn_scale = 0.0;   ///< k_t
  double bias_per_m = 0.0;   ///< b (rad per m driven forward)
  double sigma_xy = 0.0;     ///< s_xy after the correction (m/√m), robust, as the check measures it
  double sigma_theta = 0.0;  ///< s_θ after the correction (rad/√m)
  /// Variance rates of one error component: per m driven, per rad turned, and a floor per increment.
  struct Rates {
    double per_m = 0.0, per_rad = 0.0, floor = 0.0;
  };
  Rates xy_rates;     ///< of e_x and of e_y (m²/m, m²/rad, m²)
  Rates theta_rates;  ///< of e_θ (rad²/m, rad²/rad, rad²)
  double median_path = 0.0;  ///< L̄ (m)
  double turn_length = 1.0;  ///< m of path per radian of turn (the path proxy)
  std::size_t used = 0;      ///< increments fitted (0: no model; covariance() is then zero)
  /// Uncertainty of (k_s, k_t, b) over a stretch of the log: the spread of
  /// the fit on 8 consecutive stretches of the matched increments (fewer
  /// than 160: the parameters' own squares). covariance_along carries it
  /// through the sub-steps, where it acts on every one alike.
  Eigen::Matrix3d parameter_covariance = Eigen::Matrix3d::Zero();

  /// The wheel increment with the systematic errors removed.
  Eigen::Vector3d correct(const Eigen::Vector3d& wheel) const;
  /// Path proxy |w_xy| + turn_length·|w_θ| of an increment (m).
  double path_of(const Eigen::Vector3d& increment) const;
  /// Covariance of a (corrected) wheel increment driven over a path of
  /// `path` m (at least its own path proxy; more when the robot may have
  /// wandered, e.g. across a logging gap whose odometry was not logged).
  Eigen::Matrix3d covariance(const Eigen::Vector3d& increment, double path) const;
  /// The corrected composition of wheel sub-steps (the odometry messages
  /// between two scans, as increments), and its covariance.
  Eigen::Vector3d correct_along(const std::vector<Eigen::Vector3d>& steps) const;
  Eigen::Matrix3d covariance_along(const std::vector<Eigen::Vector3d>& steps) const;

 private:
  /// Σ for the composition of `steps` (corrected), step j's noise from
  /// `noise_of[j]` (the wheel sub-step its rates are taken at), the floor once.
  Eigen::Matrix3d propagate(const std::vector<Eigen::Vector3d>& steps,
                            const std::vector<Eigen::Vector3d>& noise_of) const;
};

/// Fits the wheel model on the increments `check` kept as matched (the
/// others are left out); `used` = 0 when fewer than 20 are left.
/// Systematic terms the data cannot separate (a log that only drove
/// straight never shows a turn scale) stay at zero.
WheelModel fit_wheel_model(const std::vector<Eigen::Vector3d>& wheel, const std::vector<Eigen::Vector3d>& matched,
                           const WheelCheckResult& check, const WheelCheckOptions& options);

}  // namespace mspace::scan_matching
