// point_feature.hpp — the `point` feature type (T-RO §IV-E, Tables I and II).
//
// A point feature is one 3-D point, x_f = {x^3D}. Its M-space (eqs. 10–12) is
//   dim 0: empty — a tentative point, not in the estimator;
//   dim 2: the horizontal position, B = [I₂ 0], B̃ = [I₂ 0]ᵀ — a point seen
//          only in the plane of a 2-D sensor; z lies outside the M-space and
//          is held fixed (at the height of the scan plane where the point was
//          initialised) until an elevation is measured;
//   dim 3: the whole point, B = B̃ = I (Table II).
// Three measurement kinds observe it:
//
//  * "range_bearing_elevation", v = (r, b, e): range, bearing and elevation in
//    the sensor frame (a 3-D range sensor);
//  * "range_bearing", v = (r, b): range and bearing in the sensor's x–y plane
//    (a planar sensor: a 2-D laser scanner, the simulated range sensor). It
//    measures the projection of the point on the scan plane,
//    h(p) = (√(x²+y²), atan2(y, x)), and says nothing about its height;
//  * "bearing3d", v = unit vector from the sensor towards the point in the
//    sensor frame, C_v of rank 2 (a camera: the `lamps` extractor sees ceiling
//    lamps this way, T-RO §IV-E and ICRA §VI).
//
// Life cycle with range/bearing[/elevation]:
//   create        → tentative point at the back-projection of the first
//                   measurement (a planar one: in the scan plane), with a
//                   gating covariance so it can be matched;
//   add_dense_…   → each matched observation (v, C_v, sensor view) is stored
//                   (the most recent `max_dense`), and the point follows the
//                   latest back-projection;
//   extend        → after `min_observations` observations the point is
//                   initialised from the latest one: to dim 3 if it measured
//                   an elevation, else to dim 2 (x, y; z stays where the
//                   back-projection put it, in the scan plane);
//   2 → 3         → a point at dim 2 matched by a measurement with an
//                   elevation (range_bearing_elevation) keeps it as dense
//                   information and extends to dim 3 at once (see below).
//
// Initialisation is the standard EKF landmark initialisation: x_f = g(v, x_ms)
// with g the back-projection, so δx_f = J_s δx_ms + J_v δv, and the new
// M-space perturbations are δx_p = B δx_f. The robot part B J_s δx_ms is
// handed to the estimator as Extension::J_sensor (which brings the
// correlation with the robot), the measurement part as
// C_new = B J_v C_v J_vᵀ Bᵀ. The earlier observations only confirm that the
// feature exists (the association gate already checked they agree); they are
// not fused, because their errors are correlated with the robot pose through
// poses the filter no longer holds.
//
// At dim 2 the innovation of a planar measurement is h(x_o) − v (2 rows); a
// range_bearing_elevation measurement contributes its planar part only,
// η = (√(x²+y²) − r cos e, atan2(y, x) − b), since z is not estimated yet. For
// a level sensor neither depends on z; for a tilted one z is the fixed value
// the M-space approximation holds it at (its effect is not in the covariance).
// A bearing3d measurement is not used at dim 2 (innovation() rejects it).
//
// Extension 2 → 3 (elevation): the new coordinate is the height at which the
// measured ray u = R_ms s(b, e) (s the unit direction of bearing b and
// elevation e) passes the vertical line through the estimated (x, y):
//   λ = u_hᵀ(p_h − t_h)/|u_h|²   (closest approach in the horizontal plane),
//   z = t_z + u_z λ,
// with t the sensor position and the subscript h the x–y part. So
//   δz = J_own δx_p,old + J_sensor δx_ms + J_v δv,  J_own = u_z u_hᵀ/|u_h|²,
// and C_new = J_v C_v J_vᵀ (the range is not used: (x, y) already hold the
// distance more precisely). The same measurement's planar part has just
// updated (x, y) through r cos e and b; the noise of e is independent of it
// to first order at small elevations (∂(r cos e)/∂e = −r sin e), which is
// what this neglects.
//
// Life cycle with bearings only (one image gives a direction, not a point):
//   create        → tentative point on the ray at `initial_depth`;
//   add_dense_…   → the dense information is the list of rays: each matched
//                   bearing with its camera pose (hence the camera centre and
//                   the map-frame direction with its angular covariance) and
//                   the path distance. Rays closer than `ray_spacing` of path
//                   distance to the previous stored ray replace the newest one,
//                   at most `max_rays` are kept (the first always). The point
//                   moves to the least-squares intersection of its rays with a
//                   weak prior `initial_depth` ± `initial_depth_sigma` along
//                   the newest ray ("consistent with the last observation",
//                   ICRA §IV), and its gating covariance is that least
//                   squares' covariance: long along the ray while the depth is
//                   unknown, so later bearings of the same lamp pass the gate at
//                   any plausible depth while those of a lamp beside it do not;
//   extend        → once `min_rays` rays are stored and two of them are at
//                   least `min_parallax_deg` apart, the point is triangulated
//                   (rays only, no prior) and enters the estimator at dim 3.
//
// Bearing initialisation: the triangulated point p with covariance C_tri is
// expressed in the frame of the last camera, p = x_ms ⊕ p_s (inverse of
// eq. 7). The estimator gets J_sensor = ∂p/∂x_ms at fixed p_s (the correlation
// with the robot, as if the whole triangulation were one measurement taken
// from the current pose) and C_new = C_tri. The rays' own camera-pose errors
// relative to the current pose are not in C_new.
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

