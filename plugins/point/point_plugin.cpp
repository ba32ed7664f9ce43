// point_plugin.cpp — the plugin library's one export (see
// mspace/plugin_export.hpp). The feature type itself is in point_feature.cpp.
#include <memory>

#include "mspace/plugin_export.hpp"
#include "point_feature.hpp"

namespace {

mspace::PluginDescriptor describe() {
  mspace::PluginDescriptor d;
  d.name = "point";
  d.kind = mspace::PluginKind::Feature;
  d.description =
      "A 3-D point (T-RO §IV-E), M-space 0 → 3 with B = I, measured by range/bearing/elevation "
      "(initialised after min_observations observations) or by bearings only, e.g. ceiling lamps "
      "(triangulated from min_rays rays with min_parallax_deg of parallax)";
  d.params = mspace::point::PointType::param_specs();
  d.factory = [](const mspace::PluginArgs& args) -> std::unique_ptr<mspace::PluginObject> {
    return std::make_unique<mspace::point::PointType>(args);
  };
  return d;
}

}  // namespace

MSPACE_EXPORT_PLUGIN(describe)
