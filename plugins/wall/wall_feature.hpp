// wall_feature.hpp — the `wall` feature type (T-RO §IV-F, eqs. 13–15, Tables I
// and II; ICRA §II).
//
// x_f = {x_start^2D, x_end^2D}: the wall's two end points in the map. With
// t = (x_end − x_start)/L the wall's direction and L its length, the normal
// γ = (t_y, −t_x) (eq. 13) points away from the wall surface, towards the side
// the sensor sees it from: a wall is never matched from behind.
//
// M-space (Table II), rows of B in this order:
//   dim 0: tentative, not in the estimator;
//   dim 2: rotation and normal offset, B of eq. 14, B̃ of eq. 15, taken about
//          an anchor: the centre when the line entered the M-space, kept
//          while unmeasured ends slide (otherwise sliding would silently
//          change what the covariance describes);
//   dim 3: + the tangential position of the first end point observed as a
//          real end (start or end, whichever came first);
//   dim 4: + the other one.
// Measured by "line_segment2d" (mspace/measurements/line_segment2d.hpp):
// the innovation is (ρ̂ − ρ, α̂ − α) in the sensor frame, plus ŝ_k − s_k for
// each end point k in the M-space that the measurement marks as real; the
// start ↔ s_a, end ↔ s_b. A measurement whose segment does not overlap the
// wall (within match_margin) does not belong to it.
//
// Dense information: each matched observation's inlier points (in the map
// frame, at the sensor pose of the time), the sensor pose, the path distance
// and the real ends it saw; observations older than max_path_distance of
// travel are pruned. It is used to
//   - extend 0 → 2 after min_observations observations with at least
//     min_points points spanning min_length and spreading at most
//     max_normal_std about their line; the line is initialised from the
//     latest measurement (standard EKF initialisation, like the point);
//   - extend an end point after min_end_observations observations saw it as
//     a real end, within max_end_spread of each other, the latest one now;
//   - slide the end points that are not in the M-space outwards along the
//     wall to the longest extent observed (the M-space is untouched).
//
// Shared corners (T-RO §VI, eq. 33): an end point of a wall in the map may be
// shared with an end point of another line feature (two 2-D blocks) when the
// two lines cross at min_corner_angle or more; the corner is their
// intersection. The wall's M-space columns are then its own dimensions —
// the angle about the corner (the free end's normal displacement, scaled by
// L/L_s, eq. 33; none when both ends are shared) and the free end's
// tangential position if it was measured — followed by two columns per
// shared corner (its x, y; they carry the whole wall along). A shared end is
// never slid.
#pragma once

#include <Eigen/Core>
#include <array>
#include <deque>
#include <memory>
#include <numbers>
#include <optional>
#include <string>
#include <vector>

#include "mspace/feature.hpp"
#include "mspace/params.hpp"