/// The measurement kinds a point feature understands.
inline constexpr const char* kRangeBearingElevation = "range_bearing_elevation";
inline constexpr const char* kRangeBearing = "range_bearing";
inline constexpr const char* kBearing3d = "bearing3d";

/// M-space dimensions of a point: tentative, planar (x, y), whole point.
inline constexpr int kTentativeDim = 0;
inline constexpr int kPlanarDim = 2;
inline constexpr int kFullDim = 3;

/// Points closer than this to the sensor's z axis (m) have no defined
/// bearing: they are neither measured nor initialised.
inline constexpr double kMinAxisDistance = 1e-3;

/// Settings of the `point` feature type.
struct PointConfig {
  // range/bearing[/elevation]
  int min_observations = 3;         ///< observations before a point is initialised
  int max_dense = 10;               ///< observations kept while tentative
  double min_range_for_init = 0.0;  ///< closer observations do not initialise (m)
  // bearing only
  int min_rays = 3;                  ///< rays before a point is triangulated
  int max_rays = 20;                 ///< rays kept while tentative
  double min_parallax_deg = 10.0;    ///< largest angle between two rays needed to triangulate
  double initial_depth = 2.0;        ///< depth along the newest ray until triangulated (m)
  double initial_depth_sigma = 1.0;  ///< std of that depth prior (m)
  double ray_spacing = 0.05;         ///< path distance between stored rays (m)
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

/// The same for a planar measurement v = (r, b): the point in the scan plane,
/// p = (r cos b, r sin b, 0) in the sensor frame; J_v is 3 × 2.
placement::Placement back_project_planar(const Eigen::Vector2d& v, const Pose6& x_ms);

/// h(p) = (√(x²+y²), atan2(y, x)): range and bearing of the projection of a
/// sensor-frame point on the sensor's x–y plane. J (if non-null) = ∂h/∂p (2 × 3,
/// last column 0).
Eigen::Vector2d planar_range_bearing(const Eigen::Vector3d& p, Eigen::Matrix<double, 2, 3>* J = nullptr);

/// The height z at which the ray of the direction (b, e) measured from x_ms
/// passes the vertical line through the map-frame point (x, y) (closest
/// approach in the horizontal plane; see the file comment), with
/// J_xy = ∂z/∂(x, y), J_s = ∂z/∂x_ms and J_v = ∂z/∂(r, b, e) (∂z/∂r = 0).
/// std::nullopt when the ray is within 1e-3 rad of vertical or the line is
/// behind the sensor (λ ≤ 0).
struct RayHeight {
  double z = 0.0;
  Eigen::RowVector2d J_xy;
  Eigen::Matrix<double, 1, 6> J_s;
  Eigen::RowVector3d J_v;
};
std::optional<RayHeight> ray_height(const Eigen::Vector2d& xy, const Eigen::Vector3d& v, const Pose6& x_ms);

// ---------------------------------------------------------------- bearing geometry

/// An orthonormal basis E = (e1 e2) of the plane orthogonal to a unit vector
/// n, smooth in n within each hemisphere (the construction of Duff et al.,
/// "Building an orthonormal basis, revisited", JCGT 2017; s = +1 for n_z ≥ 0,
/// −1 otherwise, so E is defined for every n). With k = 1/(1 + s n_z):
///   e1 = (1 − k n_x², −k n_x n_y, −s n_x),  e2 = (−s k n_x n_y, s(1 − k n_y²), −n_y).
/// dE1, dE2 are ∂e1/∂n and ∂e2/∂n of these formulas (rows: components of e,
/// columns: n_x, n_y, n_z).
struct TangentBasis {
  Eigen::Matrix<double, 3, 2> E;
  Eigen::Matrix3d dE1;
  Eigen::Matrix3d dE2;
};
TangentBasis tangent_basis(const Eigen::Vector3d& n);

/// The bearing innovation (eq. 16) of a predicted sensor-frame point p for a
/// measured direction v: with n = v/|v| and E = tangent_basis(n).E,
///   η = Eᵀ p/|p|   (2 rows: the predicted direction in the measured
///                   direction's tangent plane; 0 when p lies on the ray),
///   J_ηo = Eᵀ (I − p̂p̂ᵀ)/|p|,
///   J_ηv = (p̂ᵀ ∂e_k/∂n)_k (I − nnᵀ)/|v|.
/// With C_v of rank 2 across n, J_ηv C_v J_ηvᵀ ≈ EᵀC_v E is full rank: the
/// rank-2 covariance becomes a 2×2 one. False when |p| or |v| is ~0, or when p
/// is 90° or more away from v (Eᵀp̂ cannot tell p from −p).
bool bearing_innovation(const Eigen::Vector3d& p, const Eigen::Vector3d& v, Innovation& out);

/// A bearing observation as a ray in the map frame.
struct Ray {
  Eigen::Vector3d centre;       ///< the camera centre
  Eigen::Vector3d direction;    ///< unit direction towards the point
  /// Information (inverse covariance) of the direction, rank 2 across it
  /// (1/rad²): a point at depth d off the ray by δ has χ² = δᵀ·information·δ/d².
  Eigen::Matrix3d information;
};

/// The covariance (rad²) of v's direction in its tangent plane, E^T C_v E/|v|²
/// with E = tangent_basis(v/|v|).E. std::nullopt when it is not positive
/// definite (C_v of rank < 2 across v) or v is ~0.
std::optional<Eigen::Matrix2d> tangent_covariance(const Eigen::Vector3d& v, const Eigen::Matrix3d& C_v);

/// The ray of bearing v (covariance C_v, sensor frame) seen from x_ms. Throws
/// std::invalid_argument when tangent_covariance() has none.
Ray make_ray(const Eigen::Vector3d& v, const Eigen::Matrix3d& C_v, const Pose6& x_ms);

/// Largest angle (rad) between the directions of two rays; 0 for fewer than two.
double max_parallax(const std::vector<Ray>& rays);

/// A depth prior along the last ray: (p − c)·u = depth ± sigma.
struct DepthPrior {
  double depth = 0.0;
  double sigma = 0.0;
};

/// The result of triangulate().
struct Triangulation {
  Eigen::Vector3d point;
  Eigen::Matrix3d covariance;
  double min_depth = 0.0;  ///< smallest (p − c_i)·u_i over the rays: > 0 when p is in front of every camera
};

/// Linear least-squares triangulation: the point p minimising
///   Σ_i (p − c_i)ᵀ W_i (p − c_i) [+ ((p − c_L)·u_L − depth)²/σ² with a prior],
/// W_i = information_i / d_i², the perpendicular offsets from the rays weighted
/// by their angular noise scaled to the depth d_i of p along ray i. The depths
/// come from the previous solution (a few reweighting passes; the first uses
/// the prior's depth, or 1). Then p = A⁻¹ Σ W_i c_i and the covariance is A⁻¹,
/// A = Σ W_i (+ u_L u_Lᵀ/σ²). std::nullopt when there is no ray or A is
/// (numerically) singular — e.g. parallel rays and no prior.
std::optional<Triangulation> triangulate(const std::vector<Ray>& rays,
                                         const std::optional<DepthPrior>& prior = std::nullopt);

// ---------------------------------------------------------------- the feature

/// One stored observation of a point (its dense information): a
/// range/bearing/elevation measurement, a planar range/bearing one (`size` 2:
/// v and C_v padded with zeros) or a bearing, with the view it was taken from
/// (camera pose and its covariance, time, sensor, path distance).
struct PointObservation {
  Eigen::Vector3d v;
  Eigen::Matrix3d C_v;
  SensorView view;
  int size = 3;  ///< rows of v: 2 for a planar range/bearing, else 3
  bool planar() const { return size == 2; }
};

class PointFeature : public Feature {
 public:
  /// A tentative point (M-space dim 0) at the back-projection of the
  /// range/bearing/elevation or planar range/bearing `m` seen from `view`
  /// (a placeable measurement: see PointType::create). No observation is
  /// stored yet (the kernel calls add_dense_information right after creation).
  PointFeature(const PointConfig& config, const PointObservation& first);
  /// A tentative point on the ray of a "bearing3d" measurement at
  /// `initial_depth`, its gating covariance from the depth prior. No ray is
  /// stored yet. Throws std::invalid_argument for a measurement
  /// tangent_covariance() rejects.
  PointFeature(const PointConfig& config, const Measurement& bearing, const SensorView& view);
  /// A point at x_f with M-space dimension 0, 2 or 3 and no stored
  /// observations (conformance samples).
  PointFeature(const PointConfig& config, const Eigen::Vector3d& x_f, int mspace_dim);
  /// A point rebuilt from save(): x_f, dimension, the stored observations
  /// and rays and the gating covariance. Throws std::invalid_argument on
  /// state it cannot read.
  PointFeature(const PointConfig& config, const SavedFeature& saved);

