// pole_plugin.cpp — the plugin library's one export (see
// mspace/plugin_export.hpp). The feature type itself is in pole_feature.cpp.
#include <memory>

#include "mspace/plugin_export.hpp"
#include "pole_feature.hpp"

namespace {

mspace::PluginDescriptor describe() {
  mspace::PluginDescriptor d;
  d.name = "pole";
  d.kind = mspace::PluginKind::Feature;
  d.description =
      "A vertical cylinder (tree trunk, post; T-RO §IV-H): radius + 2-D centre, M-space 0 → 3 with "
      "B = I, measured by range/bearing/diameter; initialised after min_detections detections";
  d.params = mspace::pole::PoleType::param_specs();
  d.factory = [](const mspace::PluginArgs& args) -> std::unique_ptr<mspace::PluginObject> {
    return std::make_unique<mspace::pole::PoleType>(args);
  };
  return d;
}

}  // namespace

MSPACE_EXPORT_PLUGIN(describe)
