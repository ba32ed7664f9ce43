// hline_feature.hpp — the `hline` feature type: a horizontal line on the
// ceiling seen by an upward-looking camera (ICRA §V, eqs. 17–22; T-RO §IV-G,
// Table II).
//
// x_f = {p1^3D, p2^3D}, the end points, always at the same height (the
// horizontal constraint is kept by B̃, see hline_B_dual).
//
// M-space (rows of B, hline_geometry.hpp):
//   dim 0: tentative, not in the estimator;
//   dim 1: the direction only — a rotation in the xy plane about an anchor
//          (the centre when the direction entered; eq. 17);
//   dim 3: + the offset in xy normal to the line and the height (eq. 21).
// The position along the line is never in the M-space: the end points slide
// to the longest observed extent.
//
// Measured by "ceiling_line" (sensors_plugins/ceiling_lines): the plane
// through the camera centre and the observed segment, normal c. The
// innovation is η = c·t̂ (eq. 20) at dims 0 and 1 and (c·t̂, c·r̂) (eqs. 20,
// 22) at dim 3. A measurement does not belong to the line when it is behind
// the camera, when its segment does not overlap the line (give or take
// match_margin) or, while the position is a guess (dims 0, 1), when the
// plane misses the predicted centre by more than match_angle.
//
// Dense information: per observation, the plane (c and its covariance in the
// map), the camera centre, the rays to the two end points (map) and the path
// distance; observations older than max_path_distance are pruned.
//   dims 0, 1: a plane is stored only when it can belong to the line of the
//          stored ones. At these dims c·t̂ is the same for every parallel
//          line, so a parallel neighbour (the tile grid, 0.6 m) would
//          otherwise leave its planes here and the triangulation would mix
//          two lines. The test: seen from the new plane's camera, the stored
//          planes give the slope and the inverse height of the ray to the
//          line (least squares in inverse-height form, estimate_ray, with a
//          prior N(1/initial_height, inverse_height_sigma²) for the height
//          the planes do not fix yet); the new plane's angle must agree with
//          that ray, χ²(1) at consistency_probability;
//   0 → 1  after min_observations whose directions agree within
//          max_direction_spread: the weighted mean direction, with the
//          variance from C_v (inflated by the observed spread) and J_sensor
//          for all observations turning with the sensor (a heading error
//          turns the line with it);
//   1 → 3  once the camera centres spread min_baseline normal to the line,
//          and only if the planes are one line seen well enough:
//          (a) their χ² (inverse-height form, seen from the newest camera)
//              passes at consistency_probability; if not, the plane with the
//              largest deleted residual (its residual against the fit of all
//              the others) is dropped from the dense information;
//          (b) the cameras on either side of every cut across their
//              positions agree (split_test, χ²(2) at consistency_probability)
//              — a line's ray from one camera path can meet a neighbour's
//              planes from a few other viewpoints in a wrong point that (a),
//              summed over many planes, may miss; if not, the smaller side is
//              dropped;
//          (c) the least squares fixes the height: its σ at most
//              max_height_sigma times the height above the camera;
//          (d) the viewing rays to the line (in the plane normal to it)
//              leave no gap wider than max_ray_gap times their angular span:
//              two groups of rays always meet in a point, right or not; rays
//              between them show whether it is right.
//          Otherwise the line stays at dim 1 and waits for more views. Then:
//          offset and height by least squares on the planes, with its
//          covariance, J_sensor (everything moving rigidly with the sensor)
//          and J_own (the dependence on the direction in the M-space);
//   dims 0, 1: the line follows the newest plane at a guessed height
//          (initial_height above the camera), not in the M-space;
//   all dims: the end points slide along the line to the extent of the
//          observed end-point rays (their closest points on the line).
#pragma once

#include <Eigen/Core>
#include <deque>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "hline_geometry.hpp"
#include "mspace/feature.hpp"
#include "mspace/params.hpp"

