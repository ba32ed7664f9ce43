// mspace/feature.hpp — the feature-type plugin interface (T-RO §IV–V).
//
// A FeatureType plugin (one per YAML instance, e.g. `point`) creates Feature
// objects. A Feature owns its full coordinates x_f and its dense information;
// the estimator only ever sees its M-space perturbations δx_p. What is per
// feature type lives here: the parameterisation (layout), B and B̃ for the
// current M-space dimension (eqs. 10–12), the innovation η with J_ηo and J_ηv
// (eq. 16), dense-information handling and M-space extension. Everything else
// — the transform to the sensor frame, J_η,state = J_ηo (J_or  J_of B̃)
// (eq. 30), the estimator — is generic and lives in the SDK and kernel.
#pragma once

#include <cstdint>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include <Eigen/Core>

#include "mspace/coords.hpp"
#include "mspace/measurement.hpp"
#include "mspace/plugin.hpp"
#include "mspace/scene.hpp"

namespace mspace {

/// η(x_o, v) and its Jacobians at the current linearisation point.
struct Innovation {
  Eigen::VectorXd eta;      ///< expected value 0; the EKF applies δx = −K η (eq. 31)
  Eigen::MatrixXd J_eta_o;  ///< ∂η/∂x_o (m × n, n = layout size)
  Eigen::MatrixXd J_eta_v;  ///< ∂η/∂v   (m × dim v)
};

/// New M-space dimensions produced by Feature::extend (phase 4).
///
/// The new perturbations are modelled as
///   δx_p,new = J_sensor · δx_ms + J_own · δx_p,old + w,   w ~ N(0, C_new),
/// where x_ms is the pose of sensor `sensor` at the current step and δx_p,old
/// are the feature's M-space dimensions before the extension. The estimator
/// adds the rows with the covariances and cross-covariances this implies.
struct Extension {
  int new_dims = 0;
  int sensor = 0;
  Eigen::MatrixXd J_sensor;  ///< new_dims × 6 (may be zero-size: no correlation with the robot)
  Eigen::MatrixXd J_own;     ///< new_dims × old dim (may be zero-size)
  Eigen::MatrixXd C_new;     ///< new_dims × new_dims, symmetric positive definite
};

/// One named array of a feature's saved state: a matrix of doubles that map
/// files store to the bit (docs/persistence.md).
struct SavedArray {
  std::string name;
  Eigen::MatrixXd value;
};

/// Everything needed to rebuild a feature that behaves exactly as the saved
/// one: the same innovations, the same future add_dense_information() and
/// extend() results (map files, checkpoints, the conformance round trip).
/// The kernel stores it through kernel/src/persistence.cpp; only the plugin
/// knows what `extra` and `arrays` mean.
struct SavedFeature {
  Eigen::VectorXd coords;  ///< x_f
  int mspace_dim = 0;
  Eigen::VectorXd extra;   ///< type-specific state (e.g. lengths at join time), may be empty
  /// Dense information and any other state, as named arrays (names unique
  /// within a feature, the plugin's own), e.g. one column per stored
  /// observation (mspace/saved_state.hpp packs sensor views).
  std::vector<SavedArray> arrays{};
  /// The plugin's own version of this layout (0 = unversioned); restore()
  /// refuses versions it cannot read.
  int version = 0;

