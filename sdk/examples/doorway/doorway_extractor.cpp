// doorway_extractor.cpp — the `doorway_jambs` extractor: each reading row
// (r1, b1, r2, b2) is one doorway seen by a planar scanner, jamb 1 first.
// Each row becomes a "doorway_jambs" measurement with a diagonal covariance.
#include <cmath>
#include <memory>
#include <random>
#include <stdexcept>
#include <string>

#include "doorway_feature.hpp"
#include "mspace/extractor.hpp"
#include "mspace/plugin_export.hpp"

namespace {

using namespace mspace;

class JambExtractor final : public Extractor {
 public:
  explicit JambExtractor(const PluginArgs& args)
      : range_sigma_(args.params.get_double("range_sigma")),
        bearing_sigma_(args.params.get_double("bearing_sigma_deg") * M_PI / 180.0) {}

  void extract(const SensorReading& reading, std::vector<Measurement>& out) override {
    if (reading.values.rows() == 0) return;
    if (reading.values.cols() != 4)
      throw std::runtime_error("doorway_jambs: reading on '" + reading.channel + "' has " +
                               std::to_string(reading.values.cols()) + " columns, expected 4 (r1 b1 r2 b2)");
    const Eigen::Vector4d var(range_sigma_ * range_sigma_, bearing_sigma_ * bearing_sigma_,
                              range_sigma_ * range_sigma_, bearing_sigma_ * bearing_sigma_);
    for (Eigen::Index row = 0; row < reading.values.rows(); ++row) {
      Measurement m;
      m.kind = doorway::kJambsKind;
      m.v = reading.values.row(row).transpose();
      m.C_v = var.asDiagonal();
      out.push_back(std::move(m));
    }
  }

  // Conformance support: three doorways 2–6 m away.
  std::optional<SensorReading> sample_reading(std::uint64_t seed) const override {
    std::mt19937_64 rng(seed);
    std::uniform_real_distribution<double> range(2, 6), bearing(-1.5, 1.5);
    SensorReading r{"doors", 0.0, Eigen::MatrixXd(3, 4), {}};
    for (int i = 0; i < 3; ++i) r.values.row(i) << range(rng), bearing(rng), range(rng), bearing(rng);
    return r;
  }

 private:
  double range_sigma_, bearing_sigma_;
};

PluginDescriptor describe() {
  PluginDescriptor d;
  d.name = "doorway_jambs";
  d.kind = PluginKind::Extractor;
  d.description = "Rows (r1, b1, r2, b2) of doorway jambs → doorway_jambs measurements";
  d.params = {param_double("range_sigma", 0.03, "range noise std (m)", 1e-6),
              param_double("bearing_sigma_deg", 0.5, "bearing noise std (deg)", 1e-6)};
  d.factory = [](const PluginArgs& args) -> std::unique_ptr<PluginObject> { return std::make_unique<JambExtractor>(args); };
  return d;
}

}  // namespace

MSPACE_EXPORT_PLUGIN(describe)
