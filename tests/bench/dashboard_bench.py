#!/usr/bin/env python3
"""The browser dashboard under a fleet: frame time and memory in headless Chromium.

Starts rim_server --http on loopback, creates N sessions and streams F frames of the simulated
city into each (rimctl, a few streams at a time), then opens the dashboard in Debian's headless
Chromium (SwiftShader: software WebGL, no GPU) and reports
  - the time from opening the page to every listed tile loaded,
  - frame time (median, p95 over the page's last ~120 frames) sampled for --sample-s seconds,
  - the page's JS heap, and the resident memory of all the browser's processes,
  - the same while K sessions keep streaming (tiles replaced as their versions move).
Prints one JSON object (and writes it with --out). BENCHMARK.md quotes it.

The page shows the finest level of detail (as when these numbers were first measured), or the
level --resolution-m names (the page's ?resolution_m=R; docs/dashboard.md).

Usage: dashboard_bench.py BUILD_DIR [--sessions 12] [--frames 12] [--iterations 2] [--step 3]
                          [--sample-s 40] [--live 2] [--resolution-m 0] [--out FILE]
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from typing import Any, Dict, List

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.join(HERE, "..", "e2e"))
import cdp  # noqa: E402
from dashboard_e2e import Server, api_counts, get_json  # noqa: E402


def browser_rss_bytes(marker: str) -> int:
    """Resident memory of every process whose command line holds `marker` (the browser's
    private profile folder), summed."""
    total = 0
    for pid in os.listdir("/proc"):
        if not pid.isdigit():
            continue
        try:
            with open(f"/proc/{pid}/cmdline", "rb") as f:
                if marker.encode() not in f.read():
                    continue
            with open(f"/proc/{pid}/status") as f:
                for line in f:
                    if line.startswith("VmRSS:"):
                        total += int(line.split()[1]) * 1024
        except OSError:
            continue
    return total


def sample(browser: "cdp.Browser", seconds: float) -> Dict[str, Any]:
    medians, p95s, heaps, rss = [], [], [], []
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        time.sleep(1.0)
        state = browser.evaluate("JSON.parse(JSON.stringify(window.rimDashboard))")
        frame = state.get("frame_ms") or {}
        if frame.get("median") is not None:
            medians.append(frame["median"])
            p95s.append(frame["p95"])
        if state.get("heap_bytes"):
            heaps.append(state["heap_bytes"])
        rss.append(browser_rss_bytes(browser._tmp))  # noqa: SLF001 (its profile folder)
    return {
        "frame_ms_median": round(statistics.median(medians), 1) if medians else None,
        "frame_ms_p95": round(statistics.median(p95s), 1) if p95s else None,
        "js_heap_mb": round(max(heaps) / 1e6, 1) if heaps else None,
        "browser_rss_mb": round(max(rss) / 1e6, 1) if rss else None,
        "status": state.get("status"),
        "errors": state.get("errors"),
    }


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("build")
    parser.add_argument("--sessions", type=int, default=12)
    parser.add_argument("--frames", type=int, default=12)
    parser.add_argument("--iterations", type=int, default=2)
    parser.add_argument("--step", type=float, default=3.0, help="metres driven per frame")
    parser.add_argument("--sample-s", type=float, default=40.0)
    parser.add_argument("--live", type=int, default=2, help="sessions streaming while sampled")
    parser.add_argument("--resolution-m", type=float, default=0.0,
                        help="level of detail the page shows (0: the finest)")
    parser.add_argument("--out")
    args = parser.parse_args()
    build = os.path.abspath(args.build)
    rimctl = os.path.join(build, "clients", "rimctl")
    data = tempfile.mkdtemp(prefix="rim_dashboard_bench_")
    server = Server(build, data, "--max-sessions", str(args.sessions + 1))
    env = dict(os.environ, RIM_SERVER=server.address)
    result: Dict[str, Any] = {"sessions": args.sessions, "frames_per_session": args.frames,
                              "resolution_m": args.resolution_m}
    try:
        robots = [f"robot_{i:02d}" for i in range(args.sessions)]
        for robot in robots:
            subprocess.run([rimctl, "session", "create", robot, "--preset", "maicity", "--set",
                            f"train.iterations={args.iterations}", "--set",
                            f"train.min_iterations={args.iterations}"],
                           env=env, check=True, stdout=subprocess.DEVNULL)
        start = time.monotonic()
        for batch in range(0, len(robots), 3):
            streams = [subprocess.Popen([rimctl, "stream", robot,
                                         f"sim:city?frames={args.frames}&seed={3 + i}&step={args.step}"
                                         "&threads=1"],
                                        env=env, stdout=subprocess.DEVNULL,
                                        stderr=subprocess.DEVNULL)
                       for i, robot in enumerate(robots[batch:batch + 3], start=batch)]
            for p in streams:
                if p.wait() != 0:
                    raise RuntimeError("rimctl stream failed")
        result["streaming_s"] = round(time.monotonic() - start, 1)
        counts = api_counts(server.url, resolution_m=args.resolution_m)
        result["tiles"] = sum(t for t, _ in counts.values())
        result["triangles"] = sum(f for _, f in counts.values())

        with cdp.Browser(width=1280, height=800) as browser:
            opened = time.monotonic()
            browser.navigate(f"{server.url}/?resolution_m={args.resolution_m:g}")
            expected = json.dumps({r: [t, f] for r, (t, f) in counts.items()})
            browser.wait_for(
                "(() => { const s = window.rimDashboard; if (!s || s.status !== 'ok') return false;"
                f" const want = {expected};"
                " return Object.entries(want).every(([r, [t, f]]) => s.sessions[r] &&"
                " s.sessions[r].tiles_loaded === t && s.sessions[r].faces === f &&"
                " !s.sessions[r].pending); })()", timeout_s=600, interval_s=0.2)
            result["page_load_s"] = round(time.monotonic() - opened, 1)
            result["idle"] = sample(browser, args.sample_s)
            # A few robots keep streaming: tiles near them are replaced as versions move.
            live = [subprocess.Popen([rimctl, "stream", robot,
                                      f"sim:city?frames={args.frames + 6}&seed={3 + i}"
                                      f"&step={args.step}&threads=1"],
                                     env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
                    for i, robot in enumerate(robots[:args.live])]
            result["live_sessions"] = args.live
            result["live"] = sample(browser, args.sample_s)
            for p in live:
                p.kill()
                p.wait()
            result["gpu"] = browser.evaluate("JSON.parse(JSON.stringify("
                                             "window.rimDashboard.gpu || null))")
        sessions = get_json(server.url + "/api/v1/sessions")["sessions"]
        result["server_host_memory_mb"] = round(
            sum(s["host_memory_bytes"] for s in sessions) / 1e6, 1)
    finally:
        server.stop()
        shutil.rmtree(data, ignore_errors=True)
    text = json.dumps(result, indent=1)
    print(text)
    if args.out:
        with open(args.out, "w") as f:
            f.write(text + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