namespace mspace::hline {

struct HLineConfig {
  int min_observations = 3;
  double max_direction_spread = 0.035;  ///< rad (2.005°; the value the ceiling runs were measured with)
  double initial_height = 2.0;          ///< m above the camera
  double min_baseline = 0.5;            ///< m normal to the line
  double max_path_distance = 10.0;      ///< m of path "distance"
  int max_observations = 100;
  double match_angle = 0.087;  ///< rad (4.985°; the value the ceiling runs were measured with)
  double match_margin = 0.5;   ///< m
  double consistency_probability = 0.99;  ///< of the χ² tests that planes are one line
  double inverse_height_sigma = 0.25;     ///< 1/m, σ of the prior 1/initial_height in those tests
  double max_height_sigma = 0.02;         ///< largest σ of the triangulated height / height above the camera
  double max_ray_gap = 0.4;               ///< largest gap between the viewing rays / their angular span
};

/// One observation kept as dense information.
struct HLineObservation {
  PlaneObservation plane;  ///< c, its covariance, the camera centre (map)
  Vec3 ray_s, ray_e;       ///< unit rays to the end points (map)
  SensorView view;         ///< time, sensor, pose and path distance
};

class HLineFeature : public Feature {
 public:
  /// A line with the given end points (their heights must agree) and
  /// M-space dimension 0, 1 or 3; `anchor` is the point (x, y) the M-space
  /// is taken about (projected onto the line). Throws std::invalid_argument
  /// otherwise.
  HLineFeature(const HLineConfig& config, const Vec6& x_f, int mspace_dim, const Vec2& anchor);

  const CoordLayout& layout() const override;
  Eigen::MatrixXd B() const override;
  Eigen::MatrixXd B_dual() const override;
  bool innovation(const Eigen::VectorXd& x_o, const Measurement& m, Innovation& out) const override;
  /// Dim 0: the direction's variance as a turn of x_f about the centre; none otherwise.
  Eigen::MatrixXd gating_covariance() const override;
  /// Eq. 24, then the two heights are made one number and the anchor follows the line.
  void apply_perturbation(const Eigen::VectorXd& dx_p) override;
  void add_dense_information(const Measurement& m, const SensorView& view) override;
  /// Each end point along the line; at dims 0, 1 also the translations along n and z.
  Eigen::MatrixXd symmetry_directions() const override;
  /// Half the length.
  std::optional<double> footprint_radius() const override;
  /// Dim 1: the direction alone (DrawingItem::Kind::Direction), shown at the
  /// camera centre of the newest stored observation — the end points there
  /// are a guess at initial_height, not a position. Other dims: the generic
  /// drawing (a tentative line is drawn as a tentative feature; at dim 3 the
  /// end points are the line).
  std::optional<FeatureDrawing> drawing() const override;
  /// Version 1: extra = the anchor (x, y); arrays "observations" (a column
  /// per stored observation: the plane's c, C_c column-major and camera
  /// centre o, the rays to the end points, the sensor view packed by
  /// mspace/saved_state.hpp; 66 rows) and, at dim 0, "gating_covariance" (6×6).
  SavedFeature save() const override;
  std::optional<Extension> extend(const SensorView& last_view) override;

  /// Restores the exact anchor, the dense information and the gating
  /// covariance of a saved line (FeatureType::restore).
  void set_saved_state(const Vec2& anchor, std::deque<HLineObservation> observations,
                       const Eigen::Matrix<double, 6, 6>& gating_cov);

  const Vec2& anchor() const { return anchor_; }
  int num_observations() const { return static_cast<int>(observations_.size()); }
  const std::deque<HLineObservation>& observations() const { return observations_; }

