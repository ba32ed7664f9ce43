// point_feature.hpp — the `point` feature type (T-RO §IV-E, Tables I and II).
//
// A point feature is one 3-D point, x_f = {x^3D}. Its M-space is either empty
// (dim 0: a tentative point, not in the estimator) or the whole point
// (dim 3, B = I). It is measured by "range_bearing_elevation" measurements
// v = (r, b, e): range, bearing and elevation in the sensor frame.
//
// Life cycle:
//   create        → tentative point at the back-projection of the first
//                   measurement, with a gating covariance so it can be matched;
//   add_dense_…   → each matched observation (v, C_v, sensor view) is stored
//                   (the most recent `max_dense`), and the point follows the
//                   latest back-projection;
//   extend        → after `min_observations` observations the point is
//                   initialised to its full dimension 3 from the latest one.
//
// Initialisation is the standard EKF landmark initialisation: x_f = g(v, x_ms)
// with g the back-projection, so δx_f = J_s δx_ms + J_v δv. The robot part
// J_s δx_ms is handed to the estimator as Extension::J_sensor (which brings
// the correlation with the robot), the measurement part as
// C_new = J_v C_v J_vᵀ. The earlier observations only confirm that the
// feature exists (the association gate already checked they agree); they are
// not fused, because their errors are correlated with the robot pose through
// poses the filter no longer holds.
#pragma once

#include <Eigen/Core>
#include <cstdint>
#include <deque>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "mspace/feature.hpp"
#include "mspace/placement.hpp"
#include "mspace/params.hpp"

namespace mspace::point {

/// The measurement kind a point feature understands.
inline constexpr const char* kRangeBearingElevation = "range_bearing_elevation";

/// Points closer than this to the sensor's z axis (m) have no defined
/// bearing: they are neither measured nor initialised.
inline constexpr double kMinAxisDistance = 1e-3;

/// Settings of the `point` feature type.
struct PointConfig {
  int min_observations = 3;         ///< observations before a point is initialised
  int max_dense = 10;               ///< observations kept while tentative
  double min_range_for_init = 0.0;  ///< closer observations do not initialise (m)
};

/// h(p) = (|p|, atan2(y, x), atan2(z, √(x²+y²))): range, bearing and
/// elevation of a sensor-frame point. J (if non-null) = ∂h/∂p.
Eigen::Vector3d cartesian_to_spherical(const Eigen::Vector3d& p, Eigen::Matrix3d* J = nullptr);

/// The inverse of h: p = r (cos e cos b, cos e sin b, sin e).
/// J (if non-null) = ∂p/∂(r, b, e).
Eigen::Vector3d spherical_to_cartesian(const Eigen::Vector3d& v, Eigen::Matrix3d* J = nullptr);

/// A measurement v taken from sensor pose x_ms, placed in the map frame.
/// x_f = to_map_frame(spherical_to_cartesian(v), x_ms) with its Jacobians
/// J_v = ∂x_f/∂v and J_s = ∂x_f/∂x_ms (mspace/placement.hpp).
placement::Placement back_project(const Eigen::Vector3d& v, const Pose6& x_ms);

/// One stored observation of a tentative point (its dense information).
struct PointObservation {
  Eigen::Vector3d v;
  Eigen::Matrix3d C_v;
  SensorView view;
};

class PointFeature : public Feature {
 public:
  /// A tentative point (M-space dim 0) at the back-projection of (v, C_v)
  /// seen from `view`. No observation is stored yet (the kernel calls
  /// add_dense_information right after creation).
  PointFeature(const PointConfig& config, const Eigen::Vector3d& v, const Eigen::Matrix3d& C_v,
               const SensorView& view);
  /// A point at x_f with M-space dimension 0 or 3 and no stored
  /// observations (map files, FeatureType::restore).
  PointFeature(const PointConfig& config, const Eigen::Vector3d& x_f, int mspace_dim);

  const CoordLayout& layout() const override;

  /// dim 3: B = B̃ = I₃ (Table II); dim 0: 0×3 and 3×0.
  Eigen::MatrixXd B() const override;
  Eigen::MatrixXd B_dual() const override;

  /// η = h(x_o) − v with the angles wrapped to (−π, π]; J_ηo = ∂h/∂x_o,
  /// J_ηv = −I. False for another measurement kind or a point within
  /// kMinAxisDistance of the sensor's z axis.
  bool innovation(const Eigen::VectorXd& x_o, const Measurement& m, Innovation& out) const override;

  /// While tentative: the map-frame covariance of the latest back-projection,
  /// J_v C_v J_vᵀ + J_s C_ms J_sᵀ. Zero-size once initialised.
  Eigen::MatrixXd gating_covariance() const override;

  /// Stores (v, C_v, view), keeping the `max_dense` most recent, and moves a
  /// tentative point to the new back-projection. Nothing to store once
  /// initialised. Throws std::invalid_argument for a non-point measurement.
  void add_dense_information(const Measurement& m, const SensorView& view) override;

  /// Initialises a tentative point to dim 3 once `min_observations` are
  /// stored and the latest was taken at `last_view` (same time stamp and
  /// sensor: J_sensor must refer to the current sensor pose) at a range of at
  /// least `min_range_for_init`. See the file comment for the model.
  std::optional<Extension> extend(const SensorView& last_view) override;

  /// Observations currently stored (0 once initialised).
  int num_observations() const { return static_cast<int>(observations_.size()); }

 private:
  /// Moves the tentative point to the back-projection of v seen from `view`
  /// and refreshes the gating covariance.
  void place_at(const Eigen::Vector3d& v, const Eigen::Matrix3d& C_v, const SensorView& view);

  PointConfig config_;
  std::deque<PointObservation> observations_;
  Eigen::Matrix3d gating_cov_ = Eigen::Matrix3d::Zero();
};

/// The plugin object: creates point features.
class PointType : public FeatureType {
 public:
  /// The declared parameters: min_observations, max_dense, min_range_for_init.
  static std::vector<ParamSpec> param_specs();

  /// Throws std::invalid_argument when max_dense < min_observations (the
  /// point could never be initialised).
  explicit PointType(const PluginArgs& args);

  const CoordLayout& layout() const override;
  int max_mspace_dim() const override { return 3; }
  std::vector<std::string> measurement_kinds() const override;

  /// A tentative point from a "range_bearing_elevation" measurement;
  /// nullptr for other kinds, malformed or non-finite measurements, a
  /// range ≤ 0, or a point within kMinAxisDistance of the sensor's z axis.
  std::unique_ptr<Feature> create(const Measurement& m, const SensorView& view) override;

  /// Conformance sample: a sensor pose with a small tilt, a point 2–8 m away
  /// in its field of view and the noise-free measurement of it (C_v of the
  /// default range_bearing extractor). dim 0: a tentative point created from
  /// that measurement; dim 3: an initialised point. std::nullopt for other dims.
  std::optional<FeatureSample> sample(int dim, std::uint64_t seed) const override;
  /// A point from SavedFeature (3 coordinates, dim 0 or 3, no extra state);
  /// throws std::invalid_argument otherwise. The point's own Feature::save()
  /// is the default one: a point has no state beyond x_f and its dimension
  /// (and no symmetry directions: every coordinate is measured).
  std::unique_ptr<Feature> restore(const SavedFeature& saved) const override;

  const PointConfig& config() const { return config_; }

 private:
  PointConfig config_;
};

}  // namespace mspace::point
