#!/usr/bin/env bash
# End to end, offline: rim_sim makes a noise-free synthetic city with its ground-truth mesh,
# rim_map maps it with the maicity preset, rim_eval scores the mesh against the ground truth.
# Usage: offline_city.sh BUILD_DIR [WORK_DIR]
set -euo pipefail
BUILD="$(cd "$1" && pwd)"
ROOT="$(cd "$(dirname "$0")/../.." && pwd)"
if [ -n "${2:-}" ]; then
  WORK="$2"
else
  WORK="$(mktemp -d)"
  # A scratch folder of our own: removed on exit unless RIM_KEEP_TEST_DIRS is set.
  [ -n "${RIM_KEEP_TEST_DIRS:-}" ] || trap 'rm -rf "$WORK"' EXIT
fi
FRAMES="${RIM_E2E_FRAMES:-40}"

"$BUILD/clients/rim_sim" --scene city --out "$WORK/city" --frames "$FRAMES" --seed 3 --observed-box none
"$BUILD/clients/rim_map" "$WORK/city" --preset maicity --out "$WORK/map"

# Evaluate where the mapper was asked to reconstruct: the maicity local box (±10 m, z −3..+3 m
# around the sensor) swept along the drive, kept 0.5 m inside its faces. Walls above the box and
# streets beyond it were never in any local map.
REGION="$(python3 "$ROOT/clients/tools/drive_region.py" "$WORK/city/poses.txt")"
# Accuracy and precision against the scene mesh (dense, exact surfaces). Completeness and recall
# against the surface the LiDAR saw from any frame, near or far (gt_observed.ply written with
# --observed-box none), inside the union of the local boxes along the drive (rim_eval --box
# --seq): what a user sees missing. The full mesh also holds ground under parked cars and faces
# behind buildings that no scan reached.
"$BUILD/clients/rim_eval" "$WORK/map/mesh.ply" "$WORK/city/gt.ply" --region "$REGION" --json \
  > "$WORK/eval_mesh.json"
BOX=(--box 10,10,-3,3 --seq "$WORK/city")
"$BUILD/clients/rim_eval" "$WORK/map/mesh.ply" "$WORK/city/gt_observed.ply" "${BOX[@]}" \
  --json > "$WORK/eval_observed.json"
"$BUILD/clients/rim_eval" "$WORK/map/mesh.ply" "$WORK/city/gt_observed.ply" "${BOX[@]}"

python3 - "$WORK/eval_mesh.json" "$WORK/eval_observed.json" "$WORK/map/timing.json" <<'PY'
import json, sys
mesh = json.load(open(sys.argv[1]))["standard"]
obs = json.load(open(sys.argv[2]))["standard"]
timing = json.load(open(sys.argv[3]))
acc, prec = mesh["accuracy_cm"], mesh["precision_pct"]
comp, rec = obs["completeness_cm"], obs["recall_pct"]
c_l1 = (acc + comp) / 2
fscore = 2 * prec * rec / (prec + rec)
print(f"e2e offline city: Acc {acc:.2f} cm, Comp {comp:.2f} cm, C-L1 {c_l1:.2f} cm, "
      f"precision {prec:.2f} %, recall {rec:.2f} %, F-score {fscore:.2f} %, "
      f"{timing['ms_per_frame']:.0f} ms/frame")
# Measured 0.86 / 0.78 cm and 99.97 / 99.77 % (tests/e2e/README.md); the limits leave room for
# run-to-run training variation while failing on any real regression.
ok = c_l1 <= 2.0 and fscore >= 97.0
print("PASS" if ok else "FAIL: expected C-L1 <= 2.0 cm and F-score >= 97 %")
sys.exit(0 if ok else 1)
PY