  /// Adds (or replaces) array `name`.
  void put(const std::string& name, Eigen::MatrixXd value) {
    for (SavedArray& a : arrays)
      if (a.name == name) {
        a.value = std::move(value);
        return;
      }
    arrays.push_back({name, std::move(value)});
  }
  /// Array `name`, nullptr when absent.
  const Eigen::MatrixXd* find(const std::string& name) const {
    for (const SavedArray& a : arrays)
      if (a.name == name) return &a.value;
    return nullptr;
  }
};

class Feature;

/// What Feature::drawing() asks map.png to draw, in map coordinates (x, y).
struct DrawingItem {
  enum class Kind : std::uint8_t {
    Polygon,   ///< a closed outline through the columns of `points`
    Segments,  ///< separate segments: columns (0, 1), (2, 3), …
    Points,    ///< a dot at each column
    /// Directions known without a position (e.g. a ceiling line whose
    /// M-space holds its direction only): columns (0, 1), (2, 3), … are
    /// pairs (where to show it, unit direction). The picture draws a glyph of
    /// a fixed size in pixels, not to scale, centred where the pair says —
    /// a place the feature was seen from, not a place it is at — in a style
    /// no placed item has. Build it with direction_item().
    Direction,
  };
  Kind kind = Kind::Points;
  Eigen::Matrix2Xd points;
  std::string label;  ///< written beside the item's first point (may be empty)
};
struct FeatureDrawing {
  std::vector<DrawingItem> items;
  /// Whether nothing of the drawing is placed in the map: every item is a
  /// Direction (a picture then draws no position ellipses for the feature
  /// and leaves it out of its extent and its side view).
  bool direction_only() const;
};

/// The Direction item of the undirected line direction `angle` (rad, from the
/// map's x axis; θ and θ + π are the same), shown at `shown_at` (map x, y),
/// e.g. the sensor position it was last seen from.
DrawingItem direction_item(const Eigen::Vector2d& shown_at, double angle, std::string label = {});

/// Shared coordinates (T-RO §VI): what a feature proposes when one of its
/// coordinate blocks is to be shared with a block of another feature — the
/// common value (e.g. the corner where two walls meet) and its Jacobians with
/// respect to both features' coordinates.
struct JoinProposal {
  Eigen::VectorXd value;    ///< the shared block's coordinates (block size)
  Eigen::MatrixXd J_this;   ///< ∂value/∂x_f of the proposing feature (k × n)
  Eigen::MatrixXd J_other;  ///< ∂value/∂x_f of the other feature (k × n_other)
};

/// A random valid configuration for the conformance suite (`mspace check`):
/// a feature at a given M-space dimension, a sensor pose that sees it and a
/// measurement consistent with it (innovation ≈ 0 up to noise).
struct FeatureSample {
  std::unique_ptr<Feature> feature;
  Pose6 x_ms;
  Measurement measurement;
};

/// The k-th observation of a sample's feature by a moving sensor
/// (FeatureType::sample_observation): where the sensor is and what it measures.
struct SampleObservation {
  Pose6 x_ms;                  ///< sensor pose in the map frame
  double path_distance = 0.0;  ///< SensorView::path_distance of this observation
  Measurement measurement;     ///< consistent with the feature (innovation ≈ 0)
};

class Feature {
 public:
  virtual ~Feature() = default;

  /// The coordinate layout (same for every feature of a type).
  virtual const CoordLayout& layout() const = 0;

  /// x_f in the map frame.
  const Eigen::VectorXd& coords() const { return x_; }
  /// Current M-space dimension (0 = tentative, not in the estimator).
  int mspace_dim() const { return mdim_; }

  /// B(x_f): mdim × n (eq. 10). B̃(x_f): n × mdim (eq. 11). B·B̃ = I (eq. 12).
  virtual Eigen::MatrixXd B() const = 0;
  virtual Eigen::MatrixXd B_dual() const = 0;

  /// Innovation for measurement `m` given the feature's coordinates in the
  /// sensor frame x_o (eq. 16). Returns false when the measurement cannot
  /// belong to this feature (wrong kind, behind the sensor, …).
  virtual bool innovation(const Eigen::VectorXd& x_o, const Measurement& m,
                          Innovation& out) const = 0;

  /// Covariance of x_f along the directions the M-space does not cover,
  /// used only to gate tentative features (n × n; zero-size means none).
  virtual Eigen::MatrixXd gating_covariance() const { return {}; }

  /// eq. 24: x_f += B̃ δx_p. Features that keep constraints or derived data
  /// override and call the base.
  virtual void apply_perturbation(const Eigen::VectorXd& dx_p) { x_ += B_dual() * dx_p; }

  /// Phase 3: store the evidence of a matched (or creating) measurement and
  /// slide coordinates orthogonal to the M-space.
  virtual void add_dense_information(const Measurement& m, const SensorView& view) = 0;

  /// Directions in x_f space (n × s, one per column) along which the
  /// feature can move without changing any innovation at its current M-space
  /// dimension — the symmetries outside the M-space (e.g. sliding unmeasured
  /// wall end points along the wall). Zero columns: none declared.
  virtual Eigen::MatrixXd symmetry_directions() const { return {}; }

  /// For pictures only: the radius (m) of the feature's horizontal footprint
  /// around its point block, e.g. a tree trunk's; std::nullopt draws a dot.
  virtual std::optional<double> footprint_radius() const { return std::nullopt; }

  /// For pictures only (map.png, the frames of output.frames): how the
  /// feature looks from above, in map coordinates (x, y). std::nullopt (the
  /// default) keeps the generic drawing: the point blocks joined in order, or
  /// footprint_radius(). A feature whose M-space holds no position yet (a
  /// direction only) returns Direction items, not its guessed coordinates.
  virtual std::optional<FeatureDrawing> drawing() const { return std::nullopt; }

  // ---- Shared coordinates (T-RO §VI, eq. 33) -------------------------------
  //
  // M-space columns are ordered: the feature's own dimensions first, then one
  // group per shared block in ascending block order (block_size columns each,
  // the identity: the shared point's x, y [, z] perturbation). Extensions add
  // own dimensions (before the shared groups).

