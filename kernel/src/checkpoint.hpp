// checkpoint.hpp — checkpoints of a run and resuming from them
// (docs/persistence.md §4; issue 11 item 3).
//
// A checkpoint is a map directory whose map.bin says "checkpoint" and holds,
// besides every feature and shared coordinate, the resolved configuration
// (PARM), the kernel's own state (RUN) and every plugin object's run-time state
// (PSTA): the estimator's covariance, a data source's position and random
// generators. It is one file, written to a temporary name, flushed to disk and
// renamed over the previous checkpoint, so a crash while writing leaves the
// previous checkpoint whole. Resuming makes a new Slam from the stored
// configuration and restores everything into it before its first step: the
// resumed run then computes exactly what the uninterrupted run would have.
#pragma once

#include <cstdint>
#include <filesystem>
#include <functional>
#include <memory>

namespace mspace::kernel {

class Slam;
class PluginRegistry;
struct RunConfig;

/// The checkpoint folder of a run: <output.dir>/checkpoint.
std::filesystem::path checkpoint_dir(const RunConfig& config);

/// Writes the run's state to <dir>/map.bin atomically (replacing the previous
/// checkpoint there only once the new one is complete on disk). Returns the
/// file's size in bytes.
std::uintmax_t write_checkpoint(const Slam& slam, const std::filesystem::path& dir);

/// The checkpoint file `given` names: a map.bin itself, a folder holding one,
/// or a run's output folder holding checkpoint/map.bin. PersistenceError when
/// there is none.
std::filesystem::path find_checkpoint_file(const std::filesystem::path& given);

/// A Slam that continues from the checkpoint `given` names (see
/// find_checkpoint_file): the configuration is the checkpoint's, passed to
/// `adjust` before the plugins are made (the CLI changes only the output
/// folder, the step limit and the checkpoint interval there). Throws
/// PersistenceError naming the file (and the plugin or feature concerned) for
/// a corrupt or truncated file, another format or SDK version, a plugin that
/// is missing or differs, or a state a plugin refuses; nothing is returned
/// half-loaded.
std::unique_ptr<Slam> resume_from_checkpoint(const std::filesystem::path& given, PluginRegistry& registry,
                                             const std::function<void(RunConfig&)>& adjust = {});

}  // namespace mspace::kernel
