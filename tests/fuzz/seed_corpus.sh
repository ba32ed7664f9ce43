#!/usr/bin/env bash
# Seeds the fuzz corpora with pieces of the real data files (issue 11 item 5):
# for each file, its leading comment lines followed by COUNT windows of LINES
# consecutive records taken at evenly spaced places (the first at the start),
# one seed each. Small seeds keep libFuzzer fast; the data sets are never
# copied into the repository.
#
#   tests/fuzz/seed_corpus.sh DATASETS_DIR OUT_DIR
#
# writes OUT_DIR/<harness>/ for the harnesses that read these formats, and
# skips, saying so, a file that is absent.
set -euo pipefail
data=${1:?usage: seed_corpus.sh DATASETS_DIR OUT_DIR}
out=${2:?usage: seed_corpus.sh DATASETS_DIR OUT_DIR}

# windows HARNESS FILE LINES COUNT
windows() {
  local harness=$1 file=$2 lines=$3 count=$4
  if [[ ! -f $file ]]; then
    echo "seed_corpus: $file is absent; no seeds from it" >&2
    return
  fi
  mkdir -p "$out/$harness"
  awk -v lines="$lines" -v count="$count" -v prefix="$out/$harness/$(basename "$file")" '
    NR == FNR { if (!header_done && /^#/) head = head $0 "\n"; else header_done = 1; total++; next }
    FNR == 1 { n = total - lines; if (n < 1) n = 1 }
    { for (k = 0; k < count; k++) {
        start = 1 + int(k * n / count)
        if (FNR >= start && FNR < start + lines) {
          f = prefix "." k
          if (!(f in opened)) { opened[f] = 1; printf "%s", head > f }
          if (!/^#/) print > f
        }
      } }
  ' "$file" "$file"
}

windows carmen_log "$data/intel_lab/intel.gfs.log" 20 8
windows intel_table "$data/intel_lab/intel_910_scans.txt" 3 8
windows relations "$data/intel_lab/intel.relations" 30 4
windows victoria_park "$data/victoria_park/text/aa3_dr.txt" 40 4
windows victoria_park "$data/victoria_park/text/aa3_gpsx.txt" 40 4
windows victoria_park "$data/victoria_park/rfs_slam/measurements.dat" 40 4
