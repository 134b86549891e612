#!/usr/bin/env bash
# Installs dependencies, builds rim and runs its tests. The one test command of README.md; CI
# runs exactly this. Usage: bash tests/run.sh [ctest label regex, default 'unit|integration|e2e']
set -euo pipefail
cd "$(dirname "$0")/.."
LABELS="${1:-unit|integration|e2e}"
BUILD_DIR="${RIM_BUILD_DIR:-build}"

bash deploy/install-deps.sh
export CCACHE_DIR="${CCACHE_DIR:-$HOME/.cache/ccache}"
cmake -S . -B "$BUILD_DIR" -G Ninja -DCMAKE_BUILD_TYPE=Release
cmake --build "$BUILD_DIR" --parallel "$(nproc)"
# The rim_data_dir of the real LiDAR data is optional: tests that use it skip with a message.
export RIM_HKU_CAMPUS="${RIM_HKU_CAMPUS:-$(cd .. && pwd)/shared/data/hku_campus}"
ctest --test-dir "$BUILD_DIR" --output-on-failure -L "$LABELS" --timeout 1200
