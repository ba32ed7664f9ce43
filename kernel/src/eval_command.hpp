// eval_command.hpp — `mspace eval`: scores any trajectory file with the
// project's own metrics, as a run's summary does, so that the output of
// another SLAM system (or of an earlier run) is measured the same way:
//
//   - ATE against a reference trajectory (evaluation.hpp: each reference pose
//     paired with the estimate interpolated at its time, SE(2) alignment);
//   - the relations metric of Kümmerle et al. 2009 (relations.hpp), over all
//     relations and split into short ones and long ones (t2 − t1 ≥ a
//     threshold, 60 s by default: the loop closures).
//
// Trajectory files are TUM (`t x y z qx qy qz qw`) or planar (`t x y theta`,
// theta in rad); '#' lines and empty lines are skipped; the width is fixed by
// the first pose line and every other line must have it.
#pragma once

#include <cstddef>
#include <filesystem>
#include <iosfwd>
#include <optional>
#include <string>
#include <vector>

#include "evaluation.hpp"
#include "relations.hpp"

namespace mspace::kernel {

/// Reads a trajectory file (TUM or `t x y theta`; see above), sorted by time.
/// Throws std::runtime_error "file:line: problem" for a malformed line, a
/// non-unit quaternion, a file that cannot be opened or that holds no pose.
std::vector<StampedPose> read_trajectory_file(const std::filesystem::path& file);

struct EvalOptions {
  std::filesystem::path estimate;
  std::filesystem::path reference;  ///< empty: no ATE
  std::filesystem::path relations;  ///< empty: no relations
  double max_gap = 1.0;             ///< s: estimate poses further apart are not interpolated (ATE)
  double relations_max_dt = 1e-4;   ///< s: a relation's stamp must be this close to an estimate pose
  double long_seconds = 60.0;       ///< s: relations at least this long are the long ones
};

struct EvalResult {
  std::size_t estimate_poses = 0;
  double estimate_t0 = 0.0, estimate_t1 = 0.0;  ///< time span of the estimate
  std::optional<TrajectoryErrors> ate;
  std::optional<RelationErrors> relations_all, relations_short, relations_long;
};

/// Reads the files and scores the estimate. Throws std::runtime_error for a
/// bad file (with file:line) or when the reference or the relations share no
/// time with the estimate (nothing would be measured).
EvalResult evaluate_files(const EvalOptions& options);

/// The human-readable report (what `mspace eval` prints).
void print_eval(std::ostream& out, const EvalResult& result, const EvalOptions& options);

/// The same figures as flat YAML (`key: value` lines), for scripts.
void write_eval_yaml(const std::filesystem::path& file, const EvalResult& result, const EvalOptions& options);

}  // namespace mspace::kernel
