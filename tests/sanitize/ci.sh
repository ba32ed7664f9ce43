#!/usr/bin/env bash
# The whole test suite under AddressSanitizer + UndefinedBehaviorSanitizer
# (docs/reliability.md "Sanitizers", which says what it costs); .ci/run runs
# it last.
#
#   tests/sanitize/ci.sh [BUILD_DIR [CTEST_ARGS...]]   # default: build-asan
#   tests/sanitize/ci.sh build-asan -R Checkpoint        # a part of the suite
#
# Configures BUILD_DIR with the product instrumented (-DMSPACE_SANITIZE: the
# SDK library, the kernel, `mspace`, the Python module, every plugin library —
# dlopen'ed by the kernel and the tests) at -O1; the test programs (their own
# code and the product sources they compile in) and the ceiling renderer
# compiled as in the normal build (so, after ./setup.sh with the same ccache
# and MSPACE_WERROR, ccache hands those objects over), builds it and runs
# ctest on it (with CTEST_ARGS, e.g. -R or -L to run a part). The compiler
# is c++ (g++ on Debian, the one measured in docs/reliability.md, and the
# normal build's, whose test objects ccache then shares); SANITIZE_CXX=clang++
# chooses clang, which compiled kernel/src/slam.cpp with 31 % less CPU time
# there but recompiles every test.
# UBSan findings are fatal (-fno-sanitize-recover), ASan's always are; leak
# checking is on. Prints the build and the suite's wall times.
#
# Environment: SANITIZE_SHARD=k/n runs every test but the long ones of
# tests/sanitize/long_tests.txt, and of those shard k of n (.ci/run: the whole
# suite takes about 40 min under the sanitizers, too long beside the rest of
# CI); NORMAL_BUILD (default: build) is where the normal suite's test costs
# are read, so that the longest tests start first; JOBS (default: nproc);
# ASAN_OPTIONS / UBSAN_OPTIONS replace the defaults below.
set -euo pipefail
src=$(cd "$(dirname "${BASH_SOURCE[0]}")/../.." && pwd)
build=${1:-build-asan}
(($#)) && shift
jobs=${JOBS:-$(nproc)}
compiler=()
[[ -n ${SANITIZE_CXX:-} ]] && compiler=(-DCMAKE_CXX_COMPILER="$SANITIZE_CXX")

launcher=()
command -v ccache > /dev/null && launcher=(-DCMAKE_CXX_COMPILER_LAUNCHER=ccache)
start=$(date +%s)
cmake -S "$src" -B "$build" -G Ninja -DCMAKE_BUILD_TYPE=Release "${compiler[@]}" \
  -DMSPACE_SANITIZE=address,undefined -DMSPACE_WERROR="${MSPACE_WERROR:-OFF}" "${launcher[@]}" \
  -DPython3_EXECUTABLE=/usr/bin/python3 > "$build.configure.log" 2>&1 ||
  { cat "$build.configure.log"; exit 1; }
cmake --build "$build" -j "$jobs"
built=$(date +%s)
echo "sanitize: built with ${SANITIZE_CXX:-c++} in $((built - start)) s"

# CTest starts the dearest tests first when it knows their costs: the normal
# suite's (the README's test command, which .ci/run runs before this) order
# them well, so the longest runs do not start last and leave a core idle.
costs=Testing/Temporary/CTestCostData.txt
normal_build=${NORMAL_BUILD:-$src/build}
if [[ -f $normal_build/$costs && ! -f $build/$costs ]]; then
  mkdir -p "$build/Testing/Temporary"
  cp "$normal_build/$costs" "$build/$costs"
fi

# The long tests (tests/sanitize/long_tests.txt) in shards: SANITIZE_SHARD=k/n
# runs every other test and the long tests of shard k of n.
exclude=()
if [[ -n ${SANITIZE_SHARD:-} ]]; then
  if ! [[ $SANITIZE_SHARD =~ ^([0-9]+)/([1-9][0-9]*)$ ]] || ((BASH_REMATCH[1] >= BASH_REMATCH[2])); then
    echo "sanitize: SANITIZE_SHARD must be k/n with 0 <= k < n, not '$SANITIZE_SHARD'" >&2
    exit 2
  fi
  shard=${BASH_REMATCH[1]} shards=${BASH_REMATCH[2]}
  # Every listed name must be a test of this build: a renamed long test would
  # otherwise run in every CI run from then on, unnoticed, until CI's time ran out.
  list=$src/tests/sanitize/long_tests.txt
  ctest --test-dir "$build" -N | sed -n 's/^ *Test *#[0-9]*: \([^ ]*\).*/\1/p' > "$build/sanitize_tests.txt"
  missing=$(awk -F'\t' 'NR == FNR { known[$1] = 1; next }
                         !/^#/ && !($2 in known) { printf "%s:%d: no test named %s in this build\n", FILENAME, FNR, $2 }' \
            "$build/sanitize_tests.txt" "$list")
  if [[ -n $missing ]]; then
    echo "$missing" >&2
    echo "sanitize: a renamed test is renamed in $list too (its seconds stay), a removed one removed" >&2
    exit 2
  fi
  # Largest first, each to the shard with the least time so far; the names of
  # the other shards' tests, as a CTest regular expression.
  others=$(grep -v '^#' "$list" | sort -t$'\t' -k1,1nr -k2,2 |
    awk -F'\t' -v k="$shard" -v n="$shards" '
      { best = 0
        for (i = 1; i < n; ++i) if (load[i] < load[best]) best = i
        load[best] += $1
        if (best == k) { mine++; mine_s += $1 } else { others++; print $2 } }
      END { printf "sanitize: the long tests of shard %d/%d: %d (about %d s under the sanitizers); %d in the other shards\n",
                   k, n, mine, mine_s, others > "/dev/stderr" }' |
    sed 's/[][\\^$.*+?()|]/\\&/g' | paste -sd'|')
  # (A parameterised test's CTest name goes on after a space: "  # GetParam() = ...".)
  [[ -n $others ]] && exclude=(-E "^($others)( |\$)")
fi

# A 32 MB quarantine instead of 256 MB: a use after free is still caught when
# less than 32 MB were freed in between; the runs spend a sixth less time
# (fewer page faults: docs/reliability.md "Sanitizers").
export ASAN_OPTIONS=${ASAN_OPTIONS:-detect_leaks=1:quarantine_size_mb=32}
export UBSAN_OPTIONS=${UBSAN_OPTIONS:-print_stacktrace=1:halt_on_error=1}
status=0
ctest --test-dir "$build" -j "$jobs" --output-on-failure "${exclude[@]}" "$@" || status=$?
echo "sanitize: suite ran in $(($(date +%s) - built)) s (exit $status)"
exit $status