  const CoordLayout& layout() const override;

  /// dim 3: B = B̃ = I₃ (Table II); dim 2: B = [I₂ 0], B̃ = Bᵀ; dim 0: 0×3 and 3×0.
  Eigen::MatrixXd B() const override;
  Eigen::MatrixXd B_dual() const override;

  /// range/bearing/elevation: η = h(x_o) − v with the angles wrapped to
  /// (−π, π]; J_ηo = ∂h/∂x_o, J_ηv = −I; at dim 2 its planar part only (see
  /// the file comment). range_bearing: η = planar_range_bearing(x_o) − v,
  /// J_ηv = −I₂. Both false for a point within kMinAxisDistance of the
  /// sensor's z axis.
  /// bearing3d: bearing_innovation(x_o, v) (2 rows); false at dim 2.
  /// False for any other kind or a malformed measurement.
  bool innovation(const Eigen::VectorXd& x_o, const Measurement& m, Innovation& out) const override;

  /// While tentative, the map-frame covariance of x_f: for a
  /// range/bearing[/elevation], of the latest back-projection,
  /// J_v C_v J_vᵀ + J_s C_ms J_sᵀ; for bearings, of the rays' least squares
  /// with the depth prior plus J_s C_ms J_sᵀ of the newest camera (J_s at a
  /// point fixed in that camera's frame). Zero-size once initialised.
  Eigen::MatrixXd gating_covariance() const override;

