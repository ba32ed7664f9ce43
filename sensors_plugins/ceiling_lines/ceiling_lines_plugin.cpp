// The plugin export of `ceiling_lines` (the one MSPACE_EXPORT_PLUGIN of this library).
#include <memory>

#include "ceiling_lines.hpp"
#include "mspace/plugin_export.hpp"

namespace {

mspace::PluginDescriptor describe() {
  mspace::PluginDescriptor d;
  d.name = "ceiling_lines";
  d.kind = mspace::PluginKind::Extractor;
  d.description =
      "Ceiling-camera images → 'ceiling_line' measurements (ICRA eq. 18: undistorted end points "
      "relative to the principal point and the focal length) by Canny + Hough";
  d.params = mspace::ceiling_lines::CeilingLineExtractor::param_specs();
  d.factory = [](const mspace::PluginArgs& args) -> std::unique_ptr<mspace::PluginObject> {
    return std::make_unique<mspace::ceiling_lines::CeilingLineExtractor>(args);
  };
  return d;
}

}  // namespace

MSPACE_EXPORT_PLUGIN(describe)
