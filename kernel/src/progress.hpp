// progress.hpp — progress output for long runs: a redrawn bar on a terminal,
// a line every 10 % otherwise (logs, CI).
#pragma once

#include <chrono>
#include <cstddef>
#include <functional>
#include <string>

namespace mspace::kernel {

class Progress {
 public:
  /// total = 0 when the number of steps is unknown.
  Progress(std::size_t total, bool enabled);
  /// Called after every step; redraws at most ~10 times a second. `status`
  /// is asked for only when the line is drawn (it may look at the whole map).
  void update(std::size_t done, const std::function<std::string()>& status);
  /// Final redraw and newline.
  void finish(std::size_t done, const std::string& status);

 private:
  void draw(std::size_t done, const std::string& status, bool final);

  std::size_t total_;
  bool enabled_;
  bool tty_;
  int last_decile_ = -1;
  std::chrono::steady_clock::time_point start_, last_draw_;
};

}  // namespace mspace::kernel
