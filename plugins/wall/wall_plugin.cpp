// wall_plugin.cpp — the plugin library's one export (see mspace/plugin_export.hpp).
#include <memory>

#include "mspace/plugin_export.hpp"
#include "wall_feature.hpp"

namespace {

mspace::PluginDescriptor describe() {
  mspace::PluginDescriptor d;
  d.name = "wall";
  d.kind = mspace::PluginKind::Feature;
  d.description =
      "A wall: two 2-D end points (T-RO §IV-F), M-space 0 → 2 (eqs. 14/15) → 3 → 4 as end points are observed "
      "as real ends; measured by line_segment2d; dense scan points slide unmeasured ends along the wall";
  d.params = mspace::wall::WallType::param_specs();
  d.factory = [](const mspace::PluginArgs& args) -> std::unique_ptr<mspace::PluginObject> {
    return std::make_unique<mspace::wall::WallType>(args);
  };
  return d;
}

}  // namespace

MSPACE_EXPORT_PLUGIN(describe)
