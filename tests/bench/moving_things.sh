#!/usr/bin/env bash
# Moving things, measured (BENCHMARK.md, "Moving things"): for each seed, a noisy city with people
# crossing the street and cars passing in the other lane, and the same city without them. Each is
# mapped offline with the filter on and off, and scored against the static ground truth inside the
# union of the local boxes along the drive: floater share (mesh area beyond 20 cm of any true
# surface; ghosts: those also beyond 20 cm of what moves where the last scan saw it, rim_sim's
# gt_moving_last.ply), strict accuracy minus accuracy, C-L1, F-score, ms per frame and the filter's part of it
# (rim_map's "transient" stage). Prints one row per run
# and writes them to OUT/moving_things.json.
# Usage: tests/bench/moving_things.sh BUILD_DIR OUT_DIR [PRESET] [SEED ...]
#   defaults: PRESET maicity; seeds 301 302 303. Seed 302 sets facades back 4-10 m, seed 303 drives
#   0.7 m a frame: no seed here was looked at while the filter was tuned (that was seed 72).
# Environment: FRAMES (default 100), CROSSERS (6), MOVERS (3), NOISE (0.03); KINDS ("moving
# static") and FILTERS ("true false") choose the runs; ROWS_FILE names where rows are appended;
# RIM_MAP_ARGS adds rim_map arguments (e.g. "--set transient.past_frames=0").
set -euo pipefail
BUILD="$(cd "$1" && pwd)"
OUT="$2"
PRESET="${3:-maicity}"
shift $(( $# >= 3 ? 3 : $# ))
SEEDS=("$@")
[ ${#SEEDS[@]} -gt 0 ] || SEEDS=(301 302 303)
FRAMES="${FRAMES:-100}"
read -r -a MAP_ARGS <<< "${RIM_MAP_ARGS:-}"
mkdir -p "$OUT"
ROWS="${ROWS_FILE:-$OUT/rows.jsonl}"
[ -n "${ROWS_FILE:-}" ] || : > "$ROWS"

city_options() {  # SEED -> extra rim_sim options that make the seed's city differ
  case "$1" in
    302) echo "--building-setback 4,10" ;;
    303) echo "--step 0.7" ;;
    *) echo "" ;;
  esac
}

for seed in "${SEEDS[@]}"; do
  read -r -a extra <<< "$(city_options "$seed")"
  for kind in ${KINDS:-moving static}; do
    city="$OUT/city_${seed}_$kind"
    movers=()
    [ "$kind" = moving ] && movers=(--crossers "${CROSSERS:-6}" --movers "${MOVERS:-3}")
    [ -d "$city" ] || "$BUILD/clients/rim_sim" --scene city --out "$city" --frames "$FRAMES" \
      --seed "$seed" --noise "${NOISE:-0.03}" "${movers[@]}" ${extra[@]+"${extra[@]}"} > /dev/null
    for filter in ${FILTERS:-true false}; do
      run="$OUT/map_${seed}_${kind}_${PRESET}_$filter"
      "$BUILD/clients/rim_map" "$city" --preset "$PRESET" --out "$run" \
        --set transient.enabled=$filter ${MAP_ARGS[@]+"${MAP_ARGS[@]}"} > "$run.log" 2>&1
      # What moves, where the last scan saw it: there at the end, so floaters there are no ghosts.
      present=()
      [ -f "$city/gt_moving_last.ply" ] && present=(--present "$city/gt_moving_last.ply")
      "$BUILD/clients/rim_eval" "$run/mesh.ply" "$city/gt.ply" --box 10,10,-3,3 --seq "$city" \
        ${present[@]+"${present[@]}"} --json > "$run/eval_mesh.json"
      "$BUILD/clients/rim_eval" "$run/mesh.ply" "$city/gt_observed.ply" --box 10,10,-3,3 \
        --seq "$city" --json > "$run/eval_observed.json"
      python3 - "$run" "$seed" "$kind" "$PRESET" "$filter" >> "$ROWS" <<'PY'
import json, sys
run, seed, kind, preset, filt = sys.argv[1:]
mesh = json.load(open(f"{run}/eval_mesh.json"))
obs = json.load(open(f"{run}/eval_observed.json"))["standard"]
timing = json.load(open(f"{run}/timing.json"))
std, strict = mesh["standard"], mesh["strict"]
# Accuracy and precision against the scene mesh, completeness and recall against what the LiDAR
# saw (as the offline city test scores).
c_l1 = (std["accuracy_cm"] + obs["completeness_cm"]) / 2
p, r = std["precision_pct"], obs["recall_pct"]
print(json.dumps({
    "seed": int(seed), "city": kind, "preset": preset, "filter": filt == "true",
    "floater_pct": 100 * mesh["floater_share"], "floater_m2": mesh["floater_area_m2"],
    "ghost_pct": 100 * mesh.get("ghost_share", mesh["floater_share"]),
    "acc_cm": std["accuracy_cm"], "strict_acc_cm": strict["accuracy_cm"],
    "c_l1_cm": c_l1, "f_pct": 2 * p * r / (p + r), "recall_pct": r,
    "ms_per_frame": timing["ms_per_frame"],
    "preprocess_ms": timing["stages_ms_per_frame"].get("preprocess"),
    "transient_ms": timing["stages_ms_per_frame"].get("transient"),
    "removed": [timing.get("transient_buffer_removed", 0),
                timing.get("transient_deferred_removed", 0),
                timing.get("transient_departed_removed", 0),
                timing.get("transient_past_removed", 0)]}))
PY
      tail -n 1 "$ROWS" | python3 -c '
import json, sys
r = json.loads(sys.stdin.read())
print("seed %(seed)d %(city)-6s %(preset)-14s filter %(filter)-5s floaters %(floater_pct).3f %% "
      "(%(floater_m2).1f m2), ghosts %(ghost_pct).3f %%  strict-acc %(gap)+.2f cm  C-L1 %(c_l1_cm).3f  F %(f_pct).2f  "
      "%(ms_per_frame).0f ms/frame (filter %(transient_ms).1f)  removed %(removed)s"
      % dict(r, filter=str(r["filter"]), gap=r["strict_acc_cm"] - r["acc_cm"]))'
    done
  done
done
python3 -c 'import json, sys; print(json.dumps([json.loads(l) for l in open(sys.argv[1])], indent=1))' \
  "$ROWS" > "$OUT/moving_things.json"
