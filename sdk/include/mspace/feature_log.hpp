// mspace/feature_log.hpp — a feature's logger.
//
// Extractors, feature types and every other plugin object get their logger in
// PluginArgs; a Feature is made by its type, not by the kernel, so it gets its
// logger here instead. Inside any Feature member:
//
//   #include "mspace/feature_log.hpp"
//   mspace::feature_log(*this).debug("width ", w, " m from ", n, " observations");
//
// In a run the kernel attaches a logger to every feature right after create()
// or restore(): it writes through the logger of the feature's type instance
// with the feature's id in front ("[D] [walls] #12: …"). A feature nobody
// attached (inside its constructor, in tools, in `mspace check`) logs into
// null_logger(). No layout of the plugin interfaces changes (no ABI change):
// the attachment is kept by the SDK library, keyed by the feature's address.
#pragma once

#include "mspace/log.hpp"

namespace mspace {

class Feature;

/// The logger attached to `feature`, or null_logger() when none is.
Logger& feature_log(const Feature& feature);

/// For the owner of the feature (the kernel): from now on feature_log(feature)
/// returns `logger`, which must stay valid until it is detached; nullptr
/// detaches. Detach before the feature is destroyed (its address may be
/// reused). Thread safe.
void attach_feature_log(const Feature& feature, Logger* logger);

}  // namespace mspace
