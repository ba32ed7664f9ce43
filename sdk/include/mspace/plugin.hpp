// mspace/plugin.hpp — what every plugin library describes about itself.
//
// A plugin library exports exactly one descriptor (see plugin_export.hpp):
// its name (what YAML's `plugin:` key names), its kind, the SDK ABI tag it was
// built with, a description, its parameters and a factory. The kernel creates
// one object per configured instance through the factory and casts it to the
// interface of the declared kind (FeatureType, Extractor, Estimator,
// MotionModel or DataSource).
#pragma once

#include <memory>
#include <string>
#include <vector>

#include "mspace/log.hpp"
#include "mspace/params.hpp"

namespace mspace {

enum class PluginKind : std::uint8_t { Feature, Extractor, Estimator, MotionModel, Source };

/// "feature", "extractor", "estimator", "motion_model", "source".
const char* plugin_kind_name(PluginKind kind);

/// Base of every object a plugin factory returns.
class PluginObject {
 public:
  virtual ~PluginObject() = default;
};

/// What the factory receives: the validated parameters, the instance's name
/// from the YAML and its logger (valid for the object's lifetime).
struct PluginArgs {
  std::string instance_name;
  Params params;
  Logger* logger = nullptr;
  Logger& log() const { return logger != nullptr ? *logger : null_logger(); }
};

using PluginFactory = std::unique_ptr<PluginObject> (*)(const PluginArgs& args);

struct PluginDescriptor {
  std::string name;
  PluginKind kind = PluginKind::Feature;
  std::string abi_tag;  ///< filled by MSPACE_EXPORT_PLUGIN with MSPACE_ABI_TAG
  std::string description;
  std::vector<ParamSpec> params;
  PluginFactory factory = nullptr;
};

}  // namespace mspace
