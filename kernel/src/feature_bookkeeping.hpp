// feature_bookkeeping.hpp — what the kernel keeps about one feature besides
// the plugin's own state: its estimator rows, shared blocks and history. The
// same fields in a running map (MapFeature, slam.hpp) and in a map file or
// checkpoint (StoredFeature, persistence.hpp), so they are copied as one.
#pragma once

#include <cstdint>
#include <map>
#include <vector>

namespace mspace::kernel {

struct FeatureBookkeeping {
  /// Estimator indices of its M-space columns, in the feature's column order:
  /// own_idx, then the shared blocks' indices in ascending block order.
  std::vector<int> state_idx;
  std::vector<int> own_idx;   ///< indices of the feature's own dimensions
  std::map<int, int> shared;  ///< coordinate block → SharedCoordinate id
  std::int64_t created_step = 0;
  std::int64_t last_seen_step = 0;
  int last_sensor = 0;       ///< sensor of the newest evidence
  double last_seen_t = 0.0;  ///< time stamp of the newest evidence
  int times_matched = 0;
  double created_path = 0.0;    ///< path distance (Slam) when created
  double last_seen_path = 0.0;  ///< path distance of the newest evidence
  /// Path distance where the current run of observations began: the
  /// creation, or the last re-observation after the robot had travelled
  /// association.loop_min_gap_path without seeing it (a revisit).
  double seen_since_path = 0.0;
  /// Id of the older feature a loop closure found this one to duplicate
  /// (0: none). It stays in the estimator, tied to that one by a
  /// coincidence factor or the closure's update, and is no longer associated.
  int merged_into = 0;
};

}  // namespace mspace::kernel
