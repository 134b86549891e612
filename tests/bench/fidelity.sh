#!/usr/bin/env bash
# Mesh fidelity and cost of rim against the TSDF reference (tests/bench/README.md, "TSDF
# reference"), on one dataset, one host, one evaluator. Runs, one after the other:
#   rim_map DATASET --preset PRESET                     -> OUT/rim
#   rim_tsdf DATASET --carve (min weight 1)             -> OUT/tsdf_carve
#   rim_tsdf DATASET --min-weight 5 (no carving)        -> OUT/tsdf
# then scores each mesh with rim_eval against DATASET/gt_observed.ply inside the union of the
# boxes BOX about the drive (--box BOX --seq DATASET), prints a table and writes OUT/fidelity.json.
# Usage: tests/bench/fidelity.sh BUILD DATASET OUT [PRESET] [BOX]
#   defaults: PRESET maicity, BOX 10,10,-3,3 (rim's local map: ±10 m, 3 m below and above)
# Environment: RIM=0 skips the rim_map run (an OUT/rim from an earlier run is still scored);
# RIM_ARGS adds arguments to rim_map (e.g. RIM_ARGS="--set train.iterations=10");
# TSDF_ARGS adds arguments to both rim_tsdf runs (e.g. TSDF_ARGS="--voxel 0.05 --trunc 0.15").
set -euo pipefail
if [ $# -lt 3 ]; then
  sed -n '2,13p' "$0" | sed 's/^# \{0,1\}//'
  exit 2
fi
BUILD="$(cd "$1" && pwd)"
DATASET="$(cd "$2" && pwd)"
OUT="$3"
PRESET="${4:-maicity}"
BOX="${5:-10,10,-3,3}"
RIM_MAP="$BUILD/clients/rim_map"
RIM_EVAL="$BUILD/clients/rim_eval"
RIM_TSDF="$BUILD/tests/bench/tsdf/rim_tsdf"
for bin in "$RIM_EVAL" "$RIM_TSDF"; do
  [ -x "$bin" ] || { echo "fidelity: $bin is missing (build it first)" >&2; exit 1; }
done
if [ "${RIM:-1}" != 0 ] && [ ! -x "$RIM_MAP" ]; then
  echo "fidelity: $RIM_MAP is missing (build it first, or RIM=0)" >&2
  exit 1
fi
[ -f "$DATASET/gt_observed.ply" ] || {
  echo "fidelity: $DATASET/gt_observed.ply is missing (rim_sim --observed-box none writes it)" >&2
  exit 1
}
mkdir -p "$OUT"
read -r -a rim_args <<< "${RIM_ARGS:-}"
read -r -a tsdf_args <<< "${TSDF_ARGS:-}"

runs=()
if [ "${RIM:-1}" != 0 ]; then
  echo "fidelity: rim_map --preset $PRESET ${RIM_ARGS:-}" >&2
  "$RIM_MAP" "$DATASET" --preset "$PRESET" --out "$OUT/rim" ${rim_args[@]+"${rim_args[@]}"} \
    > "$OUT/rim.log" 2>&1 || { tail -n 20 "$OUT/rim.log" >&2; exit 1; }
fi
[ -f "$OUT/rim/mesh.ply" ] && runs+=(rim)
echo "fidelity: rim_tsdf --carve ${TSDF_ARGS:-}" >&2
"$RIM_TSDF" "$DATASET" --out "$OUT/tsdf_carve" --carve ${tsdf_args[@]+"${tsdf_args[@]}"} \
  > "$OUT/tsdf_carve.log" 2>&1 || { tail -n 20 "$OUT/tsdf_carve.log" >&2; exit 1; }
echo "fidelity: rim_tsdf --min-weight 5 ${TSDF_ARGS:-}" >&2
"$RIM_TSDF" "$DATASET" --out "$OUT/tsdf" --min-weight 5 ${tsdf_args[@]+"${tsdf_args[@]}"} \
  > "$OUT/tsdf.log" 2>&1 || { tail -n 20 "$OUT/tsdf.log" >&2; exit 1; }
runs+=(tsdf_carve tsdf)

for run in "${runs[@]}"; do
  echo "fidelity: rim_eval $run" >&2
  "$RIM_EVAL" "$OUT/$run/mesh.ply" "$DATASET/gt_observed.ply" --box "$BOX" --seq "$DATASET" \
    --json > "$OUT/$run/eval.json"
done

python3 - "$OUT" "$DATASET" "$PRESET" "$BOX" "${runs[@]}" <<'PY'
import json, sys

out, dataset, preset, box = sys.argv[1:5]
runs = sys.argv[5:]
labels = {"rim": f"rim ({preset})", "tsdf_carve": "TSDF, carving, w>=1",
          "tsdf": "TSDF, no carving, w>=5"}
rows = []
for run in runs:
    timing = json.load(open(f"{out}/{run}/timing.json"))
    ev = json.load(open(f"{out}/{run}/eval.json"))
    m = ev["standard"]
    rows.append({
        "run": run,
        "label": labels.get(run, run),
        "ms_per_frame": timing["ms_per_frame"],
        # rim_map writes peak_rss_mb (ru_maxrss / 1024, so MiB); rim_tsdf peak_rss_mib.
        "peak_mib": timing.get("peak_rss_mib", timing.get("peak_rss_mb")),
        "acc_cm": m["accuracy_cm"],
        "comp_cm": m["completeness_cm"],
        "c_l1_cm": m["chamfer_l1_cm"],
        "precision_pct": m["precision_pct"],
        "recall_pct": m["recall_pct"],
        "f_pct": m["fscore_pct"],
        "floater_share": ev["floater_share"],
        "timing": timing if run != "rim" else {
            k: timing.get(k) for k in ("ms_per_frame", "frames", "iterations_per_frame",
                                       "peak_rss_mb", "mesh_s")},
        "eval": ev,
    })


def fmt(v, spec):
    return "n/a" if v is None else format(v, spec)


head = (f"{'run':<24} {'ms/frame':>9} {'peak MiB':>9} {'Acc':>7} {'Comp':>7} {'C-L1':>7} "
        f"{'P %':>7} {'R %':>7} {'F %':>7} {'floaters':>9}")
print(f"\n{dataset}: standard protocol against gt_observed.ply inside --box {box} "
      "(cm, %, floater share of the mesh area beyond 20 cm)")
print(head)
print("-" * len(head))
for r in rows:
    print(f"{r['label']:<24} {fmt(r['ms_per_frame'], '9.1f')} {fmt(r['peak_mib'], '9.0f')} "
          f"{fmt(r['acc_cm'], '7.2f')} {fmt(r['comp_cm'], '7.2f')} {fmt(r['c_l1_cm'], '7.2f')} "
          f"{fmt(r['precision_pct'], '7.2f')} {fmt(r['recall_pct'], '7.2f')} "
          f"{fmt(r['f_pct'], '7.2f')} {fmt(r['floater_share'], '9.4f')}")

ratios = {}
by_run = {r["run"]: r for r in rows}
if "rim" in by_run:
    rim = by_run["rim"]
    for run in ("tsdf_carve", "tsdf"):
        t = by_run.get(run)
        if t is None:
            continue
        ok = lambda a, b: a is not None and b not in (None, 0)
        ratios[run] = {
            "c_l1": rim["c_l1_cm"] / t["c_l1_cm"] if ok(rim["c_l1_cm"], t["c_l1_cm"]) else None,
            "time": (rim["ms_per_frame"] / t["ms_per_frame"]
                     if ok(rim["ms_per_frame"], t["ms_per_frame"]) else None),
        }
        print(f"rim / {labels[run]}: C-L1 x{fmt(ratios[run]['c_l1'], '.2f')}, "
              f"time per frame x{fmt(ratios[run]['time'], '.2f')}")
json.dump({"dataset": dataset, "preset": preset, "box": box, "rows": rows,
           "rim_ratio_to": ratios}, open(f"{out}/fidelity.json", "w"), indent=1)
print(f"-> {out}/fidelity.json")
PY
