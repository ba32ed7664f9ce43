// The plugin export of `lamps` (the one MSPACE_EXPORT_PLUGIN of this library).
#include <memory>

#include "lamps.hpp"
#include "mspace/plugin_export.hpp"

namespace {

mspace::PluginDescriptor describe() {
  mspace::PluginDescriptor d;
  d.name = "lamps";
  d.kind = mspace::PluginKind::Extractor;
  d.description =
      "Ceiling-camera images → 'bearing3d' measurements: unit vectors in the camera frame "
      "towards bright compact blobs (lamps: round, square or up to 2:1), with their covariance";
  d.params = mspace::lamps::LampExtractor::param_specs();
  d.factory = [](const mspace::PluginArgs& args) -> std::unique_ptr<mspace::PluginObject> {
    return std::make_unique<mspace::lamps::LampExtractor>(args);
  };
  return d;
}

}  // namespace

MSPACE_EXPORT_PLUGIN(describe)