  /// Stores the observation (see the file comment) and moves a tentative
  /// point. At dim 2 only a range/bearing/elevation is stored (the newest
  /// one: the evidence for 2 → 3); nothing at dim 3. Throws
  /// std::invalid_argument for a measurement of another kind, a malformed
  /// one, or a bearing whose covariance has rank < 2 across it.
  void add_dense_information(const Measurement& m, const SensorView& view) override;

  /// Initialises a tentative point (see the file comment): from
  /// range/bearing[/elevation] observations once `min_observations` are
  /// stored (to dim 3 if the newest has an elevation, else to dim 2), else
  /// from rays once `min_rays` are stored with a parallax of at least
  /// `min_parallax_deg` and a triangulated point in front of every camera (to
  /// dim 3). A point at dim 2 extends to 3 from a stored elevation
  /// observation (ray_height). Always the newest observation must have been
  /// taken at `last_view` (same time stamp and sensor: J_sensor must refer to
  /// the current sensor pose); range/bearing also needs a range of at least
  /// `min_range_for_init` to initialise.
  std::optional<Extension> extend(const SensorView& last_view) override;

  /// Version 2: arrays "observations" and "rays" (one column per stored
  /// observation: the size of v (2 or 3), v and C_v column-major padded to 3
  /// and 3×3, the sensor view packed by mspace/saved_state.hpp; 58 rows) and,
  /// while tentative, "gating_covariance" (3×3). No extra. restore() also
  /// reads version 1 (57 rows: no size, every observation 3 rows).
  SavedFeature save() const override;

