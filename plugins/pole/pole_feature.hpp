// pole_feature.hpp — the `pole` feature type (T-RO §IV-H): a vertical
// cylinder such as a tree trunk or a lamp post.
//
// Coordinates x_f = {radius (Scalar), centre (Point2D)} = (ρ, x, y): the
// radius transforms as a scalar (eq. 9, unchanged by the frame) and the
// centre as a vertical line (eq. 8 with the pseudo-rotation of eq. 34). The
// M-space is empty while the pole is tentative (dim 0, not in the estimator)
// and the whole of x_f once initialised (dim 3, B = B̃ = I).
//
// Measurement "range_bearing_diameter": v = (r, b, d), the range and bearing
// of the trunk centre in the sensor's x–y plane and the trunk diameter, as
// ACFR's tree detector and the `laser_poles` extractor report them.
//
// Life cycle:
//   create        → tentative pole at the back-projection of the detection,
//                   with a gating covariance so the kernel can match it;
//   add_dense_…   → every matched detection is counted and the tentative
//                   pole moves to the newest back-projection;
//   extend        → after `min_detections` detections the pole is
//                   initialised to dim 3 from the newest one (standard EKF
//                   landmark initialisation, see placement.hpp). The earlier
//                   detections only confirm that it is a persistent object.
#pragma once

#include <Eigen/Core>
#include <cstdint>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "mspace/feature.hpp"
#include "mspace/params.hpp"

namespace mspace::pole {

/// The measurement kind a pole understands.
inline constexpr const char* kRangeBearingDiameter = "range_bearing_diameter";

/// Centres closer than this to the sensor (m) have no defined bearing.
inline constexpr double kMinRange = 1e-3;

/// Settings of the `pole` feature type.
struct PoleConfig {
  int min_detections = 3;           ///< consistent detections before initialisation
  double min_range_for_init = 0.0;  ///< closer detections do not initialise (m)
};

/// h(x_o) = (√(x²+y²), atan2(y, x), 2ρ) for sensor-frame coordinates
/// x_o = (ρ, x, y). J (if non-null) = ∂h/∂x_o.
Eigen::Vector3d observe(const Eigen::Vector3d& x_o, Eigen::Matrix3d* J = nullptr);

/// The inverse of h: x_o = (d/2, r cos b, r sin b). J (if non-null) = ∂x_o/∂v.
Eigen::Vector3d sensor_coords(const Eigen::Vector3d& v, Eigen::Matrix3d* J = nullptr);

/// The newest detection of a tentative pole.
struct PoleDetection {
  Eigen::Vector3d v;
  Eigen::Matrix3d C_v;
  SensorView view;
};

class PoleFeature : public Feature {
 public:
  /// A tentative pole (dim 0) at the back-projection of (v, C_v) seen from
  /// `view`; no detection is counted yet (the kernel calls
  /// add_dense_information right after creation).
  PoleFeature(const PoleConfig& config, const Eigen::Vector3d& v, const Eigen::Matrix3d& C_v,
              const SensorView& view);
  /// A pole rebuilt from saved state (see save()): coordinates, dimension 0
  /// or 3, detections counted so far and the gating covariance (dim 0).
  PoleFeature(const PoleConfig& config, const Eigen::Vector3d& x_f, int mspace_dim, int detections,
              const Eigen::Matrix3d& gating_cov);
  /// Sets the newest detection of a restored tentative pole (see save()).
  void set_latest(const PoleDetection& detection) { latest_ = detection; }

  const CoordLayout& layout() const override;

  /// dim 3: B = B̃ = I₃ (§IV-H); dim 0: 0×3 and 3×0.
  Eigen::MatrixXd B() const override;
  Eigen::MatrixXd B_dual() const override;
  /// eq. 24, x_f += B̃ δx_p, with B̃ = I: the same numbers without building B̃
  /// (the kernel applies every update to every feature).
  void apply_perturbation(const Eigen::VectorXd& dx_p) override;

  /// eq. 16: η = h(x_o) − v with the bearing wrapped to (−π, π];
  /// J_ηo = ∂h/∂x_o, J_ηv = −I. False for another kind, a malformed
  /// measurement or a centre within kMinRange of the sensor.
  bool innovation(const Eigen::VectorXd& x_o, const Measurement& m, Innovation& out) const override;

  /// While tentative: covariance of the newest back-projection,
  /// J_v C_v J_vᵀ + J_s C_ms J_sᵀ. Zero-size once initialised.
  Eigen::MatrixXd gating_covariance() const override;

  /// Counts the detection and moves a tentative pole to its back-projection.
  /// Nothing to do once initialised. Throws std::invalid_argument for a
  /// measurement a pole does not understand.
  void add_dense_information(const Measurement& m, const SensorView& view) override;

  /// Version 1: extra = (detections, gating covariance row-major) for a
  /// tentative pole, empty once initialised; array "latest" (57 × 1: v, C_v
  /// column-major, the sensor view packed by mspace/saved_state.hpp) while a
  /// newest detection is kept.
  SavedFeature save() const override;

  /// The estimated trunk radius (x_f's scalar block), for pictures.
  std::optional<double> footprint_radius() const override { return x_[0]; }

  /// Initialises a tentative pole to dim 3 once it has `min_detections`
  /// detections, the newest taken at `last_view` (same time and sensor) at a
  /// range of at least `min_range_for_init`.
  std::optional<Extension> extend(const SensorView& last_view) override;

  int num_detections() const { return detections_; }

 private:
  void place_at(const PoleDetection& detection);

  PoleConfig config_;
  int detections_ = 0;
  std::optional<PoleDetection> latest_;
  Eigen::Matrix3d gating_cov_ = Eigen::Matrix3d::Zero();
};

/// The plugin object: creates pole features.
class PoleType : public FeatureType {
 public:
  /// min_detections, min_range_for_init.
  static std::vector<ParamSpec> param_specs();

  explicit PoleType(const PluginArgs& args);
  explicit PoleType(const PoleConfig& config) : config_(config) {}

  const CoordLayout& layout() const override;
  int max_mspace_dim() const override { return 3; }
  std::vector<std::string> measurement_kinds() const override;

  /// A tentative pole from a "range_bearing_diameter" measurement; nullptr
  /// for other kinds, non-finite values, a range below kMinRange or a
  /// diameter ≤ 0.
  std::unique_ptr<Feature> create(const Measurement& m, const SensorView& view) override;

  /// A pole in front of a random, slightly tilted sensor, 2–30 m away, radius
  /// 0.05–0.6 m, with the exact measurement of it (dims 0 and 3).
  std::optional<FeatureSample> sample(int dim, std::uint64_t seed) const override;
  /// Inverts PoleFeature::save(); throws std::invalid_argument on
  /// inconsistent saved state.
  std::unique_ptr<Feature> restore(const SavedFeature& saved) const override;
  /// Conformance (mspace/scene.hpp): the true feature of a VerticalCylinder shape, at
  /// its largest M-space dimension; nullptr for other shapes.
  std::unique_ptr<Feature> from_true_shape(const TrueShape& shape, const Pose6& x_ms) const override;

  const PoleConfig& config() const { return config_; }

 private:
  PoleConfig config_;
};

}  // namespace mspace::pole
