// The plugin export of `tree_detections` (the one MSPACE_EXPORT_PLUGIN of this library).
#include <memory>

#include "mspace/plugin_export.hpp"
#include "tree_detections.hpp"

namespace {

mspace::PluginDescriptor describe() {
  mspace::PluginDescriptor d;
  d.name = "tree_detections";
  d.kind = mspace::PluginKind::Extractor;
  d.description =
      "Pass-through of trunks from an external detector: rows (range, bearing, diameter) → "
      "range_bearing_diameter measurements with covariance from the parameters";
  d.params = mspace::tree_detections::TreeDetectionsExtractor::param_specs();
  d.factory = [](const mspace::PluginArgs& args) -> std::unique_ptr<mspace::PluginObject> {
    return std::make_unique<mspace::tree_detections::TreeDetectionsExtractor>(args);
  };
  return d;
}

}  // namespace

MSPACE_EXPORT_PLUGIN(describe)
