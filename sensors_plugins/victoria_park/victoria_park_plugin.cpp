// The plugin export of `victoria_park` (the one MSPACE_EXPORT_PLUGIN of this library).
#include <memory>

#include "mspace/plugin_export.hpp"
#include "victoria_park.hpp"

namespace {

mspace::PluginDescriptor describe() {
  mspace::PluginDescriptor d;
  d.name = "victoria_park";
  d.kind = mspace::PluginKind::Source;
  d.description =
      "ACFR Victoria Park log: 40 Hz dead reckoning (speed, steering), ACFR tree detections "
      "(range, bearing, diameter) per scan, GPS fixes (x, y) as ground truth";
  d.params = mspace::victoria_park::VictoriaParkSource::param_specs();
  d.factory = [](const mspace::PluginArgs& args) -> std::unique_ptr<mspace::PluginObject> {
    return std::make_unique<mspace::victoria_park::VictoriaParkSource>(args);
  };
  return d;
}

}  // namespace

MSPACE_EXPORT_PLUGIN(describe)
