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
# dlopen'ed by the kernel and the tests — and the product sources that test
# programs compile in) at -O1, the tests' own code and the ceiling renderer
# compiled as in the normal build (so, after ./setup.sh with the same ccache
# and MSPACE_WERROR, ccache hands those objects over), builds it and runs
# ctest on it (with CTEST_ARGS, e.g. -R or -L to run a part). The compiler
# is c++ (g++ on Debian, the one measured in docs/reliability.md, and the
# normal build's, whose test objects ccache then shares); SANITIZE_CXX=clang++
# chooses clang, which compiled kernel/src/slam.cpp with 31 % less CPU time
# there but recompiles every test.
# UBSan findings are fatal (-fno-sanitize-recover), ASan's always are; leak
# checking is on. Prints the build and the suite's wall times.
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

export ASAN_OPTIONS=${ASAN_OPTIONS:-detect_leaks=1}
export UBSAN_OPTIONS=${UBSAN_OPTIONS:-print_stacktrace=1:halt_on_error=1}
status=0
ctest --test-dir "$build" -j "$jobs" --output-on-failure "$@" || status=$?
echo "sanitize: suite ran in $(($(date +%s) - built)) s (exit $status)"
exit $status
