// doorway_plugin.cpp — the one export of libmspace-plugin-doorway.so.
#include <memory>

#include "doorway_feature.hpp"
#include "mspace/plugin_export.hpp"

namespace {

mspace::PluginDescriptor describe() {
  mspace::PluginDescriptor d;
  d.name = "doorway";
  d.kind = mspace::PluginKind::Feature;
  d.description = "A doorway: two vertical jambs [point2d, point2d]; M-space 0 → 3 (centre, orientation, width "
                  "fixed) → 4 (width estimated); measured by doorway_jambs";
  d.params = doorway::DoorwayType::param_specs();
  d.factory = [](const mspace::PluginArgs& args) -> std::unique_ptr<mspace::PluginObject> {
    return std::make_unique<doorway::DoorwayType>(args);
  };
  return d;
}

}  // namespace

MSPACE_EXPORT_PLUGIN(describe)
