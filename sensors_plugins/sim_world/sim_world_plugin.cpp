// The plugin export of `sim_world` (the one MSPACE_EXPORT_PLUGIN of this library).
#include <memory>

#include "mspace/plugin_export.hpp"
#include "sim_world.hpp"

namespace {

mspace::PluginDescriptor describe() {
  mspace::PluginDescriptor d;
  d.name = "sim_world";
  d.kind = mspace::PluginKind::Source;
  d.description =
      "Deterministic simulated world: point landmarks, a planar robot driving a looping clover "
      "route, noisy odometry and (range, bearing) readings, ground truth";
  d.params = mspace::sim_world::param_specs();
  d.factory = [](const mspace::PluginArgs& args) -> std::unique_ptr<mspace::PluginObject> {
    return std::make_unique<mspace::sim_world::SimWorld>(args);
  };
  return d;
}

}  // namespace

MSPACE_EXPORT_PLUGIN(describe)
