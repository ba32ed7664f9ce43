// logging.hpp — the kernel's logging: spdlog behind the SDK's Logger interface.
//
// Every plugin instance gets its own logger named after the instance, and the
// kernel logs as "mspace". All of them write to stderr, one line per message:
//   [I] [walls] 12 features in the map
// (level letter T/D/I/W/E, then the logger name). Time stamps are left out on
// purpose: a run's time comes from its data, not from the computer clock. One
// global level applies to all loggers.
#pragma once

#include <memory>
#include <string>

#include "mspace/log.hpp"

namespace mspace::kernel {

/// "trace", "debug", "info", "warn", "error" or "off"; anything else throws
/// std::invalid_argument listing the choices.
LogLevel parse_log_level(const std::string& text);
/// The inverse of parse_log_level.
const char* log_level_name(LogLevel level);

/// Sets the level of every logger, existing and future (default: Info).
void set_log_level(LogLevel level);
LogLevel log_level();

/// A new logger named after a plugin instance (give it to PluginArgs::logger).
std::shared_ptr<Logger> make_instance_logger(const std::string& instance);

/// A logger that writes through `target` with `prefix` in front of every
/// message, e.g. a feature's ("#12: "), attached by FeatureTypeSlot::adopt.
std::shared_ptr<Logger> make_prefixed_logger(std::shared_ptr<Logger> target, std::string prefix);

/// The kernel's own logger, named "mspace": kernel_log().info("loaded ", n, " plugins").
Logger& kernel_log();

}  // namespace mspace::kernel
