#!/usr/bin/env bash
# Builds the libFuzzer targets (tests/fuzz) with clang, AddressSanitizer and UBSan in build-fuzz/
# and runs each for RIM_FUZZ_SECONDS (default 60) under `ctest -L fuzz`. Installs nothing: it needs
# Debian's clang and libclang-rt-14-dev (deploy/install-deps.sh installs them).
# Usage: bash tests/fuzz/run.sh [ctest -R regex, e.g. fuzz_pcd]
# Env: RIM_FUZZ_SECONDS, RIM_FUZZ_BUILD_DIR (default build-fuzz), RIM_FUZZ_JOBS (default nproc).
set -euo pipefail
cd "$(dirname "$0")/../.."
BUILD_DIR="${RIM_FUZZ_BUILD_DIR:-build-fuzz}"
SECONDS_PER_TARGET="${RIM_FUZZ_SECONDS:-60}"
JOBS="${RIM_FUZZ_JOBS:-$(nproc)}"

for tool in clang clang++; do
  command -v "$tool" > /dev/null || { echo "run.sh: $tool not found (Debian package clang)" >&2; exit 2; }
done
# libFuzzer's runtime comes with compiler-rt, not with clang itself.
if ! echo 'extern "C" int LLVMFuzzerTestOneInput(const unsigned char*, unsigned long) { return 0; }' |
    clang++ -x c++ -fsanitize=fuzzer,address,undefined -o /dev/null - 2> /dev/null; then
  echo "run.sh: clang cannot link -fsanitize=fuzzer (Debian package libclang-rt-14-dev)" >&2
  exit 2
fi

export CCACHE_DIR="${CCACHE_DIR:-$HOME/.cache/ccache}"
CC=clang CXX=clang++ cmake -S . -B "$BUILD_DIR" -G Ninja -DCMAKE_BUILD_TYPE=Release -DRIM_FUZZ=ON \
  -DRIM_FUZZ_SECONDS="$SECONDS_PER_TARGET"
targets=$(sed -n 's/^rim_add_fuzz(\([a-z_]*\) .*/fuzz_\1/p' tests/fuzz/CMakeLists.txt)
# shellcheck disable=SC2086  # one word per target
cmake --build "$BUILD_DIR" --parallel "$JOBS" --target $targets
ctest --test-dir "$BUILD_DIR" --output-on-failure -L fuzz ${1:+-R "$1"}
