#!/usr/bin/env bash
# The GPU checks that fit a short device loan, from a bundle that tests/gpu/bundle.sh made:
# gpu_kernels_test (the kernels against the CPU path), then rim_map --device cuda on a small
# rim_sim city, checking what it reports about the device: the `sync` stage and the device memory
# in timing.json, the device in run.json and MapperStats. tests/gpu/run.sh is the full set (memcheck,
# the CPU comparison on 80 frames, the benchmark). Exit status 0 only when every step passed.
#
# Usage: tests/gpu/quick.sh BUNDLE_DIR [OUT_DIR]
set -uo pipefail
bundle=$(cd "${1:?usage: tests/gpu/quick.sh BUNDLE_DIR [OUT_DIR]}" && pwd)
out=${2:-${OUT:-/tmp/rim-gpu}}
mkdir -p "$out"
export LD_LIBRARY_PATH=$bundle/lib${LD_LIBRARY_PATH:+:$LD_LIBRARY_PATH}
failed=()
nvidia-smi --query-gpu=name,driver_version,memory.total --format=csv 2>&1 | tee "$out/device.txt"

echo "== gpu_kernels_test"
timeout 120 "$bundle/bin/gpu_kernels_test" --gtest_output="xml:$out/gpu_kernels_test.xml" \
  >"$out/gpu_kernels_test.log" 2>&1 || failed+=(gpu_kernels_test)
grep -E '^\[ +(OK|FAILED|PASSED) +\]|Failure' "$out/gpu_kernels_test.log" | head -30

echo "== rim_map --device cuda, ${RIM_GPU_FRAMES:=30} frames (seed ${RIM_GPU_SEED:=671})"
city=$out/city
rm -rf "$city" "$out/map-cuda"
"$bundle/bin/rim_sim" --scene city --out "$city" --frames "$RIM_GPU_FRAMES" \
  --seed "$RIM_GPU_SEED" >"$out/rim_sim.log" 2>&1 || failed+=(rim_sim)
timeout 120 "$bundle/bin/rim_map" "$city" --preset maicity --out "$out/map-cuda" --device cuda \
  --set train.threads=2 >"$out/map-cuda.log" 2>&1 || failed+=(rim_map-cuda)
tail -25 "$out/map-cuda.log"
python3 - "$out/map-cuda" <<'PY' || failed+=(device-reports)
import json, sys
d = sys.argv[1]
t = json.load(open(f"{d}/timing.json"))
r = json.load(open(f"{d}/run.json"))
stages = t["stages_ms_per_frame"]
checks = {
    "timing.json has a sync stage > 0": isinstance(stages.get("sync"), (int, float)) and stages["sync"] > 0,
    "timing.json device_memory_mb > 0": isinstance(t.get("device_memory_mb"), (int, float)) and t["device_memory_mb"] > 0,
    "run.json names a cuda device": str(r.get("device", "")).startswith("cuda"),
}
print("stages:", {k: v for k, v in stages.items()}, "device_memory_mb:", t.get("device_memory_mb"),
      "device:", r.get("device"))
for what, ok in checks.items():
    print(("ok   " if ok else "FAIL ") + what)
sys.exit(0 if all(checks.values()) else 1)
PY

if ((${#failed[@]})); then
  echo "FAILED: ${failed[*]}"
  exit 1
fi
echo "quick GPU checks passed"
