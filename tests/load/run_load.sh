#!/usr/bin/env bash
# Starts rim_server on loopback and drives it with rim_load (ctest label `load`, not run by CI;
# results go into BENCHMARK.md). Usage: run_load.sh BUILD_DIR [rim_load flags...]
# RIM_SERVER_ARGS: extra rim_server flags (e.g. "--background-nice 0"), split on spaces.
set -euo pipefail
BUILD="$(cd "$1" && pwd)"
shift
WORK="$(mktemp -d)"
trap 'kill -TERM "$PID" 2> /dev/null || true; wait "$PID" 2> /dev/null || true; rm -rf "$WORK"' EXIT
# shellcheck disable=SC2086
"$BUILD/server/rim_server" --listen 127.0.0.1:0 --data-dir "$WORK/data" --checkpoint-every 0 \
  ${RIM_SERVER_ARGS:-} > "$WORK/out" 2> "${RIM_SERVER_LOG:-$WORK/log}" &
PID=$!
for _ in $(seq 1 600); do
  ADDR="$(sed -n 's/^rim_server listening on //p' "$WORK/out")"
  [ -n "$ADDR" ] && break
  sleep 0.1
done
[ -n "$ADDR" ] || { cat "${RIM_SERVER_LOG:-$WORK/log}" >&2; exit 1; }
/usr/bin/time -f "rim_load wall %e s" "$BUILD/tests/rim_load" --server "$ADDR" "$@"
grep -E "^VmHWM|^VmRSS" "/proc/$PID/status" | sed 's/^/rim_server /'
