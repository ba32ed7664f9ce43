// The plugin export of `laser_poles` (the one MSPACE_EXPORT_PLUGIN of this library).
#include <memory>

#include "laser_poles.hpp"
#include "mspace/plugin_export.hpp"

namespace {

mspace::PluginDescriptor describe() {
  mspace::PluginDescriptor d;
  d.name = "laser_poles";
  d.kind = mspace::PluginKind::Extractor;
  d.description =
      "Poles in a planar laser scan: clusters of neighbouring returns fitted with circles "
      "→ range_bearing_diameter measurements with the fit's covariance";
  d.params = mspace::laser_poles::LaserPolesExtractor::param_specs();
  d.factory = [](const mspace::PluginArgs& args) -> std::unique_ptr<mspace::PluginObject> {
    return std::make_unique<mspace::laser_poles::LaserPolesExtractor>(args);
  };
  return d;
}

}  // namespace

MSPACE_EXPORT_PLUGIN(describe)
