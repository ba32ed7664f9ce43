#include "progress.hpp"

#include <cstdio>
#include <unistd.h>

namespace mspace::kernel {

Progress::Progress(std::size_t total, bool enabled)
    : total_(total), enabled_(enabled), tty_(isatty(STDERR_FILENO) != 0) {
  start_ = last_draw_ = std::chrono::steady_clock::now();
}

void Progress::update(std::size_t done, const std::function<std::string()>& status) {
  if (!enabled_) return;
  const auto now = std::chrono::steady_clock::now();
  if (tty_) {
    if (now - last_draw_ < std::chrono::milliseconds(100)) return;
    last_draw_ = now;
    draw(done, status(), false);
    return;
  }
  if (total_ == 0) return;
  const int decile = static_cast<int>(10 * done / total_);
  if (decile == last_decile_) return;
  last_decile_ = decile;
  draw(done, status(), false);
}

void Progress::finish(std::size_t done, const std::string& status) {
  if (!enabled_) return;
  // Without a terminal the last decile line may already say 100 %.
  if (!tty_ && total_ > 0 && done >= total_ && last_decile_ == 10) return;
  draw(done, status, true);
}

void Progress::draw(std::size_t done, const std::string& status, bool final) {
  const double elapsed = std::chrono::duration<double>(std::chrono::steady_clock::now() - start_).count();
  const double rate = elapsed > 0 ? done / elapsed : 0.0;
  char line[256];
  if (total_ > 0) {
    const double frac = std::min(1.0, static_cast<double>(done) / static_cast<double>(total_));
    constexpr int kWidth = 30;
    char bar[kWidth + 1];
    const int filled = static_cast<int>(frac * kWidth);
    for (int i = 0; i < kWidth; ++i) bar[i] = i < filled ? '#' : '.';
    bar[kWidth] = '\0';
    const double eta = rate > 0 ? (static_cast<double>(total_) - static_cast<double>(done)) / rate : 0.0;
    std::snprintf(line, sizeof line, "[%s] %3.0f%% %zu/%zu steps %6.0f steps/s ETA %4.0fs  %s", bar, 100 * frac,
                  done, total_, rate, final ? 0.0 : eta, status.c_str());
  } else {
    std::snprintf(line, sizeof line, "%zu steps %6.0f steps/s  %s", done, rate, status.c_str());
  }
  if (tty_)
    std::fprintf(stderr, "\r%s\033[K%s", line, final ? "\n" : "");
  else
    std::fprintf(stderr, "%s\n", line);
  std::fflush(stderr);
}

}  // namespace mspace::kernel
