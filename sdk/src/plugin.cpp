#include "mspace/abi.hpp"
#include "mspace/log.hpp"
#include "mspace/plugin.hpp"

#include <stdexcept>

namespace mspace {

const char* sdk_library_abi_tag() { return MSPACE_ABI_TAG; }

const char* plugin_kind_name(PluginKind kind) {
  switch (kind) {
    case PluginKind::Feature: return "feature";
    case PluginKind::Extractor: return "extractor";
    case PluginKind::Estimator: return "estimator";
    case PluginKind::MotionModel: return "motion_model";
    case PluginKind::Source: return "source";
  }
  return "?";
}

void PluginObject::save_state(StateWriter& /*out*/) const {
  throw std::logic_error("this plugin object does not implement save_state()");
}

void PluginObject::restore_state(const StateReader& /*in*/, int /*version*/) {
  throw std::logic_error("this plugin object does not implement restore_state()");
}

namespace {
class NullLogger final : public Logger {
 public:
  void write(LogLevel, std::string_view) override {}
  bool enabled(LogLevel) const override { return false; }
};
}  // namespace

Logger& null_logger() {
  static NullLogger logger;
  return logger;
}

}  // namespace mspace
