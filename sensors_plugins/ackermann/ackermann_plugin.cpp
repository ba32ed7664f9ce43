// The plugin export of `ackermann` (the one MSPACE_EXPORT_PLUGIN of this library).
#include <memory>

#include "ackermann.hpp"
#include "mspace/plugin_export.hpp"

namespace {

mspace::PluginDescriptor describe() {
  mspace::PluginDescriptor d;
  d.name = "ackermann";
  d.kind = mspace::PluginKind::MotionModel;
  d.description =
      "Car-like vehicle (ACFR Victoria Park model): pose of the rear-axle centre driven by the "
      "rear-left wheel encoder speed and the steering angle, x_d = (speed, steering) held over dt "
      "(T-RO eqs. 25-26)";
  d.params = mspace::ackermann::AckermannModel::param_specs();
  d.factory = [](const mspace::PluginArgs& args) -> std::unique_ptr<mspace::PluginObject> {
    return std::make_unique<mspace::ackermann::AckermannModel>(args);
  };
  return d;
}

}  // namespace

MSPACE_EXPORT_PLUGIN(describe)
