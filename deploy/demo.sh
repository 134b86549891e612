#!/usr/bin/env bash
# The README's main job, end to end on one machine: install what is missing, build, start
# rim_server on loopback, create a session, stream the built-in synthetic city to it (rimctl
# stream ROBOT sim:city), pull the mesh tiles, score the mesh against the simulator's ground truth
# with rim_eval, draw distance slices, print the numbers and the server's own metrics, stop the
# server. Everything it writes goes to one folder, printed at the end.
#
# With --keep, the server stays up at the end (its dashboard URL printed) until Ctrl-C, so that a
# person can look at the map in a browser.
#
# Usage: bash deploy/demo.sh [--keep] [OUT_DIR]
# Environment: RIM_BUILD_DIR (default build), RIM_DEMO_FRAMES (default 40),
#   RIM_DEMO_ITERATIONS (default 20), RIM_SKIP_DEPS=1 to skip the dependency script,
#   RIM_SKIP_BUILD=1 to use the build as it is (the e2e test does both).
set -euo pipefail
cd "$(dirname "$0")/.."
ROOT="$(pwd)"
BUILD="${RIM_BUILD_DIR:-build}"
FRAMES="${RIM_DEMO_FRAMES:-40}"
ITERATIONS="${RIM_DEMO_ITERATIONS:-20}"
KEEP=""
OUT=""
for arg in "$@"; do
  case "$arg" in
    --keep) KEEP=1 ;;
    -*) echo "usage: bash deploy/demo.sh [--keep] [OUT_DIR]" >&2; exit 2 ;;
    *) OUT="$arg" ;;
  esac
done
OUT="${OUT:-$ROOT/demo-out}"
ROBOT=demo_car

say() { printf '\n== %s\n' "$*"; }

if [ -z "${RIM_SKIP_DEPS:-}" ]; then
  say "dependencies (Debian packages)"
  bash deploy/install-deps.sh
fi
if [ -z "${RIM_SKIP_BUILD:-}" ]; then
  say "build ($BUILD)"
  export CCACHE_DIR="${CCACHE_DIR:-$HOME/.cache/ccache}"
  cmake -S . -B "$BUILD" -G Ninja -DCMAKE_BUILD_TYPE=Release > /dev/null
  cmake --build "$BUILD" --parallel "$(nproc)" --target rim_server rimctl rim_sim rim_eval \
    $(grep -q '^RIM_BUILD_WEB:BOOL=ON' "$BUILD/CMakeCache.txt" && echo web)
fi
BUILD="$(cd "$BUILD" && pwd)"
RIMCTL="$BUILD/clients/rimctl"
rm -rf "$OUT"
mkdir -p "$OUT"

say "start rim_server"
# The browser dashboard too, when the build has it (the `web` target).
HTTP_FLAGS=()
[ -f "$BUILD/web/index.html" ] && HTTP_FLAGS=(--http 127.0.0.1:0)
"$BUILD/server/rim_server" --listen 127.0.0.1:0 --metrics 127.0.0.1:0 "${HTTP_FLAGS[@]}" \
  --data-dir "$OUT/data" > "$OUT/server.out" 2> "$OUT/server.log" &
SERVER_PID=$!
stop_server() {
  if kill -0 "$SERVER_PID" 2> /dev/null; then
    kill -TERM "$SERVER_PID"
    wait "$SERVER_PID" || true
  fi
}
trap stop_server EXIT
ADDR=""
for _ in $(seq 1 600); do
  ADDR="$(sed -n 's/^rim_server listening on //p' "$OUT/server.out")"
  [ -n "$ADDR" ] && break
  kill -0 "$SERVER_PID" 2> /dev/null || { cat "$OUT/server.log" >&2; exit 1; }
  sleep 0.1
done
[ -n "$ADDR" ] || { echo "rim_server did not start; see $OUT/server.log" >&2; exit 1; }
METRICS_URL="$(sed -n 's/^rim_server metrics on //p' "$OUT/server.out")"
DASHBOARD_URL="$(sed -n 's/^rim_server dashboard on //p' "$OUT/server.out")"
[ -n "$DASHBOARD_URL" ] && echo "dashboard: $DASHBOARD_URL (open it in a browser to watch the map grow)"
export RIM_SERVER="$ADDR"
# Health says SERVING once the server has warmed up.
for _ in $(seq 1 600); do "$RIMCTL" health > /dev/null 2>&1 && break; sleep 0.1; done
"$RIMCTL" info

say "session $ROBOT: stream $FRAMES frames of the synthetic city"
"$RIMCTL" session create "$ROBOT" --preset maicity --set "train.iterations=$ITERATIONS"
START=$(date +%s.%N)
"$RIMCTL" stream "$ROBOT" "sim:city?frames=$FRAMES&seed=3"
END=$(date +%s.%N)
"$RIMCTL" session get "$ROBOT"

