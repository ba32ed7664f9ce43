#!/usr/bin/env bash
# mspace set-up: installs the Debian packages mspace needs, builds it (Release,
# ccache) and runs the built-in default — a simulated world of point landmarks.
#
#   ./setup.sh            install + build + run the default (outputs in out/sim_points/)
#   ./setup.sh --no-run   install + build only
#
# Environment: BUILD_DIR (default: build), JOBS (default: nproc),
# MSPACE_WERROR=ON to treat warnings as errors (CI does), MSPACE_FUZZ_TOOLS=ON to
# also install clang and its sanitizer / libFuzzer runtime for the fuzz
# harnesses (tests/fuzz/ci.sh; CI does).
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")"

BUILD_DIR=${BUILD_DIR:-build}
JOBS=${JOBS:-$(nproc)}
RUN_DEFAULT=1
[[ "${1:-}" == "--no-run" ]] && RUN_DEFAULT=0

PACKAGES=(
  build-essential cmake ninja-build ccache pkg-config git
  libeigen3-dev libopencv-dev libboost-dev libboost-filesystem-dev
  libyaml-cpp-dev libspdlog-dev libcli11-dev libpng-dev
  libgtest-dev libgmock-dev libbenchmark-dev
  python3-dev pybind11-dev python3-numpy python3-yaml
  librosbag-storage-dev libsensor-msgs-dev libnav-msgs-dev libtf2-msgs-dev
)
# The fuzz harnesses: clang, and libFuzzer / ASan / UBSan (only recommended by clang-14).
[[ "${MSPACE_FUZZ_TOOLS:-OFF}" == ON ]] && PACKAGES+=(clang libclang-rt-14-dev zlib1g-dev)

missing=()
for p in "${PACKAGES[@]}"; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done
if ((${#missing[@]})); then
  echo "== installing: ${missing[*]}"
  SUDO=""
  [[ $(id -u) -ne 0 ]] && SUDO=sudo
  $SUDO apt-get update -qq
  DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq --no-install-recommends "${missing[@]}"
fi

echo "== configuring ($BUILD_DIR)"
# The Python module is built for Debian's python3 (the one python3-numpy is
# installed for), whatever other python3 comes first on the PATH.
cmake -S . -B "$BUILD_DIR" -G Ninja -DCMAKE_BUILD_TYPE=Release -DMSPACE_WERROR="${MSPACE_WERROR:-OFF}" \
  -DPython3_EXECUTABLE=/usr/bin/python3
echo "== building with $JOBS jobs"
cmake --build "$BUILD_DIR" -j "$JOBS"

if ((RUN_DEFAULT)); then
  echo "== running the built-in default (simulated point world)"
  "$BUILD_DIR/bin/mspace" run --out out/sim_points
fi
