#!/usr/bin/env bash
# Builds the libFuzzer harnesses of tests/fuzz against a normal build and runs
# each for a while (docs/reliability.md "Fuzzing"; CI runs it on every change).
#
#   tests/fuzz/ci.sh BUILD_DIR [SECONDS]      # SECONDS per harness, default 15
#
# Only the code under test — the reader or kernel file the harness drives and
# the SDK's record parsing — is compiled with clang, libFuzzer's coverage,
# AddressSanitizer and UndefinedBehaviorSanitizer (-O1); the rest (SDK library,
# kernel archive, plugins) comes from BUILD_DIR as built. That keeps the stage
# to a dozen compilations. For a build that instruments everything, see the
# CMake option MSPACE_FUZZ (tests/fuzz/CMakeLists.txt).
#
# Seeds: tests/fuzz/corpus/<harness> (hand-made), config/*.yaml, windows of
# the real data files when the data sets are present (seed_corpus.sh; set
# MSPACE_DATA or keep ../shared/datasets), and map files / checkpoints of short
# runs of BUILD_DIR/bin/mspace. The grown corpora are kept in
# BUILD_DIR/fuzz/corpus/, reproducers of findings in BUILD_DIR/fuzz/findings/.
# Exit status: 1 when a harness crashes, reports a sanitizer error or an
# undocumented exception.
set -euo pipefail
src=$(cd "$(dirname "${BASH_SOURCE[0]}")/../.." && pwd)
build=$(cd "${1:?usage: tests/fuzz/ci.sh BUILD_DIR [SECONDS]}" && pwd)
seconds=${2:-15}
cxx=${FUZZ_CXX:-clang++}
out=$build/fuzz
mkdir -p "$out/obj" "$out/corpus" "$out/findings" "$out/seeds"

# EIGEN_MALLOC_ALREADY_ALIGNED=0: Eigen's heap scheme of every mspace build
# (top-level CMakeLists.txt), so matrices cross into BUILD_DIR's libraries.
flags=(-std=c++20 -O1 -g -fno-omit-frame-pointer -fsanitize=address,undefined -fno-sanitize-recover=undefined
       -DNDEBUG -DEIGEN_MALLOC_ALREADY_ALIGNED=0 -I"$src/sdk/include" -I"$src/sensors_plugins" -I"$src/sensors_plugins/carmen_log"
       -I"$src/tests/fuzz" -I"$src/kernel/src" -isystem /usr/include/eigen3 -isystem /usr/include/opencv4
       -DSPDLOG_COMPILED_LIB -DSPDLOG_FMT_EXTERNAL -DSPDLOG_SHARED_LIB -DFMT_SHARED
       -DMSPACE_PLUGIN_DIR="\"$build/lib/mspace/plugins\"")
sdk=(-L"$build/lib" -lmspace_sdk -Wl,-rpath,"$build/lib")
kernel=("$build/lib/libmspace_kernel.a" -lspdlog -lfmt -lboost_filesystem -lyaml-cpp -lopencv_imgproc
        -lopencv_core -lpng -lz -ldl "${sdk[@]}")
images=(-lyaml-cpp -lopencv_imgcodecs -lopencv_core "${sdk[@]}")

# object SOURCE: compiles a file under test (coverage, no libFuzzer main) once per run of this script
# and sets $obj to the object file.
declare -A compiled
object() {
  obj="$out/obj/$(echo "$1" | tr / _).o"
  if [[ -z ${compiled[$1]:-} ]]; then
    "$cxx" "${flags[@]}" -fsanitize=fuzzer-no-link -c "$src/$1" -o "$obj"
    compiled[$1]=1
  fi
}
# harness NAME SOURCES... -- LIBRARIES...
harness() {
  local name=$1 objects=() ; shift
  while [[ $1 != -- ]]; do object "$1"; objects+=("$obj"); shift; done
  shift
  "$cxx" "${flags[@]}" -fsanitize=fuzzer "$src/tests/fuzz/fuzz_$name.cpp" "${objects[@]}" "$@" -o "$out/fuzz_$name"
  names+=("$name")
}

names=()
start=$(date +%s)
records=sdk/src/records.cpp
harness carmen_log sensors_plugins/carmen_log/carmen_reader.cpp $records -- "${sdk[@]}"
harness intel_table sensors_plugins/carmen_log/carmen_reader.cpp $records -- "${sdk[@]}"
harness victoria_park sensors_plugins/victoria_park/victoria_park.cpp sensors_plugins/victoria_park/numeric_table.cpp \
  $records -- "${sdk[@]}"
harness image_sequence_csv sensors_plugins/image_sequence/image_sequence.cpp $records -- "${images[@]}"
harness image_sequence_yaml sensors_plugins/image_sequence/image_sequence.cpp $records -- "${images[@]}"
harness relations kernel/src/relations.cpp -- "${kernel[@]}"
harness config kernel/src/config.cpp -- "${kernel[@]}"
harness map_file kernel/src/persistence.cpp -- "${kernel[@]}"
echo "fuzz: ${#names[@]} harnesses built in $(($(date +%s) - start)) s"

# Seeds beyond the repository's.
data=${MSPACE_DATA:-$src/../shared/datasets}
if [[ -d $data ]]; then
  "$src/tests/fuzz/seed_corpus.sh" "$data" "$out/seeds"
else
  echo "fuzz: no data sets at $data: seeded with tests/fuzz/corpus only"
fi
mkdir -p "$out/seeds/config" "$out/seeds/map_file"
cp "$src"/config/*.yaml "$out/seeds/config/"
if [[ -x $build/bin/mspace ]]; then
  for estimator in ekf cekf smoother; do
    run=$out/seeds/run_$estimator
    "$build/bin/mspace" run --quiet --log-level warn --out "$run" --max-steps 30 --estimator "$estimator" --checkpoint-every 25 \
      --set output.map_covariance=joint --plugin-dir "$build/lib/mspace/plugins" > /dev/null
    cp "$run/map.bin" "$out/seeds/map_file/$estimator.map.bin"
    cp "$run/checkpoint/map.bin" "$out/seeds/map_file/$estimator.checkpoint.bin"
    rm -rf "$run"
  done
fi

status=0
printf '%-20s %10s %8s %8s %8s\n' harness executions edges features corpus
for name in "${names[@]}"; do
  corpus=$out/corpus/$name
  mkdir -p "$corpus"
  seeds=("$src/tests/fuzz/corpus/$name")
  [[ -d $out/seeds/$name ]] && seeds+=("$out/seeds/$name")
  log=$out/$name.log
  if ! "$out/fuzz_$name" -max_total_time="$seconds" -timeout=60 -rss_limit_mb=2048 -print_final_stats=1 \
       -artifact_prefix="$out/findings/$name-" "$corpus" "${seeds[@]}" > "$log" 2>&1; then
    echo "fuzz: fuzz_$name found a defect; log: $log, reproducer: $out/findings/$name-*"
    grep -E "ERROR|runtime error|terminate|Assertion|refusal" "$log" | head -5 || true
    status=1
  fi
  stat() { grep "stat::$1" "$log" | awk '{print $2}'; }
  cov=$(grep -oE "cov: [0-9]+ ft: [0-9]+" "$log" | tail -1)
  printf '%-20s %10s %8s %8s %8s\n' "$name" "$(stat number_of_executed_units)" \
    "$(echo "$cov" | awk '{print $2}')" "$(echo "$cov" | awk '{print $4}')" "$(ls "$corpus" | wc -l)"
done
exit $status
