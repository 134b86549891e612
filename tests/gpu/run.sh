#!/usr/bin/env bash
# Runs the GPU path's checks on a machine with an NVIDIA GPU, from a bundle that tests/gpu/bundle.sh
# made: the kernels against the CPU path (gpu_kernels_test), the same under compute-sanitizer's
# memcheck where the machine has it, then the benchmark (rim_gpu_bench). Logs and the benchmark's
# JSON go to OUT_DIR. Exit status 0 only when every step passed. docs/gpu.md.
#
# Usage: tests/gpu/run.sh BUNDLE_DIR [OUT_DIR]
set -uo pipefail
bundle=$(cd "${1:?usage: tests/gpu/run.sh BUNDLE_DIR [OUT_DIR]}" && pwd)
out=${2:-${OUT:-/tmp/rim-gpu}}
mkdir -p "$out"
export LD_LIBRARY_PATH=$bundle/lib${LD_LIBRARY_PATH:+:$LD_LIBRARY_PATH}
failed=()
nvidia-smi --query-gpu=name,driver_version,memory.total,clocks.max.sm --format=csv 2>&1 |
  tee "$out/device.txt"
nproc | sed 's/^/host cores: /' | tee -a "$out/device.txt"

echo "== gpu_kernels_test"
timeout 300 "$bundle/bin/gpu_kernels_test" --gtest_output="xml:$out/gpu_kernels_test.xml" \
  >"$out/gpu_kernels_test.log" 2>&1 || failed+=(gpu_kernels_test)
grep -E '^\[ +(OK|FAILED|SKIPPED|PASSED) +\]|Failure|error|Expected|Which is|vs' \
  "$out/gpu_kernels_test.log" | head -60

if command -v compute-sanitizer >/dev/null; then
  echo "== compute-sanitizer memcheck (the exact-comparison cases)"
  timeout 240 compute-sanitizer --tool memcheck --error-exitcode 3 \
    "$bundle/bin/gpu_kernels_test" \
    --gtest_filter='-*TrainingFollowsTheCpuPath:*DeviceMemoryStaysFlat' \
    >"$out/memcheck.log" 2>&1 || failed+=(memcheck)
  grep -E 'ERROR SUMMARY|PASSED|FAILED' "$out/memcheck.log" | tail -4
else
  echo "compute-sanitizer: not on this machine, memcheck skipped"
fi

echo "== rim_gpu_bench"
timeout 300 "$bundle/bin/rim_gpu_bench" --out "$out/gpu_bench.json" 2>&1 |
  tee "$out/gpu_bench.log" || failed+=(rim_gpu_bench)

if ((${#failed[@]})); then
  echo "FAILED: ${failed[*]}"
  exit 1
fi
echo "all GPU checks passed"
