#!/usr/bin/env bash
# The planner probe as an accuracy test (docs/core.md, "Metric distances"): two synthetic
# cities a planner finds hard, mapped offline, and the distances the final map answers scored
# against the exact distance to the scene's mesh at free-space points on the sensor's rays.
#   close: facades on the street frontage (0-0.5 m set-back), walls driven past at arm's length;
#   open:  facades 6-8 m back behind a wide flat ground seen at grazing angles, 1 cm range noise.
# Usage: distance_probe.sh BUILD_DIR [WORK_DIR]
set -euo pipefail
BUILD="$(cd "$1" && pwd)"
if [ -n "${2:-}" ]; then
  WORK="$2"
else
  WORK="$(mktemp -d)"
  [ -n "${RIM_KEEP_TEST_DIRS:-}" ] || trap 'rm -rf "$WORK"' EXIT
fi
FRAMES="${RIM_PROBE_FRAMES:-30}"

run() {  # NAME SEED rim_sim options...
  local name=$1 seed=$2
  shift 2
  "$BUILD/clients/rim_sim" --scene city --out "$WORK/$name" --frames "$FRAMES" --seed "$seed" \
    --observed-box none "$@" > /dev/null
  "$BUILD/clients/rim_map" "$WORK/$name" --preset maicity --out "$WORK/map_$name" \
    --set train.iterations=20 --probe metric 2>/dev/null | sed -n '/^probe/,$p'
}
run close 41 --building-setback 0,0.5
run open 42 --building-setback 6,8 --noise 0.01

python3 - "$WORK/map_close/probe.json" "$WORK/map_open/probe.json" <<'PY'
import json, sys
# Regression limits, not the benchmark's targets (BENCHMARK.md, "Metric distances", measures
# those on longer runs of held-out cities): these cities are short (30 frames at 20 iterations),
# so their maps are less complete and less sharp. The network's own values, which queries gave
# before, fail most of them by far (`--probe neural` on the close city: median errors of 28-66 cm
# beyond 0.1 m, 62-76 % of points more than 10 cm too far at 0.1-1 m, gradients within 10 degrees
# for 1-55 %).
failures = []
for path in sys.argv[1:]:
    report = json.load(open(path))
    for b in report["bins"]:
        name = f"{path.split('/')[-2]} {b['lo_m']:.1f}-{b['hi_m']:.1f} m"
        if b["points"] < 500:
            failures.append(f"{name}: only {b['points']} points scored")
            continue
        near = b["hi_m"] <= 0.3
        checks = [
            ("median |error|", b["median_abs_error_m"], 0.02 if near else 0.04, "<="),
            ("share > 10 cm too far", b["share_too_far"], 0.05, "<="),
            ("share with the wrong sign, 2 cm or more from the surface",
             b["share_wrong_sign_beyond_2cm"], 0.01, "<="),
        ]
        if b["lo_m"] >= 0.1:
            checks.append(("gradient within 10 deg", b["gradient_within_10deg"],
                           0.75 if near else 0.85, ">="))
        for what, value, limit, op in checks:
            ok = value <= limit if op == "<=" else value >= limit
            if not ok:
                failures.append(f"{name}: {what} {value:.4f}, limit {op} {limit}")
if failures:
    print("distance probe FAILED:\n  " + "\n  ".join(failures))
    sys.exit(1)
print("distance probe: every bin within its limits")
PY
