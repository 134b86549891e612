#!/usr/bin/env bash
# The planner probe as an accuracy test (docs/core.md, "Metric distances"): two synthetic
# cities a planner finds hard, mapped offline, and the distances the final map answers scored
# against the exact distance to the scene's mesh at free-space points on the sensor's rays.
#   close: facades on the street frontage (0-0.5 m set-back), walls driven past at arm's length;
#   open:  facades 6-8 m back behind a wide flat ground seen at grazing angles, 1 cm range noise.
#   beside: facades 2-3.5 m back (11.5-13 m from the centre line), just beyond the side of the
#          +-10 m box: no box covers them, so the network never learns them and only the
#          distance field's returns (the deferred store's rays) put them in the distances.
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
run beside 43 --building-setback 2,3.5

python3 - "$WORK/map_close/probe.json" "$WORK/map_open/probe.json" \
  "$WORK/map_beside/probe.json" <<'PY'
import json, sys
# Regression limits, not the benchmark's targets (BENCHMARK.md, "Metric distances", measures
# those on longer runs of held-out cities): these cities are short (30 frames at 20 iterations),
# so their maps are less complete and less sharp. The network's own values, which queries gave
# before, fail most of them by far (`--probe neural` on the close city: median errors of 28-66 cm
# beyond 0.1 m, 62-76 % of points more than 10 cm too far at 0.1-1 m, gradients within 10 degrees
# for 1-55 %).
failures = []
# Over each whole city, the target BENCHMARK.md holds held-out cities to: at most 0.5 % of points
# more than 10 cm too far. The build before the distance field kept returns read 0.68 % (close)
# and 1.18 % (beside) here, 0.05 and 0.03 % after.
LIMIT_TOO_FAR = 0.005
for path in sys.argv[1:]:
    report = json.load(open(path))
    # Over the whole city: the share reported more than 10 cm too far (the dangerous direction).
    scored = sum(b["points"] for b in report["bins"])
    too_far = sum(b["share_too_far"] * b["points"] for b in report["bins"]) / max(1, scored)
    if too_far > LIMIT_TOO_FAR:
        failures.append(f"{path.split('/')[-2]}: {100 * too_far:.2f} % of all points more than "
                        f"10 cm too far, limit {100 * LIMIT_TOO_FAR} %")
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
