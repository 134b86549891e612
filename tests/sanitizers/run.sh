#!/usr/bin/env bash
# Builds rim with a sanitizer and runs tests under it (docs/testing.md, "Sanitizers").
#   bash tests/sanitizers/run.sh [address|thread] [ctest label regex, default 'unit|integration']
# address: ASan + LSan + UBSan; thread: TSan. Build folder: build-asan or build-tsan (override with
# RIM_BUILD_DIR). RIM_JOBS sets build and test parallelism (default: all cores for the build, 1 for
# ctest, since the integration tests time their servers and sanitizers already slow them).
#
# Every process that reports (test binaries, and the rim_server / rimctl / rim_sim children the
# tests start, whose stderr goes to log files the tests may not show) writes its report to
# <build>/sanitizer-logs/; the script prints them and fails when there are any, even if ctest
# passed.
set -euo pipefail
cd "$(dirname "$0")/../.."
VARIANT="${1:-address}"
LABELS="${2:-unit|integration}"
case "$VARIANT" in
  address) DEFAULT_DIR=build-asan TIMEOUT_S=4500 ;;
  thread) DEFAULT_DIR=build-tsan TIMEOUT_S=7500 ;;
  *)
    echo "usage: $0 [address|thread] [ctest label regex]" >&2
    exit 2
    ;;
esac
BUILD_DIR="${RIM_BUILD_DIR:-$DEFAULT_DIR}"
BUILD_JOBS="${RIM_JOBS:-$(nproc)}"
TEST_JOBS="${RIM_JOBS:-1}"

export CCACHE_DIR="${CCACHE_DIR:-$HOME/.cache/ccache}"
# RelWithDebInfo: optimised like production (some races only show with optimisation) and with
# line numbers in reports.
cmake -S . -B "$BUILD_DIR" -G Ninja -DCMAKE_BUILD_TYPE=RelWithDebInfo -DRIM_SANITIZE="$VARIANT"
build_start=$SECONDS
cmake --build "$BUILD_DIR" --parallel "$BUILD_JOBS"
echo "build: $((SECONDS - build_start)) s"

LOG_DIR="$(cd "$BUILD_DIR" && pwd)/sanitizer-logs"
rm -rf "$LOG_DIR"
mkdir -p "$LOG_DIR"
# Added to the defaults compiled into each binary (tests/sanitizers/default_options.cc.in).
# log_exe_name: reports are named <binary>.<pid>.
log_options="log_path=$LOG_DIR/report:log_exe_name=1"
export ASAN_OPTIONS="${ASAN_OPTIONS:+$ASAN_OPTIONS:}$log_options"
export UBSAN_OPTIONS="${UBSAN_OPTIONS:+$UBSAN_OPTIONS:}$log_options"
export TSAN_OPTIONS="${TSAN_OPTIONS:+$TSAN_OPTIONS:}$log_options"
export RIM_HKU_CAMPUS="${RIM_HKU_CAMPUS:-$(cd .. && pwd)/shared/data/hku_campus}"

# The gtest cases have no TIMEOUT of their own: they get ctest's 1500 s default scaled like the
# other tests (RIM_SANITIZE_TIMEOUT_SCALE in cmake/Sanitizers.cmake).
test_start=$SECONDS
status=0
ctest --test-dir "$BUILD_DIR" --output-on-failure -L "$LABELS" -j "$TEST_JOBS" --timeout "$TIMEOUT_S" ||
  status=$?
echo "tests: $((SECONDS - test_start)) s"

shopt -s nullglob
reports=("$LOG_DIR"/report.*)
if ((${#reports[@]} > 0)); then
  echo "sanitizer reports (${#reports[@]}):"
  for report in "${reports[@]}"; do
    echo "==> $report"
    cat "$report"
  done
  status=1
fi
exit "$status"
