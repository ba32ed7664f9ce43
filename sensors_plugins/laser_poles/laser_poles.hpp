// laser_poles.hpp — the `laser_poles` extractor: poles (tree trunks, posts)
// found in a planar laser scan.
//
// Input: a SensorReading whose `values` is either
//   N × 2 rows (beam angle rad, range m) in the sensor frame, or
//   1 × N ranges (m) at angles start_angle + k·angle_step (e.g. a SICK LMS
//   with 361 beams from −90° to +90°).
// Ranges outside [min_range, max_range] are "no return".
//
// Steps:
//   1. clusters: runs of consecutive returns whose ranges differ by at most
//      max_jump between neighbours;
//   2. a circle fitted to each cluster with at least min_points beams: an
//      algebraic (Kåsa) fit as a start, then Gauss–Newton on the geometric
//      residuals |p_i − c| − ρ;
//   3. kept when min_radius ≤ ρ ≤ max_radius, the RMS residual is at most
//      max_rms_sigmas · range_sigma and the centre lies behind the points;
//   4. covariance of (c, ρ) from range noise σ = range_sigma along the beams
//      (see fit_circle), propagated to
//      the measurement v = (|c|, atan2(c_y, c_x), 2ρ), kind
//      "range_bearing_diameter".
// A partly occluded trunk keeps the points it shows; with fewer than
// min_points it is not reported.
#pragma once

#include <Eigen/Core>
#include <cstdint>
#include <optional>
#include <vector>

#include "mspace/extractor.hpp"
#include "mspace/params.hpp"

namespace mspace::laser_poles {

inline constexpr const char* kRangeBearingDiameter = "range_bearing_diameter";

struct LaserPolesConfig {
  double range_sigma = 0.03;      ///< m, per beam
  double min_range = 0.3;         ///< m
  double max_range = 75.0;        ///< m; longer = no return
  double start_angle = -1.5707963267948966;  ///< rad, for 1 × N scans
  double angle_step = 0.008726646259971648;  ///< rad, for 1 × N scans
  double max_jump = 0.3;          ///< m between neighbouring ranges of one cluster
  int min_points = 3;
  double min_radius = 0.03;       ///< m
  double max_radius = 1.0;        ///< m
  double max_rms_sigmas = 3.0;
};

/// A fitted circle: centre c, radius ρ, covariance of (c_x, c_y, ρ).
struct Circle {
  Eigen::Vector2d centre;
  double radius = 0.0;
  Eigen::Matrix3d covariance;
  double rms = 0.0;  ///< RMS geometric residual (m)
};

/// Least-squares circle through `points` (2 × N, N ≥ 3), given in the frame
/// of the sensor that measured them with range noise σ = sigma along each
/// beam; std::nullopt when the fit does not converge.
std::optional<Circle> fit_circle(const Eigen::Matrix2Xd& points, double sigma);

/// The beams of a reading as (angle, range) rows sorted by angle.
Eigen::MatrixX2d beams_of(const SensorReading& reading, const LaserPolesConfig& config);

/// Index ranges [first, last] of the clusters of valid beams.
std::vector<std::pair<int, int>> clusters(const Eigen::MatrixX2d& beams, const LaserPolesConfig& config);

class LaserPolesExtractor final : public Extractor {
 public:
  static std::vector<ParamSpec> param_specs();
  explicit LaserPolesExtractor(const PluginArgs& args);
  explicit LaserPolesExtractor(const LaserPolesConfig& config) : config_(config) {}

  /// Throws std::runtime_error naming channel and time for a malformed reading.
  void extract(const SensorReading& reading, std::vector<Measurement>& out) override;

  /// Conformance with a feature type: a noise-free 1 × N scan (the
  /// configured start angle and step over 180°) of the trunks of
  /// pole_scene.hpp.
  std::optional<SampleScene> sample_scene(std::uint64_t seed) const override;

  const LaserPolesConfig& config() const { return config_; }

 private:
  /// The measurement of one cluster, if it is a pole.
  std::optional<Measurement> pole_from_cluster(const Eigen::MatrixX2d& beams, int first, int last) const;

  LaserPolesConfig config_;
};

}  // namespace mspace::laser_poles
