// The plugin export of `image_sequence` (the one MSPACE_EXPORT_PLUGIN of this library).
#include <memory>

#include "image_sequence.hpp"
#include "mspace/plugin_export.hpp"

namespace {

mspace::PluginDescriptor describe() {
  mspace::PluginDescriptor d;
  d.name = "image_sequence";
  d.kind = mspace::PluginKind::Source;
  d.description =
      "Camera image sequence folder (images/, frames.csv, odometry.csv, camera.yaml, optional "
      "groundtruth.tum): one step per frame with odometry increments and the image path";
  d.params = mspace::image_sequence::ImageSequence::param_specs();
  d.factory = [](const mspace::PluginArgs& args) -> std::unique_ptr<mspace::PluginObject> {
    return std::make_unique<mspace::image_sequence::ImageSequence>(args);
  };
  return d;
}

}  // namespace

MSPACE_EXPORT_PLUGIN(describe)
