// runner.hpp — a whole run: step through the data with progress output, then
// write the outputs the configuration asks for.
#pragma once

#include <cstddef>
#include <filesystem>
#include <functional>
#include <optional>
#include <string>
#include <vector>

#include "outputs.hpp"

namespace mspace::kernel {

class Slam;

struct RunOptions {
  bool progress = true;       ///< progress bar / lines on stderr
  bool write_outputs = true;  ///< trajectory, map, summary, picture, frames (output.frames)
  /// SIGINT / SIGTERM stop the run after the current step (the outputs of the
  /// steps processed are written); a second one ends the process at once.
  bool stop_on_signals = false;
  /// Called after every step with the number of steps done (tests).
  std::function<void(std::size_t)> after_step;
  /// Checkpoints (checkpoint.hpp): when the configuration's
  /// run.checkpoint_every is N > 0, <output.dir>/checkpoint/ is written after
  /// every step whose number (counted from the start of the data, restored
  /// steps included) is a multiple of N, and when a signal interrupts the run.
  bool write_checkpoints = true;
};

struct RunResult {
  RunSummary summary;
  int checkpoints = 0;                 ///< checkpoints written
  std::uintmax_t checkpoint_bytes = 0;  ///< size of the last one
  double checkpoint_seconds = 0.0;      ///< elapsed (clock) time of writing them all
  std::filesystem::path output_dir;
  int stop_signal = 0;  ///< the signal that interrupted the run, 0 if none
  std::vector<std::string> files;  ///< the output files written (names in output_dir)
  std::optional<FramesReport> frames;  ///< with output.frames: the pictures of the map written as the run went
};

/// Runs `slam` to the end of its data. Outputs: the trajectory is streamed to
/// trajectory.partial.tum while the run goes (flushed every 2 s), and every
/// final file is written atomically (TrajectoryStream, write_atomically). If
/// the data or a plugin fails midway, the outputs computed so far are still
/// written (marked as partial in the log) before the error is rethrown; an
/// interruption (stop_on_signals) writes them too and returns with
/// stop_signal set and the summary saying where it stopped.
RunResult run_to_end(Slam& slam, const RunOptions& options);

}  // namespace mspace::kernel
