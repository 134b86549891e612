#!/usr/bin/env bash
# Runs the GPU path's checks on a machine with an NVIDIA GPU, from a bundle that tests/gpu/bundle.sh
# made: the kernels against the CPU path (gpu_kernels_test), the same under compute-sanitizer's
# memcheck where the machine has it, rim_map with --device cuda against --device cpu on a rim_sim
# city (C-L1 within 10 %), then the benchmark (rim_gpu_bench). Logs and JSON go to OUT_DIR. Exit status 0 only when every step passed. docs/gpu.md.
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

echo "== rim_map on the GPU against the CPU: a rim_sim city (seed ${RIM_GPU_SEED:=661})"
city=$out/city
rm -rf "$city" "$out"/map-*
"$bundle/bin/rim_sim" --scene city --out "$city" --frames "${RIM_GPU_FRAMES:-80}" \
  --seed "$RIM_GPU_SEED" >"$out/rim_sim.log" 2>&1 || failed+=(rim_sim)
for run in cpu-2:cpu:2 cpu-16:cpu:16 cuda:cuda:2; do
  IFS=: read -r name device threads <<<"$run"
  timeout 300 "$bundle/bin/rim_map" "$city" --preset maicity --out "$out/map-$name" \
    --device "$device" --set "train.threads=$threads" >"$out/map-$name.log" 2>&1 ||
    failed+=("rim_map-$name")
  timeout 120 "$bundle/bin/rim_eval" "$out/map-$name/mesh.ply" "$city/gt.ply" --json \
    --samples 2000000 --box 10,10,-3,3 --seq "$city" >"$out/map-$name/eval.json" 2>>"$out/map-$name.log" || failed+=("rim_eval-$name")
done
python3 - "$out" <<'PY' || failed+=(rim_map-gpu-vs-cpu)
import json, sys
out = sys.argv[1]
rows, summary = {}, {}
for name in ("cpu-2", "cpu-16", "cuda"):
    t = json.load(open(f"{out}/map-{name}/timing.json"))
    e = json.load(open(f"{out}/map-{name}/eval.json"))
    rows[name] = (t, e)
    stages = t["stages_ms_per_frame"]
    summary[name] = {"ms_per_frame": t["ms_per_frame"], "stages_ms_per_frame": stages,
                     "c_l1_cm": e["standard"]["chamfer_l1_cm"], "f_pct": e["standard"]["fscore_pct"],
                     "recall_pct": e["standard"]["recall_pct"]}
    print(f"{name:7s} {t['ms_per_frame']:8.1f} ms/frame  " +
          "  ".join(f"{k} {v:.1f}" for k, v in stages.items() if isinstance(v, (int, float))))
    print(f"        C-L1 {summary[name]['c_l1_cm']} cm, F {summary[name]['f_pct']} %, "
          f"recall {summary[name]['recall_pct']} %")
json.dump(summary, open(f"{out}/rim_map_gpu_vs_cpu.json", "w"), indent=2)
cpu, gpu = summary["cpu-2"]["c_l1_cm"], summary["cuda"]["c_l1_cm"]
print(f"C-L1: cpu {cpu}, cuda {gpu}")
sys.exit(0 if cpu is not None and gpu is not None and gpu <= 1.1 * cpu + 0.05 else 1)
PY

echo "== rim_gpu_bench"
timeout 300 "$bundle/bin/rim_gpu_bench" --out "$out/gpu_bench.json" 2>&1 |
  tee "$out/gpu_bench.log" || failed+=(rim_gpu_bench)

if ((${#failed[@]})); then
  echo "FAILED: ${failed[*]}"
  exit 1
fi
echo "all GPU checks passed"