namespace mspace::wall {

struct WallConfig {
  int min_observations = 3;
  int min_points = 20;
  double min_length = 0.5;         ///< m
  double max_normal_std = 0.05;    ///< m
  int min_end_observations = 3;
  double max_end_spread = 0.1;     ///< m
  double max_path_distance = 10.0; ///< m of path "distance"
  int max_observations = 40;
  double match_margin = 0.5;       ///< m
  double min_corner_angle = 30.0 * std::numbers::pi / 180.0;  ///< rad: smallest crossing angle for a shared corner
};

enum End : int { kStart = 0, kEnd = 1 };

/// Predicted line of a wall seen from the sensor: (ρ̂, α̂, ŝ_start, ŝ_end) and
/// J = ∂/∂x_o (4 × 4), x_o = the end points in the sensor frame.
struct PredictedLine {
  Eigen::Vector4d h;
  Eigen::Matrix4d J;
};
PredictedLine predict_line(const Eigen::Vector4d& x_o);

/// Eq. 14/15 and Table II: B (dim × 4) and B̃ (4 × dim) for the wall x_f with
/// the given end points in the M-space (in the order they were added).
/// The rotation (row 1) is about `anchor`, a point on the wall; without it,
/// about the centre as in eq. 14.
Eigen::MatrixXd wall_B(const Eigen::Vector4d& x_f, const std::vector<int>& ends, const Eigen::Vector2d& anchor);
Eigen::MatrixXd wall_B_dual(const Eigen::Vector4d& x_f, const std::vector<int>& ends, const Eigen::Vector2d& anchor);
Eigen::MatrixXd wall_B(const Eigen::Vector4d& x_f, const std::vector<int>& ends);
Eigen::MatrixXd wall_B_dual(const Eigen::Vector4d& x_f, const std::vector<int>& ends);

/// Eq. 33: B (rows) and B̃ (columns) of a wall with shared end points:
/// the angle about the corner (only with exactly one shared end: the free
/// end's normal move scaled by L/L_s), the free end's tangent if `ends` holds
/// it, then two columns per shared end in ascending order (the corner's
/// x, y; with one shared end they move the whole wall).
Eigen::MatrixXd shared_wall_B(const Eigen::Vector4d& x_f, const std::vector<int>& ends,
                              const std::array<bool, 2>& shared, double L_s);
Eigen::MatrixXd shared_wall_B_dual(const Eigen::Vector4d& x_f, const std::vector<int>& ends,
                                   const std::array<bool, 2>& shared, double L_s);

/// Intersection c of the lines through the end points of a and b, with
/// J_a = ∂c/∂a and J_b = ∂c/∂b (2 × 4 each). std::nullopt when the lines
/// cross at less than min_angle.
struct LineIntersection {
  Eigen::Vector2d point;
  Eigen::Matrix<double, 2, 4> J_a, J_b;
};
std::optional<LineIntersection> intersect_lines(const Eigen::Vector4d& a, const Eigen::Vector4d& b, double min_angle);

/// How the wall's 2-D M-space (rotation, normal offset; eq. 14) responds to
/// the measured line (ρ, α) and to the sensor pose x_ms when the wall is
/// placed on the measured line: δx_p = J_v δ(ρ, α) + J_s δx_ms (planar sensor).
void line_placement_jacobians(const Eigen::Vector4d& x_f, double alpha, const Pose6& x_ms,
                              Eigen::Matrix2d& J_v, Eigen::Matrix<double, 2, 6>& J_s);

/// The wall on line (ρ, α) seen from x_ms, with its ends where the map
/// points `ends_along` project onto it.
Eigen::Vector4d place_on_line(double rho, double alpha, const Pose6& x_ms, const Eigen::Vector2d& start_near,
                              const Eigen::Vector2d& end_near);

/// One observation kept as dense information.
struct WallObservation {
  Eigen::Matrix2Xd points;  ///< inliers in the map frame
  Eigen::Vector4d v;
  Eigen::Matrix4d C_v;
  std::uint32_t flags = 0;
  SensorView view;
  std::array<std::optional<Eigen::Vector2d>, 2> real_end;  ///< map position of real start / end
};

class WallFeature : public Feature {
 public:
  /// A wall with the given coordinates and end points in the M-space; mspace_dim
  /// = 0 (tentative) or 2 + ends.size().
  WallFeature(const WallConfig& config, const Eigen::Vector4d& x_f, int mspace_dim, std::vector<int> ends);

  const CoordLayout& layout() const override;
  Eigen::MatrixXd B() const override;
  Eigen::MatrixXd B_dual() const override;
  bool innovation(const Eigen::VectorXd& x_o, const Measurement& m, Innovation& out) const override;
  Eigen::MatrixXd gating_covariance() const override;
  void apply_perturbation(const Eigen::VectorXd& dx_p) override;
  void add_dense_information(const Measurement& m, const SensorView& view) override;
  Eigen::MatrixXd symmetry_directions() const override;
  /// Version 1: extra = (measured ends…, start shared, end shared, L_s,
  /// anchor x, anchor y); arrays "observations" (a column per stored
  /// observation: v, C_v column-major, flags, the sensor view packed by
  /// mspace/saved_state.hpp, the real start (seen, x, y), the real end (seen,
  /// x, y), its number of points; 73 rows), "points" (2 × all their inlier
  /// points, in order) and, while tentative, "gating_covariance" (4×4).
  SavedFeature save() const override;
  std::optional<Extension> extend(const SensorView& last_view) override;
  /// Takes a merged copy's observations (interleaved by path distance, then
  /// pruned as usual) and slides the free ends over its extent.
  void absorb(const Feature& duplicate) override;
  bool can_share(int block) const override;
  std::optional<JoinProposal> propose_join(int block, const Feature& other, int other_block) const override;
  Eigen::MatrixXd share_block(int block, const Eigen::VectorXd& value) override;