say "mesh tiles"
"$RIMCTL" mesh "$ROBOT" --out "$OUT/mesh"

say "distance slices: 0.6 m above the street, and across it"
# The city's drive runs along x from (100, -1.75) at 1 m per frame. Queries answer the Euclidean
# distance to the mapped surface (bounded at 2 m), drawn with contour lines every 0.25 m.
X1=$(python3 -c "print(100 + $FRAMES + 8)")
XMID=$(python3 -c "print(100 + $FRAMES // 2 + 0.05)")
"$RIMCTL" query "$ROBOT" --grid "92,-12,0.6,$X1,8,0.6,0.1" --out "$OUT/slice.png" --range 2
"$RIMCTL" query "$ROBOT" --grid "$XMID,-12.5,-0.5,$XMID,8.5,3.5,0.05" \
  --out "$OUT/slice-street.png" --range 2

say "accuracy against the simulator's ground truth"
# The same city (same seed and frames) written to disk for its ground truth only.
"$BUILD/clients/rim_sim" --scene city --out "$OUT/city" --frames "$FRAMES" --seed 3 \
  --observed-box none > /dev/null
# Score where the robot-centric map was asked to reconstruct: the preset's box (±10 m, z ±3 m
# around the sensor) swept along the drive, 0.5 m inside its faces (as tests/e2e/offline_city.sh).
REGION="$(python3 "$ROOT/clients/tools/drive_region.py" "$OUT/city/poses.txt")"
"$BUILD/clients/rim_eval" "$OUT/mesh/mesh.ply" "$OUT/city/gt.ply" --region "$REGION" --json \
  > "$OUT/eval_mesh.json"
# Completeness and recall: the surface seen from any frame, near or far, inside the union of the
# local boxes along the drive (rim_eval --box --seq), as tests/e2e/offline_city.sh.
"$BUILD/clients/rim_eval" "$OUT/mesh/mesh.ply" "$OUT/city/gt_observed.ply" \
  --box 10,10,-3,3 --seq "$OUT/city" --json > "$OUT/eval_observed.json"

say "server metrics ($METRICS_URL)"
python3 - "$METRICS_URL" "$ROBOT" << 'PY' | tee "$OUT/metrics.txt"
import sys, urllib.request
url, robot = sys.argv[1], sys.argv[2]
text = urllib.request.urlopen(url, timeout=10).read().decode()
want = ["rim_scans_accepted_total", "rim_scans_integrated_total", "rim_scans_rejected_total",
        "rim_training_loss", "rim_frame_integration_seconds_sum",
        "rim_frame_integration_seconds_count", "rim_mesh_tile_bytes_total",
        "rim_session_host_memory_bytes", "rim_process_resident_memory_bytes"]
for line in text.splitlines():
    name = line.split("{")[0].split(" ")[0]
    if name in want:
        print(line)
PY

if [ -z "$KEEP" ]; then
  stop_server
  trap - EXIT
fi

say "result"
python3 - "$OUT" "$FRAMES" "$START" "$END" << 'PY' | tee "$OUT/summary.txt"
import json, os, sys
out, frames, start, end = sys.argv[1], int(sys.argv[2]), float(sys.argv[3]), float(sys.argv[4])
mesh = json.load(open(os.path.join(out, "eval_mesh.json")))["standard"]
obs = json.load(open(os.path.join(out, "eval_observed.json")))["standard"]
acc, prec = mesh["accuracy_cm"], mesh["precision_pct"]
comp, rec = obs["completeness_cm"], obs["recall_pct"]
f = 2 * prec * rec / (prec + rec)
print(f"streamed {frames} frames in {end - start:.1f} s ({frames / (end - start):.2f} frames/s)")
print(f"accuracy {acc:.2f} cm, completeness {comp:.2f} cm, Chamfer-L1 {(acc + comp) / 2:.2f} cm, "
      f"precision {prec:.2f} %, recall {rec:.2f} %, F-score {f:.2f} % (10 cm)")
print(f"mesh:      {os.path.join(out, 'mesh', 'mesh.ply')} (tiles: {os.path.join(out, 'mesh')}/*.drc)")
print(f"distance slices: {os.path.join(out, 'slice.png')} (0.6 m above the street), "
      f"{os.path.join(out, 'slice-street.png')} (across it)")
print(f"metrics:   {os.path.join(out, 'metrics.txt')}; server log: {os.path.join(out, 'server.log')}")
PY

if [ -n "$KEEP" ]; then
  say "keeping rim_server up (--keep)"
  echo "dashboard: ${DASHBOARD_URL:-(none: the build has no web target)}"
  echo "gRPC:      $ADDR (RIM_SERVER=$ADDR rimctl ...)"
  echo "press Ctrl-C to stop the server"
  trap 'stop_server; exit 0' INT TERM
  wait "$SERVER_PID" || true
fi
