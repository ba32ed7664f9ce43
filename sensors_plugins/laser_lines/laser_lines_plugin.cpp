// The plugin export of `laser_lines` (the one MSPACE_EXPORT_PLUGIN of this library).
#include <memory>

#include "laser_lines.hpp"
#include "mspace/plugin_export.hpp"

namespace {

mspace::PluginDescriptor describe() {
  mspace::PluginDescriptor d;
  d.name = "laser_lines";
  d.kind = mspace::PluginKind::Extractor;
  d.description =
      "Line segments from a planar laser scan (adaptive breakpoints, split-and-merge, trimmed total least "
      "squares): line_segment2d measurements (rho, alpha, s_a, s_b) with covariance from the inliers, the "
      "inlier points as dense information and real-end flags (corner / depth discontinuity)";
  d.params = mspace::laser_lines::LaserLinesExtractor::param_specs();
  d.factory = [](const mspace::PluginArgs& args) -> std::unique_ptr<mspace::PluginObject> {
    return std::make_unique<mspace::laser_lines::LaserLinesExtractor>(args);
  };
  return d;
}

}  // namespace

MSPACE_EXPORT_PLUGIN(describe)
