#!/usr/bin/env bash
# The JSON files rim_map writes (timing.json, run.json, probe.json) and rim_eval --json stay valid
# JSON whatever bytes the paths in them hold: a dataset and an --out folder whose names have a tab,
# a newline, \x01, \x1f, a quote and a backslash, read back with Python's json and compared.
# Usage: rim_map_json.sh BUILD_DIR [WORK_DIR]
set -euo pipefail
BUILD="$(cd "$1" && pwd)"
if [ -n "${2:-}" ]; then
  WORK="$2"
else
  WORK="$(mktemp -d)"
  [ -n "${RIM_KEEP_TEST_DIRS:-}" ] || trap 'rm -rf "$WORK"' EXIT
fi
ODD=$'odd\tname\n\x01\x1f "q" \\b'
CITY="$WORK/city $ODD"
MAP="$WORK/map $ODD"

"$BUILD/clients/rim_sim" --scene city --out "$CITY" --frames 4 --seed 7 --columns 256 > /dev/null
"$BUILD/clients/rim_map" "$CITY" --preset maicity --out "$MAP" --frames 0:4 \
  --set train.iterations=2 --set train.min_iterations=1 --probe metric > /dev/null 2> "$WORK/rim_map.err" ||
  { cat "$WORK/rim_map.err"; exit 1; }
"$BUILD/clients/rim_eval" "$CITY/gt.ply" "$CITY/gt_observed.ply" --json --samples 20000 \
  --box 10,10,-3,3 --seq "$CITY" > "$WORK/eval.json"

python3 - "$CITY" "$MAP" "$WORK/eval.json" <<'PY'
import json, math, sys
city, out, eval_path = sys.argv[1:]
assert "\t" in city and "\x01" in city and "\n" in city

def load(path):
    with open(path, "rb") as f:
        text = f.read().decode("utf-8")
    # Strict: control characters inside strings are an error, as are NaN and Infinity.
    return json.loads(text, strict=True, parse_constant=lambda c: sys.exit(f"{path}: {c}"))

run = load(f"{out}/run.json")
assert run["dataset"] == city, run["dataset"]
assert run["frames"] == [0, 4], run["frames"]
assert run["layout"] == "KITTI", run["layout"]
assert list(run)[:2] == ["rim_version", "libtorch_version"], list(run)
assert run["config"], "no config"

timing = load(f"{out}/timing.json")
assert timing["frames"] == 4, timing["frames"]
for key in ("rss_mb_per_frame", "ms_per_frame_series", "distance_mb_per_frame"):
    assert len(timing[key]) == 4, (key, timing[key])
assert list(timing)[0] == "stages_ms_per_frame", list(timing)
assert math.isfinite(timing["ms_per_frame"]) and timing["device_memory_mb"] is None

probe = load(f"{out}/probe.json")
assert list(probe) == ["drawn", "unseen_surface", "unobserved", "bins"], list(probe)
assert probe["bins"] and "median_abs_error_m" in probe["bins"][0], probe

ev = load(eval_path)
assert ev["prediction"] == f"{city}/gt.ply", ev["prediction"]
assert ev["box"]["seq"] == city, ev["box"]
assert ev["gt_kind"] == "points", ev["gt_kind"]
print("rim_map_json: passed")
PY