  const std::vector<int>& mspace_ends() const { return ends_; }
  /// The point the M-space rotation is about (the centre when the line entered).
  const Eigen::Vector2d& anchor() const { return anchor_; }
  void set_anchor(const Eigen::Vector2d& anchor);
  int num_observations() const { return static_cast<int>(observations_.size()); }
  const std::array<bool, 2>& shared_ends() const { return shared_; }
  /// Length of the wall when its first end was shared (L_s of eq. 33).
  double shared_length() const { return L_s_; }
  /// Restores sharing (map files): the ends shared and L_s.
  void set_shared(const std::array<bool, 2>& shared, double L_s);
  /// Restores the dense information and the gating covariance (map files).
  void set_dense(std::deque<WallObservation> observations, const Eigen::Matrix4d& gating_cov);

 private:
  bool in_mspace(int end) const;
  /// The end's position is a state dimension (measured or shared): never slid.
  bool fixed_end(int end) const { return in_mspace(end) || shared_[end]; }
  bool any_shared() const { return shared_[kStart] || shared_[kEnd]; }
  int own_dims() const;
  void follow_latest();          ///< tentative: onto the newest observed line
  void slide_ends();             ///< unmeasured ends outwards to the observed extent
  void prune(double path_distance);
  std::optional<Extension> extend_line();
  std::optional<Extension> extend_ends();

  WallConfig config_;
  std::vector<int> ends_;  ///< ends in the M-space, in the order added
  std::deque<WallObservation> observations_;
  Eigen::Matrix4d gating_cov_ = Eigen::Matrix4d::Zero();
  /// Rotation pivot of the M-space (a point on the wall). It stays put when
  /// unmeasured ends slide, so δx_p keeps its meaning (see wall_B).
  Eigen::Vector2d anchor_ = Eigen::Vector2d::Zero();
  std::array<bool, 2> shared_ = {false, false};  ///< start / end shared with another feature
  double L_s_ = 0.0;                              ///< length at the first join (eq. 33)
};

class WallType : public FeatureType {
 public:
  static std::vector<ParamSpec> param_specs();
  explicit WallType(const PluginArgs& args);
  explicit WallType(const WallConfig& config) : config_(config) {}

  const CoordLayout& layout() const override;
  int max_mspace_dim() const override { return 4; }
  std::vector<int> reachable_dims() const override { return {0, 2, 3, 4}; }
  std::vector<std::string> measurement_kinds() const override;
  std::unique_ptr<Feature> create(const Measurement& m, const SensorView& view) override;
  std::optional<FeatureSample> sample(int dim, std::uint64_t seed) const override;
  /// The sample's line seen again from the same pose, with both ends real
  /// (the sample's own measurement marks the ends outside the M-space as
  /// occluded): the ends extend 2 → 3/4 and 3 → 4.
  std::optional<SampleObservation> sample_observation(int dim, std::uint64_t seed, int k) const override;
  std::unique_ptr<Feature> restore(const SavedFeature& saved) const override;
  /// Conformance (mspace/scene.hpp): the true feature of a Segment shape, at
  /// its largest M-space dimension; nullptr for other shapes.
  std::unique_ptr<Feature> from_true_shape(const TrueShape& shape, const Pose6& x_ms) const override;

  const WallConfig& config() const { return config_; }

 private:
  WallConfig config_;
};

}  // namespace mspace::wall
