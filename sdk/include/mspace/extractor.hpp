// mspace/extractor.hpp — sensor extractors: raw readings → typed measurements v (T-RO eq. 16).
#pragma once

#include <cstdint>
#include <optional>
#include <string>
#include <vector>

#include <Eigen/Core>

#include "mspace/measurement.hpp"
#include "mspace/plugin.hpp"

namespace mspace {

/// One raw reading of one sensor channel, as a data source delivers it.
struct SensorReading {
  std::string channel;     ///< which sensor it belongs to (YAML `channel:`)
  double t = 0.0;          ///< time stamp (s)
  Eigen::MatrixXd values;  ///< rows of numbers: e.g. range/bearing pairs, or a scan
  std::string file;        ///< optional file (e.g. an image) the reading refers to
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
};

}  // namespace mspace
