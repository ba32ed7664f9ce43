// line_extraction.hpp — line segments from one planar laser scan.
//
// Method (split-and-merge with robust fitting):
//   1. Clustering: consecutive beams with returns belong to the same cluster
//      unless the gap between their points exceeds the adaptive breakpoint
//      distance of Borges & Aldon, r·sin Δφ / sin(λ − Δφ) + 3σ, or a beam
//      with a return outside [min_range, max_range] or more than
//      bridge_no_returns beams without any return lie between them (Δφ then
//      spans them: a dropout inside a wall does not cut it).
//   2. Split: iterative end-point fit — a cluster is split at the point
//      farthest from the chord through its ends while that distance exceeds
//      split_distance.
//   3. Merge: neighbouring pieces of one cluster whose joint fit stays within
//      split_distance are merged again.
//   4. Fit: total least squares; points farther than 3σ from the line are
//      trimmed from the segment's ends (mixed pixels at edges, a corner
//      point). Segments with fewer than min_points inliers, shorter than
//      min_length or with rms residual above max_rms are dropped (clutter:
//      chairs, people, plants).
// Covariance of (ρ, α), from the inliers: σ² is the residual variance (but
// at least range_sigma²); the offset at the centroid has variance σ²/N and
// the direction σ²/Σ s_i² (s along the line from the centroid); ρ = u·c is
// then linearised at the centroid c, var(ρ) = σ²/N + (t·c)²·var(α). Optional
// floors add systematic errors. End points: each end is known to lie between
// its last inlier and where the next beam crosses the line; the variance is
// σ² + gap²/12.
// End classification (mspace/measurements/line_segment2d.hpp) from the neighbouring
// beam beyond each end (past up to bridge_no_returns beams without any
// return, when a usable beam follows): outside the scan → Fov; no return → MaxRange; the
// next segment meets this one at an angle ≥ min_corner_angle within
// corner_distance → Corner; otherwise the line's expected range on that
// beam, ρ / cos(φ − α), against the measured one: shorter by more than
// depth_jump → Occluded, longer → Depth, neither (or a grazing beam) → Unknown.
#pragma once

#include <Eigen/Core>
#include <deque>
#include <optional>
#include <numbers>
#include <vector>

#include "mspace/measurements/line_segment2d.hpp"

namespace mspace::laser_lines {

struct LineConfig {
  double range_sigma = 0.01;          ///< range noise std (m), lower bound of σ
  double min_range = 0.05;            ///< shorter ranges are no return (m)
  double max_range = 30.0;            ///< longer ranges count as no return (m)
  double breakpoint_lambda = 10.0 * std::numbers::pi / 180.0;  ///< λ of the adaptive breakpoint detector (rad)
  /// The range noise of the breakpoint detector's 3σ term when above
  /// range_sigma (the measured noise, laser_lines' range_sigma_from_data); 0:
  /// range_sigma. Trimming and the covariance floor keep range_sigma.
  double breakpoint_sigma = 0.0;
  double split_distance = 0.05;       ///< split/merge threshold (m)
  /// A run of at most this many beams without any return (range 0, negative
  /// or not finite: what the sources write for no-return and error codes)
  /// between two beams on one line does not cut the line (random dropouts),
  /// and an end's class is read from the first usable beam past at most this
  /// many. A return beyond max_range (or below min_range) is never bridged.
  /// 0 (the default): every no-return ends a segment and decides its end
  /// (MaxRange). 2 suits random dropouts (12 % of the beams on a logged SICK,
  /// issue 18: three in a row 0.2 %); README, "Lines through dropouts", has
  /// what it does to lines and to the wall SLAM.
  int bridge_no_returns = 0;
  int min_points = 8;
  double min_length = 0.4;            ///< m
  double max_rms = 0.03;              ///< m
  double depth_jump = 0.15;           ///< m
  double min_corner_angle = 30.0 * std::numbers::pi / 180.0;  ///< rad
  double corner_distance = 0.25;      ///< m
  double max_incidence = 1.309;       ///< beams at more than this from the normal are grazing (rad, 75°)
  double distance_sigma_floor = 0.0;  ///< m, added in quadrature to σ_ρ
  double angle_sigma_floor = 0.0;     ///< rad, added in quadrature to σ_α
};

/// One extracted segment.
struct Segment {
  int first = 0, last = 0;           ///< beam indices of the first and last inlier
  double rho = 0.0, alpha = 0.0;     ///< line, sensor frame
  double s_a = 0.0, s_b = 0.0;       ///< end points along t = (sin α, −cos α)
  Eigen::Matrix4d C = Eigen::Matrix4d::Zero();  ///< covariance of (ρ, α, s_a, s_b)
  line_segment::EndReason end_a = line_segment::EndReason::None;
  line_segment::EndReason end_b = line_segment::EndReason::None;
  Eigen::Matrix2Xd inliers;          ///< in beam order
  double rms = 0.0;
};

/// Segments of a scan given as ranges and bearings in beam order (bearings
/// increasing); a range outside [min_range, max_range] (e.g. 0) is no return.
std::vector<Segment> extract_segments(const Eigen::VectorXd& ranges, const Eigen::VectorXd& bearings,
                                      const LineConfig& config);

/// The range noise σ that one segment's inliers show: the perpendicular
/// residuals of its fitted line, each turned back into range along its beam
/// (÷ cos of the beam's incidence on the line; beams beyond max_incidence are
/// left out), σ̂² = Σ e² / (n − 2). std::nullopt with fewer than 20 such points.
std::optional<double> range_noise_of_segment(const Segment& segment, double max_incidence);

/// The range noise of a laser measured on its scans: the median of the last
/// kWindow segments' estimates (range_noise_of_segment) — robust to segments
/// that are not straight walls (clutter, people) — once kMinSamples are in.
class RangeNoiseTracker {
 public:
  static constexpr std::size_t kWindow = 400;
  static constexpr std::size_t kMinSamples = 20;

  void add(const std::vector<Segment>& segments, double max_incidence);
  /// The median, or std::nullopt before kMinSamples estimates.
  std::optional<double> median() const;
  /// The σ to cut the next scan with: the median where it exceeds `floor`
  /// (the configured range_sigma), otherwise `floor`.
  double sigma(double floor) const { return sigma_above(median(), floor); }
  static double sigma_above(std::optional<double> median, double floor) {
    return median && *median > floor ? *median : floor;
  }
  const std::deque<double>& samples() const { return samples_; }
  void set_samples(std::deque<double> samples) { samples_ = std::move(samples); }

 private:
  std::deque<double> samples_;  ///< newest last
};

}  // namespace mspace::laser_lines
