#include "mspace/log.hpp"
#include "mspace/plugin.hpp"

namespace mspace {

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
