// The plugin export of `odometry2d` (the one MSPACE_EXPORT_PLUGIN of this library).
#include <memory>

#include "mspace/plugin_export.hpp"
#include "odometry2d.hpp"

namespace {

mspace::PluginDescriptor describe() {
  mspace::PluginDescriptor d;
  d.name = "odometry2d";
  d.kind = mspace::PluginKind::MotionModel;
  d.description =
      "Planar odometry (x, y, theta): increments (dx, dy, dtheta) in the previous robot frame, "
      "noise growing with distance travelled and angle turned (T-RO eqs. 25-26)";
  d.params = mspace::odometry2d::Odometry2dModel::param_specs();
  d.factory = [](const mspace::PluginArgs& args) -> std::unique_ptr<mspace::PluginObject> {
    return std::make_unique<mspace::odometry2d::Odometry2dModel>(args);
  };
  return d;
}

}  // namespace

MSPACE_EXPORT_PLUGIN(describe)
