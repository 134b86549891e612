#!/usr/bin/env python3
"""rim_server's metrics scraped by a real Prometheus server (DESIGN.md §5.4, docs/metrics.md).

Starts rim_server with --metrics on a free loopback port, starts Debian's `prometheus` with a
config generated here (scraping that port every second), drives the server with the Python client
(a short synthetic sequence, one invalid scan, queries, mesh tiles, a save, an unknown session),
then asks Prometheus's HTTP API for the series and checks their values against what was done.
Finally every family listed in docs/metrics.md must exist in Prometheus.

Usage: prometheus_e2e.py RIM_SERVER_BIN   (with a Python that has rim_client installed)
"""

from __future__ import annotations

import json
import os
import re
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
import urllib.parse
import urllib.request
from typing import Dict, List, Optional

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.normpath(os.path.join(HERE, "..", ".."))
sys.path.insert(0, os.path.join(ROOT, "tests", "python"))
import synthetic_scene as scene  # noqa: E402

import rim_client  # noqa: E402

ROBOT = "metrics_robot"
FRAMES = 6
QUERY_POINTS = 500
SMALL_SESSION = {
    "grid.half_extent_x_m": 2, "grid.half_extent_y_m": 2, "grid.z_min_m": -1.2,
    "grid.z_max_m": 1.2, "train.iterations": 8, "sampler.rays_per_iteration": 512,
}


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def start_server(binary: str, data_dir: str) -> tuple:
    log = open(os.path.join(data_dir, "server.log"), "w")
    proc = subprocess.Popen([binary, "--listen", "127.0.0.1:0", "--metrics", "127.0.0.1:0",
                             "--data-dir", data_dir], stdout=subprocess.PIPE, stderr=log, text=True)
    found: Dict[str, str] = {}

    def read() -> None:
        for line in proc.stdout:
            m = re.search(r"metrics on http://(\S+:\d+)/metrics", line)
            if m:
                found["metrics"] = m.group(1)
            m = re.search(r"rim_server listening on (\S+:\d+)", line)
            if m:
                found["grpc"] = m.group(1)
                return

    reader = threading.Thread(target=read, daemon=True)
    reader.start()
    reader.join(60)
    if "grpc" not in found or "metrics" not in found:
        proc.kill()
        raise RuntimeError(f"rim_server did not print its addresses; see {log.name}")
    return proc, log, found["grpc"], found["metrics"]


def start_prometheus(work: str, target: str) -> tuple:
    port = free_port()
    config = os.path.join(work, "prometheus.yml")
    with open(config, "w") as f:
        f.write("global:\n  scrape_interval: 1s\n  evaluation_interval: 1s\n"
                "scrape_configs:\n  - job_name: rim\n"
                f"    static_configs:\n      - targets: ['{target}']\n")
    log = open(os.path.join(work, "prometheus.log"), "w")
    proc = subprocess.Popen(
        ["prometheus", f"--config.file={config}", f"--storage.tsdb.path={work}/tsdb",
         f"--web.listen-address=127.0.0.1:{port}"], stdout=log, stderr=log)
    url = f"http://127.0.0.1:{port}"
    deadline = time.time() + 60
    while time.time() < deadline:
        try:
            with urllib.request.urlopen(url + "/-/ready", timeout=2) as r:
                if r.status == 200:
                    return proc, log, url
        except OSError:
            time.sleep(0.3)
    proc.kill()
    raise RuntimeError(f"prometheus did not become ready; see {log.name}")


class Prom:
    def __init__(self, url: str) -> None:
        self.url = url

    def query(self, expr: str) -> List[dict]:
        q = urllib.parse.urlencode({"query": expr})
        with urllib.request.urlopen(f"{self.url}/api/v1/query?{q}", timeout=5) as r:
            body = json.load(r)
        if body.get("status") != "success":
            raise RuntimeError(f"query {expr}: {body}")
        return body["data"]["result"]

    def value(self, expr: str) -> Optional[float]:
        result = self.query(expr)
        return float(result[0]["value"][1]) if result else None

    def wait_for(self, expr: str, check, timeout_s: float = 30.0) -> float:
        """Polls until check(value) holds (scrapes happen every second)."""
        deadline, last = time.time() + timeout_s, None
        while time.time() < deadline:
            last = self.value(expr)
            if last is not None and check(last):
                return last
            time.sleep(0.5)
        raise AssertionError(f"{expr}: last value {last} never satisfied the check")


def documented_families() -> List[str]:
    with open(os.path.join(ROOT, "docs", "metrics.md")) as f:
        return re.findall(r"^\| `(rim_[a-z_]+)` \|", f.read(), flags=re.M)


def drive(address: str) -> None:
    client = rim_client.Client(address, timeout=60.0)
    client.wait_ready()
    session = client.create_session(ROBOT, overrides=SMALL_SESSION)
    poses = scene.trajectory(FRAMES)
    frames = [(scene.simulate_scan(p), p) for p in poses]
    bad = frames[0][0].copy()
    bad[3, 1] = np.nan
    frames.insert(2, (bad, poses[0]))  # rejected (INVALID_ARGUMENT), the stream goes on
    summary = session.stream(frames)
    assert summary.integrated == FRAMES and summary.rejected == 1, summary
    points = np.column_stack([np.linspace(-1, 1, QUERY_POINTS), np.zeros(QUERY_POINTS),
                              np.full(QUERY_POINTS, 0.1)]).astype(np.float32)
    session.query(points, gradient=True)
    assert session.mesh_tiles(), "no mesh tiles"
    # A dashboard: the first pushed tile is enough (its push delay is a metric).
    for _ in session.watch(since=0, timeout=60.0):
        break
    session.save()
    try:
        rim_client.Session(client, "nobody").query(points[:10])
        raise AssertionError("query of an unknown session succeeded")
    except rim_client.RimError as e:
        assert e.code == "NOT_FOUND", e


