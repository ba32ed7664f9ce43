// runner.hpp — a whole run: step through the data with progress output, then
// write the outputs the configuration asks for.
#pragma once

#include <filesystem>
#include <string>

#include "outputs.hpp"

namespace mspace::kernel {

class Slam;

struct RunOptions {
  bool progress = true;       ///< progress bar / lines on stderr
  bool write_outputs = true;  ///< trajectory, map, summary, picture
};

struct RunResult {
  RunSummary summary;
  std::filesystem::path output_dir;
};

/// Runs `slam` to the end of its data. If the data or a plugin fails midway,
/// the outputs computed so far are still written (marked as partial in the
/// log) before the error is rethrown.
RunResult run_to_end(Slam& slam, const RunOptions& options);

}  // namespace mspace::kernel
