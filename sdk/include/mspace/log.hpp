// mspace/log.hpp — the logging interface plugins see.
//
// The kernel gives every plugin instance its own logger (an spdlog logger named
// after the instance, behind this interface, so spdlog never crosses the
// plugin ABI). Arguments are streamed: log.info("matched ", n, " features").
#pragma once

#include <sstream>
#include <string_view>

namespace mspace {

enum class LogLevel { Trace = 0, Debug, Info, Warn, Error, Off };

class Logger {
 public:
  virtual ~Logger() = default;
  virtual void write(LogLevel level, std::string_view message) = 0;
  virtual bool enabled(LogLevel level) const = 0;

  template <class... Args>
  void log(LogLevel level, const Args&... args) {
    if (!enabled(level)) return;
    std::ostringstream os;
    (os << ... << args);
    write(level, os.str());
  }
  template <class... Args> void trace(const Args&... a) { log(LogLevel::Trace, a...); }
  template <class... Args> void debug(const Args&... a) { log(LogLevel::Debug, a...); }
  template <class... Args> void info(const Args&... a) { log(LogLevel::Info, a...); }
  template <class... Args> void warn(const Args&... a) { log(LogLevel::Warn, a...); }
  template <class... Args> void error(const Args&... a) { log(LogLevel::Error, a...); }
};

/// A logger that drops everything (for tests and tools).
Logger& null_logger();

}  // namespace mspace
