#include "logging.hpp"

#include <atomic>
#include <stdexcept>

#include <spdlog/logger.h>
#include <spdlog/sinks/stdout_sinks.h>

namespace mspace::kernel {

namespace {

struct LevelName {
  LogLevel level;
  const char* name;
};
constexpr LevelName kLevelNames[] = {{LogLevel::Trace, "trace"}, {LogLevel::Debug, "debug"}, {LogLevel::Info, "info"},
                                     {LogLevel::Warn, "warn"},   {LogLevel::Error, "error"}, {LogLevel::Off, "off"}};

std::atomic<LogLevel> g_level{LogLevel::Info};

spdlog::level::level_enum to_spdlog(LogLevel level) {
  switch (level) {
    case LogLevel::Trace: return spdlog::level::trace;
    case LogLevel::Debug: return spdlog::level::debug;
    case LogLevel::Info: return spdlog::level::info;
    case LogLevel::Warn: return spdlog::level::warn;
    case LogLevel::Error: return spdlog::level::err;
    case LogLevel::Off: return spdlog::level::off;
  }
  return spdlog::level::info;
}

/// The one stderr sink every logger shares, so lines never interleave.
spdlog::sink_ptr stderr_sink() {
  static const spdlog::sink_ptr sink = [] {
    auto s = std::make_shared<spdlog::sinks::stderr_sink_mt>();
    s->set_pattern("[%L] [%n] %v");
    return s;
  }();
  return sink;
}

/// An spdlog logger behind the SDK interface. Filtering uses the global
/// level, so set_log_level() reaches loggers that already exist.
class SpdLogger final : public Logger {
 public:
  explicit SpdLogger(const std::string& name) : logger_(name, stderr_sink()) {
    logger_.set_level(spdlog::level::trace);
  }
  void write(LogLevel level, std::string_view message) override {
    if (enabled(level)) logger_.log(to_spdlog(level), message);
  }
  bool enabled(LogLevel level) const override {
    return level != LogLevel::Off && level >= g_level.load(std::memory_order_relaxed);
  }

 private:
  spdlog::logger logger_;
};

/// Writes through another logger with a fixed text in front of each message.
class PrefixedLogger final : public Logger {
 public:
  PrefixedLogger(std::shared_ptr<Logger> target, std::string prefix)
      : target_(std::move(target)), prefix_(std::move(prefix)) {}
  void write(LogLevel level, std::string_view message) override {
    std::string line;
    line.reserve(prefix_.size() + message.size());
    line.append(prefix_).append(message);
    target_->write(level, line);
  }
  bool enabled(LogLevel level) const override { return target_->enabled(level); }

 private:
  std::shared_ptr<Logger> target_;
  std::string prefix_;
};

}  // namespace

LogLevel parse_log_level(const std::string& text) {
  for (const LevelName& entry : kLevelNames)
    if (text == entry.name) return entry.level;
  throw std::invalid_argument("unknown log level '" + text + "' (choose trace, debug, info, warn, error or off)");
}

const char* log_level_name(LogLevel level) {
  for (const LevelName& entry : kLevelNames)
    if (entry.level == level) return entry.name;
  return "?";
}

void set_log_level(LogLevel level) { g_level.store(level, std::memory_order_relaxed); }

LogLevel log_level() { return g_level.load(std::memory_order_relaxed); }

std::shared_ptr<Logger> make_instance_logger(const std::string& instance) {
  return std::make_shared<SpdLogger>(instance);
}

std::shared_ptr<Logger> make_prefixed_logger(std::shared_ptr<Logger> target, std::string prefix) {
  if (!target) throw std::invalid_argument("make_prefixed_logger: no logger to write through");
  return std::make_shared<PrefixedLogger>(std::move(target), std::move(prefix));
}

Logger& kernel_log() {
  static SpdLogger logger("mspace");
  return logger;
}

}  // namespace mspace::kernel