  /// Range/bearing[/elevation] observations currently stored (0 at dim 3).
  int num_observations() const { return static_cast<int>(observations_.size()); }
  /// Rays currently stored (0 once initialised).
  int num_rays() const { return static_cast<int>(rays_.size()); }
  /// The stored rays in the map frame, oldest first.
  std::vector<Ray> rays() const;

 private:
  /// Moves the tentative point to the back-projection of the observation
  /// and refreshes the gating covariance.
  void place_at(const PointObservation& o);
  /// Moves the tentative point to the least squares of `rays` with the depth
  /// prior along the last one, seen from `newest`, and refreshes the gating
  /// covariance.
  void place_on_rays(const std::vector<Ray>& rays, const SensorView& newest);
  /// Appends a ray observation, keeping the spacing and the size limit.
  void store_ray(const PointObservation& observation);
  std::optional<Extension> extend_from_range_bearing(const SensorView& last_view);
  std::optional<Extension> extend_from_rays(const SensorView& last_view);
  std::optional<Extension> extend_elevation(const SensorView& last_view);

  PointConfig config_;
  std::deque<PointObservation> observations_;  ///< range/bearing[/elevation]
  std::deque<PointObservation> rays_;          ///< bearings
  Eigen::Matrix3d gating_cov_ = Eigen::Matrix3d::Zero();
};

/// The plugin object: creates point features.
class PointType : public FeatureType {
 public:
  /// The declared parameters: min_observations, max_dense, min_range_for_init
  /// (range/bearing[/elevation]); min_rays, max_rays, min_parallax_deg,
  /// initial_depth, initial_depth_sigma, ray_spacing (bearings).
  static std::vector<ParamSpec> param_specs();

  /// Throws std::invalid_argument when max_dense < min_observations or
  /// max_rays < min_rays (the point could never be initialised).
  explicit PointType(const PluginArgs& args);

  const CoordLayout& layout() const override;
  int max_mspace_dim() const override { return kFullDim; }
  /// {0, 2, 3}.
  std::vector<int> reachable_dims() const override { return {kTentativeDim, kPlanarDim, kFullDim}; }
  /// "range_bearing_elevation", "range_bearing" and "bearing3d".
  std::vector<std::string> measurement_kinds() const override;

  /// A tentative point from a "range_bearing_elevation" or "range_bearing"
  /// measurement (nullptr for a range ≤ 0 or a point within kMinAxisDistance
  /// of the sensor's z axis) or from a "bearing3d" one (nullptr when its covariance has rank < 2
  /// across it); nullptr for other kinds and malformed or non-finite measurements.
  std::unique_ptr<Feature> create(const Measurement& m, const SensorView& view) override;

  /// Conformance sample: a sensor pose with a small tilt and the noise-free
  /// measurement of a point in its field of view: a range/bearing/elevation
  /// 2–8 m away (C_v of the default range_bearing extractor), a planar
  /// range/bearing of such a point in the scan plane, or a bearing within
  /// ~50° of the optical axis, the point 1.5–4 m away (C_v of 2 mrad across
  /// the bearing). dim 0: a tentative point created from that measurement
  /// (seed % 3 picks the kind: extensions 0 → 3, 0 → 2 and, never, from one
  /// repeated bearing, which has no parallax); dim 2: a planar point with a
  /// planar measurement (even seeds) or a range/bearing/elevation, which
  /// extends it 2 → 3 (odd seeds); dim 3: an initialised point with any of the
  /// three (seed % 3). std::nullopt for other dims.
  std::optional<FeatureSample> sample(int dim, std::uint64_t seed) const override;
  /// A point from PointFeature::save() (3 coordinates, dim 0, 2 or 3);
  /// throws std::invalid_argument otherwise. No symmetry directions: at dim 2
  /// z is outside the M-space but a tilted sensor's planar innovation still
  /// depends on it.
  std::unique_ptr<Feature> restore(const SavedFeature& saved) const override;
  /// Conformance (mspace/scene.hpp): the true feature of a Point shape, at
  /// its largest M-space dimension; nullptr for other shapes.
  std::unique_ptr<Feature> from_true_shape(const TrueShape& shape, const Pose6& x_ms) const override;

  const PointConfig& config() const { return config_; }

 private:
  std::optional<FeatureSample> range_bearing_sample(int dim, std::uint64_t seed, bool planar) const;
  std::optional<FeatureSample> bearing_sample(int dim, std::uint64_t seed) const;

  PointConfig config_;
};

}  // namespace mspace::point
