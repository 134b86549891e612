#!/usr/bin/env bash
# Starts rim_server on loopback and drives it with rim_load (ctest label `load`, not run by CI;
# results go into BENCHMARK.md). Usage: run_load.sh BUILD_DIR [rim_load flags...]
# RIM_SERVER_ARGS: extra rim_server flags (e.g. "--background-nice 0"), split on spaces.
# The server's metrics are scraped every second while the load runs; at the end the script prints
# what the load's dashboards cost (docs/service.md, "Sharing the cores"): the watchers' meshing CPU
# (rim_meshing_cpu_seconds_total) and wall time (rim_meshing_seconds_sum) per integrated frame
# (rim_scans_integrated_total), and their waits for the meshing budget, summed over the load's
# sessions (rim_load's "load_" robots) as last scraped before they closed. RIM_METRICS_OUT names a
# file for that scrape. It prints the same once more for the steady state: from the first scrape
# after the load's robots integrated RIM_STEADY_FRAMES frames each (default 40: the decoder trains
# over the first 20, and while it trains every push re-meshes every block) to the last.
set -euo pipefail
BUILD="$(cd "$1" && pwd)"
shift
WORK="$(mktemp -d)"
SCRAPER=""
trap '[ -n "$SCRAPER" ] && kill "$SCRAPER" 2> /dev/null; kill -TERM "$PID" 2> /dev/null || true; wait "$PID" 2> /dev/null || true; rm -rf "$WORK"' EXIT
# shellcheck disable=SC2086
"$BUILD/server/rim_server" --listen 127.0.0.1:0 --data-dir "$WORK/data" --checkpoint-every 0 \
  --metrics 127.0.0.1:0 ${RIM_SERVER_ARGS:-} > "$WORK/out" 2> "${RIM_SERVER_LOG:-$WORK/log}" &
PID=$!
ADDR=""
METRICS=""
for _ in $(seq 1 600); do
  ADDR="$(sed -n 's/^rim_server listening on //p' "$WORK/out")"
  METRICS="$(sed -n 's/^rim_server metrics on //p' "$WORK/out")"
  [ -n "$ADDR" ] && [ -n "$METRICS" ] && break
  sleep 0.1
done
[ -n "$ADDR" ] || { cat "${RIM_SERVER_LOG:-$WORK/log}" >&2; exit 1; }
# The scrape is bash's own HTTP/1.0 request (no chunked body), not a python3 or curl process a
# second: on a 2-core host a python3 start a second (0.12-0.17 s of CPU through a pyenv shim) took
# a sixth of a core from the server it measured. A server that stops answering costs one scrape
# (5 s), not the loop.
scrape() {  # http://HOST:PORT/metrics FILE
  local hostport="${1#http://}"
  hostport="${hostport%%/*}"
  local host="${hostport%:*}" port="${hostport##*:}"
  exec 3<> "/dev/tcp/$host/$port" || return 1
  printf 'GET /metrics HTTP/1.0\r\nHost: %s\r\n\r\n' "$host" >&3
  if ! timeout 5 cat <&3 > "$2"; then
    exec 3<&-
    return 1
  fi
  exec 3<&-
  grep -q '^HTTP/1\.[01] 200' "$2"
}
# Keeps every scrape that holds the load's sessions (their families go when they close); the
# newest is last_scrape.
(
  n=0
  while sleep 1; do
    scrape "$METRICS" "$WORK/scrape" 2> /dev/null || continue
    if grep -q 'session="load_' "$WORK/scrape"; then
      n=$((n + 1))
      cp "$WORK/scrape" "$WORK/scrape.$(printf %05d "$n")"
      mv "$WORK/scrape" "$WORK/last_scrape"
    fi
  done
) &
SCRAPER=$!
/usr/bin/time -f "rim_load wall %e s" "$BUILD/tests/rim_load" --server "$ADDR" "$@"
kill "$SCRAPER" 2> /dev/null || true
SCRAPER=""
grep -E "^VmHWM|^VmRSS" "/proc/$PID/status" | sed 's/^/rim_server /'
if [ -f "$WORK/last_scrape" ]; then
  [ -n "${RIM_METRICS_OUT:-}" ] && cp "$WORK/last_scrape" "$RIM_METRICS_OUT"
  python3 - "$WORK/last_scrape" "${RIM_STEADY_FRAMES:-40}" "$WORK"/scrape.* <<'PY'
import os, re, sys

KEYS = ("rim_scans_integrated_total", "rim_meshing_cpu_seconds_total", "rim_meshing_seconds_sum",
        "rim_meshing_seconds_count", "rim_meshing_budget_wait_seconds_total")


def read(path):
    """Sums of KEYS over the load's sessions, and the fewest frames any of them integrated."""
    sums, frames = {}, []
    for line in open(path):
        m = re.match(r'^(rim_[a-z_]+)\{[^}]*session="(load_[^"]*)"[^}]*\} (\S+)$', line)
        if m and m.group(1) in KEYS:
            sums[m.group(1)] = sums.get(m.group(1), 0.0) + float(m.group(3))
            if m.group(1) == KEYS[0]:
                frames.append(float(m.group(3)))
    return sums, min(frames, default=0.0)


def report(label, sums):
    frames = sums.get(KEYS[0], 0.0)
    if frames > 0:
        print("%s: meshing CPU %.1f ms per integrated frame, wall %.1f ms (%d tiles over %d "
              "frames), waited for the budget %.1f s"
              % (label, 1e3 * sums.get(KEYS[1], 0.0) / frames, 1e3 * sums.get(KEYS[2], 0.0) / frames,
                 sums.get(KEYS[3], 0.0), frames, sums.get(KEYS[4], 0.0)))


last, _ = read(sys.argv[1])
report("watchers", last)
steady = int(sys.argv[2])
for path in sorted(p for p in sys.argv[3:] if os.path.exists(p)):
    start, fewest = read(path)
    if fewest >= steady:
        report("watchers, steady (after %d frames a robot)" % steady,
               {k: last.get(k, 0.0) - start.get(k, 0.0) for k in KEYS})
        break
PY
fi
