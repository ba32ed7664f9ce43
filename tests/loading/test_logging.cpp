// The kernel's loggers: level names, per-instance loggers and the line format.
#include <stdexcept>
#include <string>

#include <gtest/gtest.h>

#include "logging.hpp"

using mspace::LogLevel;
using namespace mspace::kernel;

namespace {

/// Restores the global log level when a test ends.
class LevelGuard {
 public:
  LevelGuard() : saved_(log_level()) {}
  ~LevelGuard() { set_log_level(saved_); }

 private:
  LogLevel saved_;
};

}  // namespace

TEST(Logging, ParsesEveryLevelName) {
  for (LogLevel level :
       {LogLevel::Trace, LogLevel::Debug, LogLevel::Info, LogLevel::Warn, LogLevel::Error, LogLevel::Off})
    EXPECT_EQ(parse_log_level(log_level_name(level)), level);
  EXPECT_EQ(parse_log_level("warn"), LogLevel::Warn);
  try {
    parse_log_level("verbose");
    ADD_FAILURE() << "expected std::invalid_argument";
  } catch (const std::invalid_argument& e) {
    EXPECT_EQ(std::string(e.what()), "unknown log level 'verbose' (choose trace, debug, info, warn, error or off)");
  }
}

TEST(Logging, InstanceLoggerWritesLevelAndNameToStderr) {
  LevelGuard guard;
  set_log_level(LogLevel::Info);
  auto log = make_instance_logger("walls");
  testing::internal::CaptureStderr();
  log->info("matched ", 3, " of ", 4.5);
  log->debug("not shown at info");
  log->warn("gate too wide");
  kernel_log().error("stopping");
  EXPECT_EQ(testing::internal::GetCapturedStderr(),
            "[I] [walls] matched 3 of 4.5\n[W] [walls] gate too wide\n[E] [mspace] stopping\n");
}

TEST(Logging, LevelAppliesToExistingLoggers) {
  LevelGuard guard;
  auto log = make_instance_logger("ekf");
  set_log_level(LogLevel::Debug);
  EXPECT_TRUE(log->enabled(LogLevel::Debug));
  EXPECT_FALSE(log->enabled(LogLevel::Trace));
  set_log_level(LogLevel::Off);
  EXPECT_FALSE(log->enabled(LogLevel::Error));
  EXPECT_FALSE(kernel_log().enabled(LogLevel::Error));
  testing::internal::CaptureStderr();
  log->error("silenced");
  EXPECT_EQ(testing::internal::GetCapturedStderr(), "");
}
