// range_bearing_plugin.cpp — the plugin library's one export (see
// mspace/plugin_export.hpp). The extractor itself is in range_bearing.cpp.
#include <memory>

#include "mspace/plugin_export.hpp"
#include "range_bearing.hpp"

namespace {

mspace::PluginDescriptor describe() {
  mspace::PluginDescriptor d;
  d.name = "range_bearing";
  d.kind = mspace::PluginKind::Extractor;
  d.description =
      "Rows of (range, bearing, elevation) → 'range_bearing_elevation' point measurements; "
      "2-column rows (a planar sensor) → 'range_bearing' (no elevation)";
  d.params = mspace::range_bearing::RangeBearingExtractor::param_specs();
  d.factory = [](const mspace::PluginArgs& args) -> std::unique_ptr<mspace::PluginObject> {
    return std::make_unique<mspace::range_bearing::RangeBearingExtractor>(args);
  };
  return d;
}

}  // namespace

MSPACE_EXPORT_PLUGIN(describe)