def main() -> int:
    binary = sys.argv[1]
    if shutil.which("prometheus") is None:
        print("prometheus is not installed (Debian package 'prometheus'; deploy/install-deps.sh)")
        return 1
    work = tempfile.mkdtemp(prefix="rim_prometheus_e2e_")
    server, server_log, grpc_addr, metrics_addr = start_server(binary, work)
    prom_proc, prom_log = None, None
    try:
        prom_proc, prom_log, prom_url = start_prometheus(work, metrics_addr)
        drive(grpc_addr)
        p = Prom(prom_url)
        s = f'{{session="{ROBOT}"}}'
        p.wait_for('up{job="rim"}', lambda v: v == 1)
        checks = [
            (f"rim_scans_accepted_total{s}", lambda v: v == FRAMES),
            (f"rim_scans_integrated_total{s}", lambda v: v == FRAMES),
            (f'rim_scans_rejected_total{{session="{ROBOT}",reason="invalid_argument"}}',
             lambda v: v == 1),
            (f"rim_ingest_queue_depth{s}", lambda v: v == 0),
            (f"rim_training_lag_frames{s}", lambda v: v == 0),
            (f"rim_iterations_per_frame{s}", lambda v: 1 <= v <= 8),
            # An upload trains on the configured batch (a robot in real time may not).
            (f"rim_rays_per_iteration{s}", lambda v: v == 512),
            # An upload is not paced: it never trains between frames.
            (f"rim_between_frames_iterations_total{s}", lambda v: v == 0),
            (f"rim_frame_integration_seconds_count{s}", lambda v: v == FRAMES),
            (f"rim_frame_integration_seconds_sum{s}", lambda v: v > 0),
            (f'rim_training_stage_seconds_count{{session="{ROBOT}",stage="backward"}}',
             lambda v: v == FRAMES),
            (f"rim_training_loss{s}", lambda v: 0 < v < 10),
            (f"rim_query_points_total{s}", lambda v: v == QUERY_POINTS),
            (f"rim_query_latency_seconds_count{s}", lambda v: v >= 1),
            (f"rim_mesh_tiles_encoded_total{s}", lambda v: v >= 1),
            (f"rim_mesh_tile_bytes_total{s}", lambda v: v > 100),
            (f"rim_meshing_seconds_count{s}", lambda v: v >= 1),
            (f"rim_mesh_tile_push_delay_seconds_count{s}", lambda v: v >= 1),
            (f"rim_meshing_cpu_seconds_total{s}", lambda v: v > 0),
            (f'rim_submaps{{session="{ROBOT}",state="active"}}', lambda v: v >= 1),
            (f"rim_session_host_memory_bytes{s}", lambda v: v > 1e6),
            # A static scene: later rays pass through nothing that was there.
            (f'rim_transient_points_removed_total{{session="{ROBOT}",store="buffer"}}',
             lambda v: v == 0),
            (f"rim_checkpoint_seconds_count{s}", lambda v: v >= 1),
            (f"rim_checkpoint_bytes{s}", lambda v: v > 1000),
            (f"rim_wal_append_seconds_count{s}", lambda v: v == FRAMES),
            ("rim_sessions_active", lambda v: v == 1),
            ("rim_process_resident_memory_bytes", lambda v: v > 1e7),
            ("rim_host_memory_budget_bytes", lambda v: v == 0),
            ('rim_grpc_requests_total{method="CreateSession",code="OK"}', lambda v: v == 1),
            ('rim_grpc_requests_total{method="QuerySdf",code="NOT_FOUND"}', lambda v: v == 1),
            ('rim_grpc_requests_total{method="StreamScans",code="OK"}', lambda v: v == 1),
            ('rim_grpc_request_seconds_count{method="SaveSession"}', lambda v: v == 1),
            # The median frame time from the buckets (cumulative counts: the frames may all have
            # been trained before the first scrape, so no rate()).
            (f"histogram_quantile(0.5, rim_frame_integration_seconds_bucket{s})",
             lambda v: 0 < v < 30),
            (f"histogram_quantile(0.99, rim_query_latency_seconds_bucket{s})",
             lambda v: 0 < v < 2.5),
        ]
        for expr, check in checks:
            value = p.wait_for(expr, check)
            print(f"ok  {expr} = {value:g}")
        missing = [f for f in documented_families()
                   if not p.query(f'{{__name__=~"{f}(_bucket|_sum|_count)?"}}')]
        if missing:
            raise AssertionError(f"families in docs/metrics.md that Prometheus never saw: {missing}")
        print(f"ok  all {len(documented_families())} documented families scraped")
    finally:
        if prom_proc is not None:
            prom_proc.terminate()
            prom_proc.wait(20)
            prom_log.close()
        server.send_signal(signal.SIGTERM)
        status = server.wait(60)
        server_log.close()
    if status != 0:
        print(open(os.path.join(work, "server.log")).read())
        raise AssertionError(f"rim_server exited with {status} after SIGTERM")
    shutil.rmtree(work, ignore_errors=True)
    print("PASS")
    return 0


if __name__ == "__main__":
    sys.exit(main())
