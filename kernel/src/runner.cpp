#include "runner.hpp"

#include <algorithm>
#include <chrono>
#include <cstdint>
#include <csignal>
#include <cstdlib>
#include <exception>
#include <memory>
#include <stdexcept>
#include <string>

#include "checkpoint.hpp"
#include "logging.hpp"
#include "occupancy_grid.hpp"
#include "persistence.hpp"
#include "progress.hpp"
#include "slam.hpp"

namespace mspace::kernel {
namespace {

std::string status_line(const Slam& slam) {
  int in_map = 0, tentative = 0;
  for (const MapFeature& f : slam.features()) (f.feature->mspace_dim() > 0 ? in_map : tentative)++;
  return std::to_string(in_map) + " features, " + std::to_string(tentative) + " tentative";
}

/// What write_outputs() wrote, and what it could not write ("name: reason; …",
/// empty when everything was written).
struct WrittenOutputs {
  std::vector<std::string> files;
  std::string failures;
  bool has(const std::string& name) const { return std::find(files.begin(), files.end(), name) != files.end(); }
  /// "writing the outputs in DIR failed (…); written: …".
  std::string failure_message(const std::filesystem::path& dir) const {
    std::string done;
    for (const std::string& name : files) done += (done.empty() ? "" : ", ") + name;
    return "writing the outputs in " + dir.string() + " failed (" + failures + "); written: " +
           (done.empty() ? std::string("nothing") : done);
  }
};

/// Writes the outputs the configuration asks for. Each output is attempted
/// whatever happened to the ones before it: a broken estimator plugin may make
/// the map's covariances unreadable, which must not cost the summary or the
/// trajectory.
WrittenOutputs write_outputs(const Slam& slam, const RunSummary& summary, const std::filesystem::path& dir,
                             const ScanCollector* scans) {
  const OutputConfig& out = slam.config().output;
  std::filesystem::create_directories(dir);
  namespace fs = std::filesystem;
  WrittenOutputs result;
  std::vector<std::string>& written = result.files;
  std::string& failures = result.failures;
  const auto attempt = [&](const char* name, const auto& write) {
    try {
      write();
    } catch (const std::exception& e) {
      failures += std::string(failures.empty() ? "" : "; ") + name + ": " + e.what();
    }
  };
  if (out.trajectory)  // with their frames (pose_files.cpp)
    attempt("trajectory", [&] {
      for (const fs::path& f : write_pose_files(dir, slam)) written.push_back(f.filename().string());
    });
  if (out.map) {
    attempt("map.yaml", [&] {
      write_atomically(dir / "map.yaml", [&](const fs::path& f) { write_map_yaml(f, slam); });
      written.emplace_back("map.yaml");
    });
    // The exact store, through the plugins' save(); atomic itself. A localize
    // run changes no map: the map.bin it read stays the map.
    if (slam.map_mode() != MapConfig::Mode::Localize)
      attempt("map.bin", [&] {
        write_map_bin(dir / "map.bin", slam);
        written.emplace_back("map.bin");
      });
  }
  if (out.summary)
    attempt("summary.yaml", [&] {
      write_atomically(dir / "summary.yaml", [&](const fs::path& f) { write_summary_yaml(f, summary, slam); });
      written.emplace_back("summary.yaml");
    });
  if (out.picture)
    attempt("map.png", [&] {
      write_atomically(dir / "map.png", [&](const fs::path& f) { write_picture(f, slam, out.picture_size); });
      written.emplace_back("map.png");
    });
  if (scans != nullptr)  // grid.pgm/.yaml/.png from the final trajectory
    attempt("grid", [&] {
      for (const fs::path& f : write_grid_outputs(dir, slam, *scans)) written.push_back(f.filename().string());
    });
  return result;
}

/// Keeps the run's range scans for the occupancy grid while it is alive.
class ScanRecording {
 public:
  ScanRecording(Slam& slam, bool on) : slam_(slam) {
    if (!on) return;
    scans_ = std::make_unique<ScanCollector>(slam.config());
    slam.set_step_observer([this](const DataStep& data, std::size_t pose) { scans_->add(data, pose); });
  }
  ~ScanRecording() {
    if (scans_) slam_.set_step_observer(nullptr);
  }
  ScanRecording(const ScanRecording&) = delete;
  ScanRecording& operator=(const ScanRecording&) = delete;
  const ScanCollector* scans() const { return scans_.get(); }

 private:
  Slam& slam_;
  std::unique_ptr<ScanCollector> scans_;
};

// ---- Interruption ------------------------------------------------------------
//
// The handler only records the signal (a sig_atomic_t write is all a handler
// may safely do); the loop looks at it after every step. A second signal
// while the first is being honoured ends the process at once (_Exit is
// async-signal-safe), for a user who does not want to wait for the outputs.

volatile std::sig_atomic_t g_stop_signal = 0;

extern "C" void on_stop_signal(int signal) {
  if (g_stop_signal != 0) std::_Exit(128 + signal);
  g_stop_signal = signal;
}

/// Installs the handlers for SIGINT and SIGTERM for its lifetime.
class StopSignals {
 public:
  StopSignals() {
    g_stop_signal = 0;
    struct sigaction action {};
    action.sa_handler = on_stop_signal;
    sigemptyset(&action.sa_mask);
    sigaction(SIGINT, &action, &old_int_);
    sigaction(SIGTERM, &action, &old_term_);
  }
  ~StopSignals() {
    sigaction(SIGINT, &old_int_, nullptr);
    sigaction(SIGTERM, &old_term_, nullptr);
    g_stop_signal = 0;
  }
  StopSignals(const StopSignals&) = delete;
  StopSignals& operator=(const StopSignals&) = delete;
  int signal() const { return g_stop_signal; }

