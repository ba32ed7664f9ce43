// mspace/extractor.hpp — sensor extractors: raw readings → typed measurements v (T-RO eq. 16).
#pragma once

#include <cstdint>
#include <optional>
#include <string>
#include <vector>

#include <Eigen/Core>

#include "mspace/measurement.hpp"
#include "mspace/plugin.hpp"
#include "mspace/scene.hpp"

namespace mspace {

/// One raw reading of one sensor channel, as a data source delivers it.
struct SensorReading {
  std::string channel;     ///< which sensor it belongs to (YAML `channel:`)
  double t = 0.0;          ///< time stamp (s)
  Eigen::MatrixXd values;  ///< rows of numbers: e.g. range/bearing pairs, or a scan
  std::string file;        ///< optional file (e.g. an image) the reading refers to
};

/// A synthetic reading and the true geometry it shows (mspace/scene.hpp):
/// what the extractor ↔ feature contract check feeds to both plugins.
struct SampleScene {
  SensorReading reading;          ///< as a data source would deliver it, noise-free
  Pose6 x_ms = Pose6::Zero();     ///< the sensor pose in the map frame when it was taken
  std::vector<TrueShape> truth;   ///< the shapes the reading shows clearly (map frame)
};

class Extractor : public PluginObject {
 public:
  /// Appends the measurements found in `reading` to `out`.
  virtual void extract(const SensorReading& reading, std::vector<Measurement>& out) = 0;

  /// Conformance support (`mspace check`): a typical valid reading drawn
  /// deterministically from `seed`, so the suite can check the measurements
  /// (finite, symmetric positive-definite C_v, deterministic). The default
  /// (std::nullopt) limits the suite to the checks that need no reading.
  virtual std::optional<SensorReading> sample_reading(std::uint64_t /*seed*/) const { return std::nullopt; }

  /// Conformance support for `mspace check EXTRACTOR.so FEATURE.so`: a
  /// noise-free reading of a few shapes placed deterministically from `seed`,
  /// with those shapes. List only shapes the extractor must find (whole in
  /// view, long or wide enough): the suite fails a listed shape that no
  /// measurement explains, and a measurement that matches no listed shape.
  /// Without sample_reading(), the extractor's own checks use the scene's
  /// reading. The default (std::nullopt) makes the pair check SKIP with that
  /// reason.
  virtual std::optional<SampleScene> sample_scene(std::uint64_t /*seed*/) const { return std::nullopt; }
};

}  // namespace mspace
