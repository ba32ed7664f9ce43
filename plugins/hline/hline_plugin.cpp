// hline_plugin.cpp — the plugin library's one export (see mspace/plugin_export.hpp).
#include <memory>

#include "hline_feature.hpp"
#include "mspace/plugin_export.hpp"

namespace {

mspace::PluginDescriptor describe() {
  mspace::PluginDescriptor d;
  d.name = "hline";
  d.kind = mspace::PluginKind::Feature;
  d.description =
      "A horizontal ceiling line: two 3-D end points at one height (ICRA §V, T-RO §IV-G), M-space 0 → 1 (direction, "
      "eq. 17) → 3 (+ offset and height by triangulation, eq. 21); measured by ceiling_line (eqs. 19–22); end points "
      "slide to the observed extent";
  d.params = mspace::hline::HLineType::param_specs();
  d.factory = [](const mspace::PluginArgs& args) -> std::unique_ptr<mspace::PluginObject> {
    return std::make_unique<mspace::hline::HLineType>(args);
  };
  return d;
}

}  // namespace

MSPACE_EXPORT_PLUGIN(describe)