 private:
  std::vector<PlaneObservation> planes() const;
  void prune(double path_distance);
  /// Dims 0, 1: onto the newest plane at the guessed height, with direction t.
  void follow_latest(const Vec2& t);
  /// x_f of the line through `point` (x, y) at height z with direction t,
  /// its ends at the extent of the stored end-point rays' closest points on
  /// it; with `grow` (or when no ray gives an extent) the current ends,
  /// projected onto it, count too.
  Vec6 line_at(const Vec2& point, const Vec2& t, double z, bool grow) const;
  /// Spread of the stored camera centres along the normal n.
  double baseline(const Vec2& n) const;
  /// The prior on the inverse height of the tests.
  InverseHeightPrior height_prior() const;
  /// The inverse-height fit of the stored planes seen from q, the weights
  /// taken at the point `at`.
  std::optional<RayEstimate> estimate_from(const LineGeometry& g, const Vec3& q, const Vec3& at) const;
  /// The same seen from the newest camera, fitted a second time with the
  /// weights at the first fit's point; that point in `at`.
  std::optional<RayEstimate> estimate_from_newest(const LineGeometry& g, Vec3& at) const;
  /// Dims 0, 1: whether `plane` agrees with the ray the stored planes give.
  bool consistent_with_stored(const PlaneObservation& plane) const;
  /// 1 → 3, test (a): whether the stored planes pass the χ² test; if not,
  /// drops the one with the largest deleted residual.
  bool residuals_agree(const LineGeometry& g);
  /// 1 → 3, test (b): whether the cameras on either side of every cut agree;
  /// if not, drops the planes on the smaller side.
  bool views_agree(const LineGeometry& g);
  /// 1 → 3, tests (c) and (d) for the line through `point` at height z, its
  /// (o, z) covariance `cov`.
  bool well_conditioned(const LineGeometry& g, const Vec2& point, double z, const Mat2& cov) const;
  std::optional<Extension> extend_direction();
  std::optional<Extension> extend_position();

  HLineConfig config_;
  Vec2 anchor_ = Vec2::Zero();
  std::deque<HLineObservation> observations_;
  Eigen::Matrix<double, 6, 6> gating_cov_ = Eigen::Matrix<double, 6, 6>::Zero();
};

class HLineType : public FeatureType {
 public:
  static std::vector<ParamSpec> param_specs();
  explicit HLineType(const PluginArgs& args);
  explicit HLineType(const HLineConfig& config) : config_(config) {}

  const CoordLayout& layout() const override;
  int max_mspace_dim() const override { return 3; }
  std::vector<int> reachable_dims() const override { return {0, 1, 3}; }
  std::vector<std::string> measurement_kinds() const override;
  /// A tentative line in the measured plane at the guessed height.
  std::unique_ptr<Feature> create(const Measurement& m, const SensorView& view) override;
  /// A line 1–3 m long, 1.5–2.5 m above a slightly tilted camera near it,
  /// and its noise-free measurement (f = 500 px, the extractor's C_v).
  std::optional<FeatureSample> sample(int dim, std::uint64_t seed) const override;
  /// The sample's line seen by a camera moving along the line's horizontal
  /// normal, 0.13 m per observation (the baseline that dim 1 → 3 needs).
  std::optional<SampleObservation> sample_observation(int dim, std::uint64_t seed, int k) const override;
  /// A Segment with both ends at one height (a ceiling line) is the line
  /// through them at dim 3, anchored at its middle; any other shape nullptr.
  std::unique_ptr<Feature> from_true_shape(const TrueShape& shape, const Pose6& x_ms) const override;
  std::unique_ptr<Feature> restore(const SavedFeature& saved) const override;

  const HLineConfig& config() const { return config_; }

 private:
  HLineConfig config_;
};

/// The ceiling_line measurement of the segment (p1, p2) (map) seen from
/// x_ms with focal length f: v = (f x1/z1, f y1/z1, f x2/z2, f y2/z2, f),
/// start = the end with the smaller v0. Used by sample() and the tests.
Eigen::VectorXd project_line(const Vec6& x_f, const Pose6& x_ms, double f);

}  // namespace mspace::hline
