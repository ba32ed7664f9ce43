// doorway_feature.hpp — a `doorway` feature type written against the
// installed mspace SDK only (an example of an out-of-tree plugin).
//
// A doorway is the pair of vertical door-frame edges (jambs), seen by a planar
// scanner as two 2-D points: x_f = {p1, p2}, layout [point2d, point2d]
// (vertical lines, T-RO Appendix, eq. 34). With
//   w = |p2 − p1| (the width), u = (p2 − p1)/w, u⊥ = (−u_y, u_x),
//   c = (p1 + p2)/2 (the centre), α = atan2(u_y, u_x) (the orientation),
// its M-space grows in two steps (reachable dimensions 0, 3, 4):
//   dim 3: (δc, δα) — the width is held fixed: a doorway's width constraint.
//          B  = [ ½I  ½I ; −u⊥ᵀ/w  u⊥ᵀ/w ]            (eq. 10)
//          B̃ = [ I  −(w/2)u⊥ ; I  (w/2)u⊥ ]            (eq. 11)
//   dim 4: (δc, δα, δw) — adds the row [−uᵀ  uᵀ] to B and the column
//          [−u/2 ; u/2] to B̃. B·B̃ = I in both cases (eq. 12).
// While at dim 3, each observation's width (|q2 − q1| of the two jambs in
// the sensor frame, independent of the robot pose) is dense information; once
// `width_observations` are stored, the width enters the estimator with the
// variance of their weighted mean (phase 4, Extension with J_sensor = 0).
//
// Measurement "doorway_jambs": v = (r1, b1, r2, b2), range and bearing of
// both jambs in the sensor frame, jamb 1 first. η = h(x_o) − v (eq. 16) with
// h the polar coordinates of both sensor-frame points, angles wrapped.
#pragma once

#include <Eigen/Core>
#include <deque>
#include <memory>
#include <optional>

#include "mspace/feature.hpp"

namespace doorway {

inline constexpr const char* kJambsKind = "doorway_jambs";

struct DoorwayConfig {
  /// Parameter `jacobians`: false ("analytic") — every Jacobian by hand;
  /// true ("numeric") — J_ηo, J_ηv, the extension's J_sensor and the
  /// measurement Jacobians behind C_new by the SDK's central differences
  /// (mspace/numeric.hpp) of the same functions. Both pass `mspace check`.
  bool numeric = false;
  int min_observations = 3;     ///< observations before a tentative doorway enters the map (dim 3)
  int width_observations = 10;  ///< width observations before the width enters the M-space (dim 4)
  int max_dense = 10;           ///< observations kept while tentative
};

/// Both jambs of v = (r1, b1, r2, b2) as sensor-frame points (q1, q2); J = ∂q/∂v.
Eigen::Vector4d jambs_in_sensor_frame(const Eigen::Vector4d& v, Eigen::Matrix4d* J = nullptr);

/// A stored observation of a tentative doorway.
struct JambObservation {
  Eigen::Vector4d v;
  Eigen::Matrix4d C_v;
  mspace::SensorView view;
};

class DoorwayFeature final : public mspace::Feature {
 public:
  /// A tentative doorway at the back-projection of v seen from `view`.
  DoorwayFeature(const DoorwayConfig& config, const Eigen::Vector4d& v, const Eigen::Matrix4d& C_v,
                 const mspace::SensorView& view);
  /// A doorway from saved state (see save()); throws std::invalid_argument
  /// on state it cannot read.
  DoorwayFeature(const DoorwayConfig& config, const mspace::SavedFeature& saved);

  const mspace::CoordLayout& layout() const override;
  Eigen::MatrixXd B() const override;
  Eigen::MatrixXd B_dual() const override;
  bool innovation(const Eigen::VectorXd& x_o, const mspace::Measurement& m, mspace::Innovation& out) const override;
  Eigen::MatrixXd gating_covariance() const override;
  /// Moves (c, α[, w]) by δx_p and rebuilds the jambs, so the width stays
  /// exactly fixed at dim 3 (first order equal to eq. 24).
  void apply_perturbation(const Eigen::VectorXd& dx_p) override;
  void add_dense_information(const mspace::Measurement& m, const mspace::SensorView& view) override;
  std::optional<mspace::Extension> extend(const mspace::SensorView& last_view) override;
  /// Version 1: extra = (Σ w/σ², Σ 1/σ², count) of the width evidence
  /// gathered at dim 3; arrays "observations" (a column per stored
  /// observation of a tentative doorway: v, C_v column-major, the sensor view
  /// packed by mspace/saved_state.hpp; 65 rows) and, at dim 0,
  /// "gating_covariance" (4×4).
  mspace::SavedFeature save() const override;
  /// map.png: each jamb as a closed 10 cm square (a door-frame post seen from
  /// above) and the opening between them as a segment labelled "door".
  std::optional<mspace::FeatureDrawing> drawing() const override;

 private:
  void place_at(const Eigen::Vector4d& v, const Eigen::Matrix4d& C_v, const mspace::SensorView& view);
  void add_width_evidence(const Eigen::Vector4d& v, const Eigen::Matrix4d& C_v);
  std::optional<mspace::Extension> enter_map();
  std::optional<mspace::Extension> add_width();

  DoorwayConfig config_;
  std::deque<JambObservation> observations_;
  Eigen::Matrix4d gating_cov_ = Eigen::Matrix4d::Zero();
  Eigen::Vector3d width_evidence_ = Eigen::Vector3d::Zero();  ///< Σ w/σ², Σ 1/σ², count
};

class DoorwayType final : public mspace::FeatureType {
 public:
  static std::vector<mspace::ParamSpec> param_specs();
  explicit DoorwayType(const mspace::PluginArgs& args);

  const mspace::CoordLayout& layout() const override;
  int max_mspace_dim() const override { return 4; }
  std::vector<int> reachable_dims() const override { return {0, 3, 4}; }
  std::vector<std::string> measurement_kinds() const override { return {kJambsKind}; }
  std::unique_ptr<mspace::Feature> create(const mspace::Measurement& m, const mspace::SensorView& view) override;
  std::optional<mspace::FeatureSample> sample(int dim, std::uint64_t seed) const override;
  std::unique_ptr<mspace::Feature> restore(const mspace::SavedFeature& saved) const override;

 private:
  DoorwayConfig config_;
};

}  // namespace doorway
