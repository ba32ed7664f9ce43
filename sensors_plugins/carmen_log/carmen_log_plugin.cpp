// The plugin export of `carmen_log` (the one MSPACE_EXPORT_PLUGIN of this library).
#include <memory>

#include "carmen_log.hpp"
#include "mspace/plugin_export.hpp"

namespace {

mspace::PluginDescriptor describe() {
  mspace::PluginDescriptor d;
  d.name = "carmen_log";
  d.kind = mspace::PluginKind::Source;
  d.description =
      "2-D laser logs: CARMEN FLASER/ROBOTLASER1/ODOM (CLF or GMapping-written) or the Intel merged scan "
      "table; one step per scan with the planar odometry increment, a (range, bearing) reading per beam "
      "(range 0 = no return) and the corrected pose as ground truth when present";
  d.params = mspace::carmen_log::CarmenLogSource::param_specs();
  d.factory = [](const mspace::PluginArgs& args) -> std::unique_ptr<mspace::PluginObject> {
    return std::make_unique<mspace::carmen_log::CarmenLogSource>(args);
  };
  return d;
}

}  // namespace

MSPACE_EXPORT_PLUGIN(describe)
