// hline_geometry.hpp — the maths of the `hline` feature type (a horizontal
// line seen by an upward-looking camera; ICRA §V, eqs. 17–22; T-RO §IV-G and
// Table II). Pure functions, no state: the feature (hline_feature.hpp) decides
// when to call them.
//
// Conventions. x_f = (p1, p2), two 3-D end points at the same height z. With
// L the length, t = (p2 − p1)_xy / L the horizontal direction and
// n = (t_y, −t_x) = (cos γ, sin γ) the horizontal normal of eqs. 17 and 21,
// the direction angle is α = atan2(t_y, t_x) (so dt/dα = −n, dn/dα = t).
// The camera frame has z along the optical axis (looking up), x = image u,
// y = image v; map z is up.
#pragma once

#include <Eigen/Core>
#include <optional>
#include <vector>

#include "mspace/feature.hpp"
#include "mspace/pose.hpp"

namespace mspace::hline {

using Vec2 = Eigen::Vector2d;
using Mat2 = Eigen::Matrix2d;
using Vec6 = Eigen::Matrix<double, 6, 1>;

/// The measurement kind of sensors_plugins/ceiling_lines: v = (v0 … v4),
/// s = (v0, v1, v4) and e = (v2, v3, v4) (ICRA eq. 18 for a z optical axis).
inline constexpr const char* kCeilingLine = "ceiling_line";
inline constexpr int kMeasurementSize = 5;

// ---------------------------------------------------------------- the line

struct LineGeometry {
  Vec3 p1, p2;
  Vec2 t;          ///< horizontal unit direction p1 → p2
  Vec2 n;          ///< (t_y, −t_x): the normal (cos γ, sin γ) of eqs. 17, 21
  double L = 0.0;  ///< length
  double z = 0.0;  ///< height of both end points
};
LineGeometry line_geometry(const Vec6& x_f);

/// x_f of the horizontal line through `point` (x, y) at height z with
/// direction t, its end points at along-line coordinates s1 and s2 from `point`.
Vec6 make_line(const Vec2& point, const Vec2& t, double z, double s1, double s2);

/// Unit direction of angle α, and α of a direction.
Vec2 direction(double alpha);
double angle_of(const Vec2& t);
/// The normal n = (t_y, −t_x) of a horizontal direction t.
inline Vec2 normal_of(const Vec2& t) { return {t.y(), -t.x()}; }
/// (x, y, 0).
inline Vec3 horizontal(const Vec2& v) { return {v.x(), v.y(), 0.0}; }

/// The point of the line through p1 closest to `point` (x, y): its foot.
Vec2 foot_on_line(const Vec6& x_f, const Vec2& point);

// ---------------------------------------------------------------- eqs. 17, 21

/// B (dim × 6) for dim 1 (eq. 17) or 3 (eq. 21), rows: rotation in the xy
/// plane, normal offset in xy (times √2), height (times √2). The rotation
/// and the offset are taken about `anchor`, a point on the line (x, y); with
/// the anchor at the centre these are eqs. 17 and 21 exactly. Any other dim
/// gives 0 × 6.
Eigen::MatrixXd hline_B(const Vec6& x_f, int dim, const Vec2& anchor);
/// B̃ (6 × dim) with B·B̃ = I (eq. 12). Its height column moves both end
/// points equally, so every perturbation keeps the line horizontal.
Eigen::MatrixXd hline_B_dual(const Vec6& x_f, int dim, const Vec2& anchor);

// ---------------------------------------------------------------- eqs. 18–22

/// A measured line in the camera frame: the rays s, e to its end points
/// (eq. 18) and the unit normal c = s×e/|s×e| of the plane through the camera
/// centre and the segment (eq. 19), with J_cv = ∂c/∂v.
struct MeasuredLine {
  Vec3 s, e, c;
  Eigen::Matrix<double, 3, kMeasurementSize> J_cv;
};
/// std::nullopt for a wrongly sized or non-finite v, v4 ≤ 0 or s ∥ e.
std::optional<MeasuredLine> measured_line(const Eigen::VectorXd& v);

/// Eqs. 19–22 for the predicted end points x_o = (ŝ, ê) in the camera frame:
/// η = c·t̂ (eq. 20) and, with rows = 2, η2 = c·r̂ (eq. 22), where
/// t̂ = (ê − ŝ)/|ê − ŝ| and r̂ = (ê + ŝ)/|ê + ŝ|. J_eta_o (rows × 6) and
/// J_eta_v (rows × 5) are analytic.
void line_innovation(const Vec6& x_o, const MeasuredLine& m, int rows, Innovation& out);

/// Along-line coordinate λ (from `point`, along the unit `dir`) of the point
/// of the line closest to the ray o + μu; std::nullopt when the ray runs
/// (nearly) parallel to the line or that point is behind the ray's origin.
/// When the ray meets the line this is where it meets it.
std::optional<double> ray_to_line(const Vec3& o, const Vec3& u, const Vec3& point, const Vec3& dir);

// ---------------------------------------------------------------- dense information

/// One observed plane in the map frame: through the camera centre o and the
/// observed segment, with unit normal c and its covariance C_c (from C_v).
struct PlaneObservation {
  Vec3 c;
  Mat3 C_c;
  Vec3 o;
};

/// The map-frame plane of measurement m seen from x_ms (c = R c_cam,
/// C_c = R J_cv C_v J_cvᵀ Rᵀ, o = the camera centre).
PlaneObservation plane_in_map(const MeasuredLine& m, const Eigen::MatrixXd& C_v, const Pose6& x_ms);

/// The horizontal line of direction t at height z that lies in the plane
/// (c with its component along t removed, so that it holds t): the point
/// (x, y) of it nearest the camera centre o. std::nullopt when the plane is
/// (nearly) horizontal.
std::optional<Vec2> point_in_plane(const PlaneObservation& p, const Vec2& t, double z);

/// ∂(ω × v)/∂x_ms for a map-frame vector v that turns with the sensor: the
/// derivative of a rigid motion of everything observed along with the
/// sensor pose, ω = E(θ, φ, ψ)·δ(θ, φ, ψ) (pose.hpp).
Eigen::Matrix<double, 3, 6> turn_with_sensor(const Vec3& v, const Pose6& x_ms);

/// The weights 1/σ²_αi of the planes' horizontal directions (see
/// fit_direction), σ² from C_c; 0 for a (nearly) horizontal plane.
std::vector<double> direction_weights(const std::vector<PlaneObservation>& planes);

/// The horizontal direction of a set of planes (each contains the line, so
/// t ⟂ c_i and t ⟂ z): weighted mean of the per-plane angles
/// α_i = angle of (−c_y, c_x), each taken modulo π next to t_ref.
/// The weights are held fixed in the Jacobian (Gauss–Newton: their
/// derivatives only multiply the residuals α_i − α).
struct DirectionFit {
  double alpha = 0.0;
  /// Var(α): the formal 1/Σw, inflated by the reduced χ² of the spread when
  /// the directions scatter more than their noise says.
  double variance = 0.0;
  double spread = 0.0;  ///< largest |α_i − α|
  /// ∂α/∂x_ms when all planes turn rigidly with the sensor pose (a yaw
  /// error turns the line with it; translations do nothing).
  Eigen::Matrix<double, 1, 6> J_pose = Eigen::Matrix<double, 1, 6>::Zero();
};
DirectionFit fit_direction(const std::vector<PlaneObservation>& planes, const std::vector<double>& weights,
                           const Vec2& t_ref, const Pose6& x_ms);

/// The weights 1/σ² of the plane residuals c̃_i·(P − o_i) of fit_position
/// at the point P = `at` (x, y, z), σ² propagated from C_c; 0 for a plane
/// that holds no line of direction t.
std::vector<double> plane_weights(const std::vector<PlaneObservation>& planes, const Vec2& t, const Vec3& at);

/// Triangulation of a line of known direction t (dim 1 → 3): weighted linear
/// least squares on the planes c̃_i·(P − o_i) = 0 for P = (pivot + o·n, z),
/// where c̃_i is c_i with its (small) component along t removed (the
/// direction is the M-space's, not re-estimated). The weights are held fixed
/// in the Jacobians (Gauss–Newton, as for fit_direction).
struct PositionFit {
  Vec2 x = Vec2::Zero();    ///< (o, z): offset of the line from the pivot along n, and its height
  Mat2 cov = Mat2::Zero();  ///< (AᵀWA)⁻¹, inflated by the reduced χ² when it exceeds 1
  double chi2 = 0.0;
  /// ∂x/∂x_ms, all planes and camera centres moving rigidly with the sensor.
  Eigen::Matrix<double, 2, 6> J_pose = Eigen::Matrix<double, 2, 6>::Zero();
  /// ∂x/∂α, the direction turning about the pivot.
  Vec2 J_alpha = Vec2::Zero();
};
/// std::nullopt with fewer than two planes or when (o, z) is not determined
/// (no baseline).
std::optional<PositionFit> fit_position(const std::vector<PlaneObservation>& planes, const std::vector<double>& weights,
                                        const Vec2& t, const Vec2& pivot, const Pose6& x_ms);

// ---------------------------------------------------------------- consistency of the planes

/// The least squares of the planes in inverse-height form, to test whether
/// they belong to one line. Seen from a reference camera centre q, the
/// line's point in the vertical plane normal to t is
///   P = q + (s n + ẑ)/ρ,
/// s the slope (horizontal over vertical) of the ray from q and ρ the
/// inverse height above q. A plane's residual times ρ,
///   ρ c̃_i·(P − o_i) = s c̃_i·n + ρ c̃_i·(q − o_i) + c̃_i·ẑ,
/// is linear in x = (s, ρ), with noise ρ σ_r,i. Unlike (offset, height),
/// this cannot drift to the cameras when the planes come from one camera
/// path parallel to the line (all such planes meet there): a plane seen
/// from q itself constrains the slope alone, whatever the height.
struct RayEstimate {
  Vec2 x = Vec2::Zero();    ///< (s, ρ)
  Mat2 cov = Mat2::Zero();  ///< (AᵀWA)⁻¹, not inflated
  double chi2 = 0.0;        ///< Σ w e² over all rows, the prior's included
  int rows = 0;             ///< planes used (nonzero weight, holding the direction), plus the prior
  /// Per plane, in input order: the χ² of its deleted residual — its
  /// residual against the fit of all the other rows, w e²/(1 − h), h its
  /// leverage w A cov Aᵀ (+∞ when the others do not fix x); 0 for a plane
  /// not used.
  std::vector<double> deleted_chi2;
};
/// A Gaussian prior N(ρ, σ²) on the inverse height above q (1/m): with it,
/// planes from one viewpoint fix x too.
struct InverseHeightPrior {
  double rho = 0.5;
  double sigma = 0.25;
};
/// `weights` are those of the residuals in metres (plane_weights); `rho`
/// is the inverse height at which they hold (the noise of ρ r is ρ σ_r).
/// std::nullopt when x is not determined.
std::optional<RayEstimate> estimate_ray(const std::vector<PlaneObservation>& planes, const std::vector<double>& weights,
                                        const Vec2& t, const Vec3& q, double rho,
                                        const std::optional<InverseHeightPrior>& prior = std::nullopt);

/// The point P (x, y, z) of `estimate` (made with t and q).
Vec3 ray_point(const RayEstimate& estimate, const Vec2& t, const Vec3& q);

/// χ² of a plane that is not part of `estimate` (made with t, q and rho),
/// with weight w (plane_weights): its scaled residual squared over its
/// variance, estimate's uncertainty included. For a plane seen from q
/// itself, a test of its angle against the ray's. +∞ for a plane that
/// holds no line of direction t or has zero weight.
double plane_chi2(const PlaneObservation& plane, double w, const Vec2& t, const Vec3& q, double rho,
                  const RayEstimate& estimate);

/// The worst disagreement between the planes seen from either side of a cut
/// across the camera positions. The usable planes are sorted by their
/// camera centre's offset along n; every cut that leaves at least two on
/// either side splits them into two sets, each fitted alone in the
/// inverse-height form of estimate_ray (each with the prior); for one line
/// the difference of the two fits is χ²(2) = Δxᵀ (cov_1 + cov_2)⁻¹ Δx. It
/// finds what the total χ² dilutes over many planes and no single plane
/// shows: one line's ray from a camera path parallel to it meeting a
/// neighbour's planes from a few other viewpoints in a wrong point.
struct SplitTest {
  double chi2 = 0.0;                 ///< the largest over the cuts (0 without a cut)
  std::vector<std::size_t> smaller;  ///< at that cut, the planes (input indices) on the side with fewer
};
SplitTest split_test(const std::vector<PlaneObservation>& planes, const std::vector<double>& weights, const Vec2& t,
                     const Vec3& q, double rho, const InverseHeightPrior& prior);

/// The viewing rays from the camera centres to the point P (x, y, z) of a
/// line of direction t, in the vertical plane normal to t: their angles from
/// the vertical, atan2(n·(P − o_i), P_z − o_z,i). Two groups of rays with a
/// gap between them always meet in a point, right or not; only rays in
/// between can show that it is wrong.
struct RaySpread {
  double span = 0.0;         ///< largest − smallest angle (rad)
  double largest_gap = 0.0;  ///< largest gap between neighbouring angles (rad)
};
RaySpread ray_spread(const std::vector<PlaneObservation>& planes, const Vec2& t, const Vec3& P);

}  // namespace mspace::hline
