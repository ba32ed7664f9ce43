#include "mspace/feature_log.hpp"

#include <mutex>
#include <shared_mutex>
#include <unordered_map>

namespace mspace {

namespace {

struct Attachments {
  std::shared_mutex mutex;
  std::unordered_map<const Feature*, Logger*> by_feature;
};

Attachments& attachments() {
  static Attachments a;
  return a;
}

}  // namespace

Logger& feature_log(const Feature& feature) {
  Attachments& a = attachments();
  std::shared_lock lock(a.mutex);
  const auto it = a.by_feature.find(&feature);
  return it != a.by_feature.end() ? *it->second : null_logger();
}

void attach_feature_log(const Feature& feature, Logger* logger) {
  Attachments& a = attachments();
  std::unique_lock lock(a.mutex);
  if (logger != nullptr)
    a.by_feature[&feature] = logger;
  else
    a.by_feature.erase(&feature);
}

}  // namespace mspace
