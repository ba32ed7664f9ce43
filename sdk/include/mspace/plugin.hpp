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
#include "mspace/state.hpp"

namespace mspace {

enum class PluginKind : std::uint8_t { Feature, Extractor, Estimator, MotionModel, Source };

/// "feature", "extractor", "estimator", "motion_model", "source".
const char* plugin_kind_name(PluginKind kind);

/// Base of every object a plugin factory returns.
class PluginObject {
 public:
  virtual ~PluginObject() = default;

  // ---- Run-time state, for checkpoints (mspace/state.hpp, docs/persistence.md) --
  //
  // An object whose behaviour depends on more than its parameters and the
  // calls it is given from now on (an estimator's covariance, a simulator's
  // random generators and position in its data) says so with has_state() and
  // saves everything that decides its future: restore_state(save_state())
  // into a fresh instance made from the same parameters must then behave
  // exactly as the saved object, bit for bit. Stateless objects are simply
  // re-created from their parameters on resume. A data source without state
  // is resumed by replay: the kernel re-creates it and discards the steps
  // already processed (exact, because sources are deterministic).
  virtual bool has_state() const { return false; }
  /// The layout version of save_state(); restore_state() refuses others.
  virtual int state_version() const { return 1; }
  /// Default: throws std::logic_error (has_state() without an implementation).
  virtual void save_state(StateWriter& out) const;
  /// Restores what save_state() wrote (at `version`) into an object freshly
  /// made from the same parameters. Throws std::invalid_argument for a version
  /// or an array it cannot read. Default: throws std::logic_error.
  virtual void restore_state(const StateReader& in, int version);
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