  /// Whether block `block` may be shared now (e.g. a wall end point once the
  /// wall is in the map). Default: never.
  virtual bool can_share(int /*block*/) const { return false; }
  /// The common value when this feature's `block` is to be shared with
  /// `other`'s `other_block` (same kind, close together). std::nullopt to
  /// refuse (e.g. two walls that are nearly parallel).
  virtual std::optional<JoinProposal> propose_join(int /*block*/, const Feature& /*other*/,
                                                   int /*other_block*/) const {
    return std::nullopt;
  }
  /// Makes `block` shared: its coordinates become `value`, its M-space columns
  /// the identity, and the own dimensions are redefined. Returns T (new own
  /// dims × old M-space dim): the new own perturbations as a linear function
  /// of the old ones, which the estimator uses to carry the covariance over.
  /// The default throws std::logic_error.
  virtual Eigen::MatrixXd share_block(int block, const Eigen::VectorXd& value);

  /// The feature's whole state — x_f, the M-space dimension and everything
  /// that decides its future behaviour (dense information, gating
  /// covariance, anchors, …) — for map files and checkpoints;
  /// FeatureType::restore inverts it exactly (bit for bit).
  virtual SavedFeature save() const { return SavedFeature{x_, mdim_, {}, {}, 0}; }

  /// Phase 4: add M-space dimensions if the dense information supports it.
  /// The feature updates x_f and its dimension itself and returns what the
  /// estimator must add; std::nullopt when nothing changes.
  virtual std::optional<Extension> extend(const SensorView& last_view) = 0;

  /// The kernel has declared `duplicate` — a feature of the same type — the
  /// same object as this one (a loop closure's pair, or a copy mapped twice
  /// and merged), after the estimator made the two coincide; `duplicate` is
  /// never matched again. Take over the evidence it alone holds (e.g. the
  /// extent a wall's copy saw beyond this wall's ends), so that it is neither
  /// lost nor mapped a third time. Only coordinates outside the M-space may
  /// change (the estimator is not told); the M-space dimension stays.
  /// Default: nothing.
  virtual void absorb(const Feature& /*duplicate*/) {}

 protected:
  Eigen::VectorXd x_;
  int mdim_ = 0;
};

/// The plugin object of a feature type.
class FeatureType : public PluginObject {
 public:
  virtual const CoordLayout& layout() const = 0;
  /// Largest M-space dimension a feature of this type can reach.
  virtual int max_mspace_dim() const = 0;
  /// Every M-space dimension a feature can have, ascending, starting at 0
  /// (e.g. {0, 3} for a point, {0, 2, 3, 4} for a wall).
  virtual std::vector<int> reachable_dims() const { return {0, max_mspace_dim()}; }
  /// Measurement kinds this type accepts (for wiring checks).
  virtual std::vector<std::string> measurement_kinds() const = 0;
  /// A new tentative feature (M-space dimension 0) from an unmatched
  /// measurement; nullptr when the measurement cannot start a feature.
  /// The kernel calls add_dense_information(m, view) on it right after.
  virtual std::unique_ptr<Feature> create(const Measurement& m, const SensorView& view) = 0;

  /// Conformance support: a random valid sample at M-space dimension `dim`,
  /// drawn deterministically from `seed`; std::nullopt when `dim` is not
  /// reachable. The default throws std::logic_error (the suite reports the
  /// type as not checkable).
  virtual std::optional<FeatureSample> sample(int dim, std::uint64_t seed) const;
  /// Conformance support for types that cannot extend from repeated
  /// identical observations (parallax, a baseline, real end points): the
  /// k-th observation (k = 1, 2, …) of the feature of sample(dim, seed) by a
  /// sensor moving as in a run. The suite feeds k = 1, 2, … until the
  /// feature extends. The default (std::nullopt) makes the suite feed the
  /// sample's own measurement from its own pose every time.
  virtual std::optional<SampleObservation> sample_observation(int dim, std::uint64_t seed, int k) const;
  /// Conformance support for `mspace check EXTRACTOR.so FEATURE.so`: the
  /// feature that *is* `shape` (mspace/scene.hpp), as seen by a sensor at
  /// x_ms (e.g. for a wall, which side faces the sensor), at the largest
  /// M-space dimension, so that its innovation compares every component a
  /// measurement has. nullptr when the type does not represent that kind of
  /// shape; the default returns nullptr for every shape (the pair check then
  /// SKIPs, saying so).
  virtual std::unique_ptr<Feature> from_true_shape(const TrueShape& /*shape*/, const Pose6& /*x_ms*/) const {
    return nullptr;
  }
  /// Rebuilds a feature from Feature::save(): restore(f.save()) must behave
  /// exactly as f from then on. Throws std::invalid_argument for state it
  /// cannot read (wrong sizes, unknown version). The default throws
  /// std::logic_error.
  virtual std::unique_ptr<Feature> restore(const SavedFeature& saved) const;
};

}  // namespace mspace
