#!/bin/bash
# End to end: the Intel table written as a bag (mspace-carmen-to-bag) and run
# with config/intel_walls.yaml's source replaced by `rosbag` gives the run on
# the table: same steps, features created, shared corners and updates; poses
# within 1e-4 m (the bag's ranges are float32, see docs/rosbag.md).
# Usage: intel_bag_run.sh BIN_DIR SOURCE_DIR WORK_DIR   (exit 77: data set absent)
set -euo pipefail
bin=$1 src=$2 work=$3
table=${MSPACE_DATA:-$src/../shared/datasets}/intel_lab/intel_910_scans.txt
if [[ ! -f $table ]]; then echo "SKIP: $table is absent (the Intel data set)"; exit 77; fi
rm -rf "$work" && mkdir -p "$work" && cd "$src"
"$bin/mspace-carmen-to-bag" "$table" "$work/intel.bag" --no-return 81
"$bin/mspace" run config/intel_walls.yaml --quiet --out "$work/table"
"$bin/mspace" run config/intel_walls.yaml --quiet --out "$work/bag" --set "source={plugin: rosbag, \
file: $work/intel.bag, ground_truth_topic: /ground_truth, odometry: scan_matched, scan_match_max_range: 30, \
initial_pose: ground_truth}"
for key in steps features_created shared_coordinates used_in_updates; do
  a=$(grep -m1 "^ *$key:" "$work/table/summary.yaml" || true) b=$(grep -m1 "^ *$key:" "$work/bag/summary.yaml" || true)
  [[ -n $a && $a == "$b" ]] || { echo "FAIL: $key: table '$a', bag '$b'"; exit 1; }
  echo "same $a"
done
paste <(grep -v '^#' "$work/table/trajectory.tum") <(grep -v '^#' "$work/bag/trajectory.tum") | awk '
  NF != 16 { print "FAIL: trajectories differ in length"; exit 1 }
  { for (i = 1; i <= 8; ++i) { d = $i - $(i + 8); if (d < 0) d = -d; if (d > m) m = d } n++ }
  END { printf "%d poses, largest difference %.3g\n", n, m; if (n != 910 || m > 1e-4) { print "FAIL"; exit 1 } }'