 private:
  struct sigaction old_int_ {}, old_term_ {};
};

const char* signal_name(int signal) {
  switch (signal) {
    case SIGINT: return "SIGINT";
    case SIGTERM: return "SIGTERM";
    default: return "a signal";
  }
}

}  // namespace

RunResult run_to_end(Slam& slam, const RunOptions& options) {
  RunResult result;
  result.output_dir = slam.config().output.dir;
  const auto start = std::chrono::steady_clock::now();
  auto elapsed = [&] { return std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count(); };
  Progress progress(slam.size_hint(), options.progress);
  std::unique_ptr<StopSignals> signals;
  if (options.stop_on_signals) signals = std::make_unique<StopSignals>();
  std::unique_ptr<TrajectoryStream> stream;
  if (options.write_outputs && slam.config().output.trajectory)
    stream = std::make_unique<TrajectoryStream>(result.output_dir, 2.0, pose_file_frame(slam, PoseFile::Robot));
  const ScanRecording recording(slam, options.write_outputs && slam.config().output.grid.enabled);
  std::unique_ptr<MapFrames> frames;
  if (options.write_outputs && slam.config().output.frames > 0)
    frames = std::make_unique<MapFrames>(result.output_dir, slam.config().output.frames,
                                         slam.config().output.picture_size, slam);
  const std::int64_t every = options.write_checkpoints ? slam.config().checkpoint_every : 0;
  const auto checkpoint = [&] {
    const auto t0 = std::chrono::steady_clock::now();
    result.checkpoint_bytes = write_checkpoint(slam, checkpoint_dir(slam.config()));
    const double seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    result.checkpoint_seconds += seconds;
    ++result.checkpoints;
    kernel_log().debug("checkpoint at step ", slam.steps_done(), ": ", result.checkpoint_bytes, " bytes in ",
                       seconds, " s");
  };
  std::size_t done = 0;
  try {
    while (slam.step()) {
      ++done;
      progress.update(static_cast<std::size_t>(slam.steps_done()), [&] { return status_line(slam); });
      if (stream) stream->append(slam.trajectory());
      if (frames) frames->after_step(slam);
      if (options.after_step) options.after_step(done);
      if (signals && signals->signal() != 0) {
        result.stop_signal = signals->signal();
        if (every > 0) checkpoint();  // `--resume` goes on from here
        break;
      }
      if (every > 0 && slam.steps_done() % every == 0) checkpoint();
    }
  } catch (const std::exception& e) {
    progress.finish(static_cast<std::size_t>(slam.steps_done()), status_line(slam));
    if (options.write_outputs && slam.steps_done() > 0) {
      // The outputs of the steps done; a failure here (a broken plugin asked
      // for the map's covariances again) must not hide the error itself.
      try {
        result.summary = summarize(slam, elapsed());
        result.summary.stopped_by_error = e.what();
        const WrittenOutputs written = write_outputs(slam, result.summary, result.output_dir, recording.scans());
        result.files = written.files;
        if (stream && written.has("trajectory.tum")) stream->discard();
        if (written.failures.empty())
          kernel_log().error("run stopped after ", slam.steps_done(),
                             " steps; the outputs of those steps were written to ", result.output_dir.string());
        else
          kernel_log().error("run stopped after ", slam.steps_done(), " steps; ",
                             written.failure_message(result.output_dir),
                             (stream && !written.has("trajectory.tum")
                                  ? "; the trajectory so far is in trajectory.partial.tum"
                                  : ""));
      } catch (const std::exception& again) {
        kernel_log().error("run stopped after ", slam.steps_done(), " steps, and writing its outputs failed too: ",
                           again.what(), (stream ? "; the trajectory so far is in trajectory.partial.tum" : ""));
      }
    }
    throw;
  }
  progress.finish(static_cast<std::size_t>(slam.steps_done()), status_line(slam));
  if (frames) {
    frames->finish(slam);
    result.frames = frames->report();
  }
  result.summary = summarize(slam, elapsed());
  if (result.stop_signal != 0) {
    const std::size_t total = slam.size_hint();
    result.summary.interrupted = "interrupted at step " + std::to_string(slam.steps_done()) + " of " +
                                 (total > 0 ? std::to_string(total) : std::string("an unknown number")) + " (" +
                                 signal_name(result.stop_signal) + ")";
    kernel_log().warn(result.summary.interrupted, "; writing the outputs of the steps processed (",
                      signal_name(result.stop_signal), " again ends at once)");
  }
  if (options.write_outputs) {
    const WrittenOutputs written = write_outputs(slam, result.summary, result.output_dir, recording.scans());
    result.files = written.files;
    if (stream && written.has("trajectory.tum")) stream->discard();
    if (!written.failures.empty()) throw std::runtime_error(written.failure_message(result.output_dir));
  }
  return result;
}

}  // namespace mspace::kernel
