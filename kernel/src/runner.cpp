#include "runner.hpp"

#include <chrono>
#include <exception>
#include <string>

#include "logging.hpp"
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

void write_outputs(const Slam& slam, const RunSummary& summary, const std::filesystem::path& dir) {
  const OutputConfig& out = slam.config().output;
  std::filesystem::create_directories(dir);
  if (out.trajectory) {
    write_tum(dir / "trajectory.tum", slam.trajectory());
    if (!slam.ground_truth().empty()) write_tum(dir / "ground_truth.tum", slam.ground_truth());
  }
  if (out.map) {
    write_map_yaml(dir / "map.yaml", slam);
    write_map_bin(dir / "map.bin", slam);  // the exact store, through the plugins' save()
  }
  if (out.summary) write_summary_yaml(dir / "summary.yaml", summary, slam);
  if (out.picture) write_picture(dir / "map.png", slam, out.picture_size);
}

}  // namespace

RunResult run_to_end(Slam& slam, const RunOptions& options) {
  RunResult result;
  result.output_dir = slam.config().output.dir;
  const auto start = std::chrono::steady_clock::now();
  auto elapsed = [&] { return std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count(); };
  Progress progress(slam.size_hint(), options.progress);
  std::size_t done = 0;
  try {
    while (slam.step()) {
      ++done;
      progress.update(done, status_line(slam));
    }
  } catch (const std::exception& e) {
    progress.finish(done, status_line(slam));
    if (options.write_outputs && done > 0) {
      result.summary = summarize(slam, elapsed());
      write_outputs(slam, result.summary, result.output_dir);
      kernel_log().error("run stopped after ", done, " steps; the outputs of those steps were written to ",
                         result.output_dir.string());
    }
    throw;
  }
  progress.finish(done, status_line(slam));
  result.summary = summarize(slam, elapsed());
  if (options.write_outputs) write_outputs(slam, result.summary, result.output_dir);
  return result;
}

}  // namespace mspace::kernel
