#!/usr/bin/env python3
"""Replicas behind a real HAProxy, sticky robots, and a failover that loses nothing.

On loopback, with the real binaries (docs/service.md, "Replicas and shared storage"):
  - 3 rim_server replicas share one data dir (--shared-sessions) behind Debian's HAProxy, run
    with the config that deploy/k8s also uses (deploy/haproxy/haproxy.cfg);
  - 6 robots create their sessions and stream the simulated city through the proxy with rimctl
    (which retries a broken stream, resending what has no final ack);
  - every robot's calls land on one replica (each replica's /metrics: a robot's scans are counted
    by exactly one);
  - one replica holding robots is killed with SIGKILL mid-stream; its robots' streams break,
    reconnect through the proxy and go on at other replicas, which take the sessions over (last
    checkpoint, then the write-ahead log);
  - at the end every robot's map holds exactly the frames it streamed: none lost, none twice.
    Prints `acked: N, recovered: N, lost: 0` from the counts compared, and the failover time
    (kill to the first scan integrated on the new replica);
  - a planned move: SIGTERM to a second replica (it saves its sessions and lets go), the proxy's
    health checks take it off the ring, and LoadSession through the proxy opens its robots'
    sessions on the last replica;
  - a call without x-robot-id (GetServerInfo) is answered through the proxy.

Usage: scale_e2e.py BUILD_DIR [HAPROXY_CFG]
"""

from __future__ import annotations

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
import urllib.request
from typing import Dict, List, Optional

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
from failures import Failures  # noqa: E402

ROOT = os.path.normpath(os.path.join(HERE, "..", ".."))
ROBOTS = [f"robot_{i}" for i in range(6)]
FRAMES = 30
RATE_HZ = 4
# A small map (4 m box, few rays) so that 6 robots train on 2 cores at about the rate they stream.
SESSION = ["grid.half_extent_x_m=2", "grid.half_extent_y_m=2", "grid.z_min_m=-1.2",
           "grid.z_max_m=1.2", "train.iterations=3", "train.min_iterations=3",
           "sampler.rays_per_iteration=256"]


_GIVEN_PORTS: set = set()


def free_port() -> int:
    """A port free now that this run has not handed out before: the kernel may give the port a
    socket just closed on to the next bind, and a replica once got the same port to listen on and
    to serve its metrics on."""
    while True:
        with socket.socket() as s:
            s.bind(("127.0.0.1", 0))
            port = s.getsockname()[1]
        if port not in _GIVEN_PORTS:
            _GIVEN_PORTS.add(port)
            return port


def wait_port(port: int, timeout_s: float) -> bool:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        try:
            socket.create_connection(("127.0.0.1", port), timeout=0.5).close()
            return True
        except OSError:
            time.sleep(0.1)
    return False


def servers_up(stats_port: int) -> Dict[str, str]:
    """server -> status (UP, DOWN, ...) of the replicas' backend, from HAProxy's CSV stats."""
    try:
        text = urllib.request.urlopen(f"http://127.0.0.1:{stats_port}/stats;csv",
                                      timeout=5).read().decode()
    except OSError:
        return {}
    lines = text.splitlines()
    if not lines:
        return {}
    header = lines[0].lstrip("# ").split(",")
    status = header.index("status") if "status" in header else 17
    out = {}
    for line in lines[1:]:
        cells = line.split(",")
        if len(cells) > status and cells[0] == "rim_replicas" and cells[1].startswith("rim-"):
            out[cells[1]] = cells[status]
    return out


def wait_servers_up(stats_port: int, names: List[str], timeout_s: float) -> bool:
    """Until HAProxy counts every named replica UP: before that its ring lacks them, and a
    session created then would open on a replica its robot is not routed to afterwards."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        up = servers_up(stats_port)
        if all(up.get(n) == "UP" for n in names):
            return True
        time.sleep(0.2)
    return False


class Replica:
    def __init__(self, build: str, data: str, logs: str, index: int) -> None:
        self.name = f"rim-{index}"
        self.port, self.metrics_port = free_port(), free_port()
        self.log = open(os.path.join(logs, f"{self.name}.log"), "w")
        self.process = subprocess.Popen(
            [os.path.join(build, "server", "rim_server"), "--listen", f"127.0.0.1:{self.port}",
             "--metrics", f"127.0.0.1:{self.metrics_port}", "--data-dir", data,
             "--shared-sessions", "--replica-id", self.name, "--warmup-frames", "0",
             "--checkpoint-every", "8"],
            stdout=subprocess.DEVNULL, stderr=self.log)

    def scans(self) -> Dict[str, int]:
        """robot -> scans accepted here, from this replica's /metrics."""
        text = urllib.request.urlopen(f"http://127.0.0.1:{self.metrics_port}/metrics",
                                      timeout=10).read().decode()
        out = {}
        for m in re.finditer(r'^rim_scans_accepted_total\{session="([^"]+)"\} (\S+)$', text,
                             re.M):
            out[m.group(1)] = int(float(m.group(2)))
        return out

    def integrated(self) -> Dict[str, int]:
        text = urllib.request.urlopen(f"http://127.0.0.1:{self.metrics_port}/metrics",
                                      timeout=10).read().decode()
        return {m.group(1): int(float(m.group(2))) for m in re.finditer(
            r'^rim_scans_integrated_total\{session="([^"]+)"\} (\S+)$', text, re.M)}

    def alive(self) -> bool:
        return self.process.poll() is None


def main() -> int:
    if len(sys.argv) < 2:
        print(__doc__)
        return 2
    build = os.path.abspath(sys.argv[1])
    cfg = sys.argv[2] if len(sys.argv) > 2 else os.path.join(ROOT, "deploy", "haproxy",
                                                            "haproxy.cfg")
    haproxy = shutil.which("haproxy") or "/usr/sbin/haproxy"
    if not os.access(haproxy, os.X_OK):
        print("scale_e2e: haproxy is not installed (deploy/install-deps.sh installs it)")
        return 1
    rimctl = os.path.join(build, "clients", "rimctl")
    work = tempfile.mkdtemp(prefix="rim_scale_")
    data, logs = os.path.join(work, "data"), os.path.join(work, "logs")
    os.makedirs(data)
    os.makedirs(logs)
    f = Failures()
    replicas = [Replica(build, data, logs, i) for i in range(3)]
    proxy_port, stats_port = free_port(), free_port()
    env = dict(os.environ, RIM_PROXY_BIND=f"127.0.0.1:{proxy_port}",
               RIM_PROXY_STATS_BIND=f"127.0.0.1:{stats_port}",
               **{f"RIM_REPLICA_{r.name[-1]}": f"127.0.0.1:{r.port}" for r in replicas})
    proxy_log = open(os.path.join(logs, "haproxy.log"), "w")
    # The proxy starts once the replicas listen, and sessions are created once it counts them all
    # UP: a replica its first checks found closed stays off the ring for a few seconds.
    replicas_listening = all(wait_port(r.port, 60) for r in replicas)
    proxy = subprocess.Popen([haproxy, "-db", "-f", cfg], env=env, stdout=proxy_log,
                             stderr=subprocess.STDOUT)
    via_proxy = dict(os.environ, RIM_SERVER=f"127.0.0.1:{proxy_port}")
    streams: Dict[str, subprocess.Popen] = {}
    try:
        f.check(replicas_listening and wait_port(proxy_port, 30) and
                wait_servers_up(stats_port, [r.name for r in replicas], 30),
                "3 replicas listening, HAProxy listening and counting them UP")
        # Health through the proxy: no x-robot-id, so round robin across the replicas.
        for _ in range(100):
            if subprocess.run([rimctl, "health"], env=via_proxy,
                              capture_output=True).returncode == 0:
                break
            time.sleep(0.2)
        info = subprocess.run([rimctl, "info"], env=via_proxy, capture_output=True, text=True)
        f.check(info.returncode == 0 and "max sessions" in info.stdout.lower(),
                f"GetServerInfo without x-robot-id through the proxy: {info.returncode}")

        for robot in ROBOTS:
            args = [rimctl, "session", "create", robot, "--preset", "maicity"]
            for s in SESSION:
                args += ["--set", s]
            created = subprocess.run(args, env=via_proxy, capture_output=True, text=True)
            f.check(created.returncode == 0, f"create {robot}: {created.stderr.strip()[:200]}")
        outputs: Dict[str, List[str]] = {r: [] for r in ROBOTS}

        def collect(robot: str, p: subprocess.Popen) -> None:
            for line in p.stdout:
                outputs[robot].append(line)

        readers = []
        for i, robot in enumerate(ROBOTS):
            p = subprocess.Popen([rimctl, "stream", robot,
                                  f"sim:city?frames={FRAMES}&seed={3 + i}&threads=1",
                                  "--rate", str(RATE_HZ), "--retries", "20"],
                                 env=via_proxy, stdout=subprocess.PIPE,
                                 stderr=subprocess.STDOUT, text=True)
            streams[robot] = p
            t = threading.Thread(target=collect, args=(robot, p), daemon=True)
            t.start()
            readers.append(t)

        # Sticky: once every robot has scans in, each is counted by exactly one replica.
        owner: Dict[str, str] = {}
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline:
            seen = {r.name: r.scans() for r in replicas}
            owner = {robot: name for name, counts in seen.items() for robot in counts
                     if counts[robot] > 0}
            if len(owner) == len(ROBOTS) and min(
                    sum(c.get(robot, 0) for c in seen.values()) for robot in ROBOTS) >= 6:
                break
            time.sleep(0.5)
        holders = {robot: [name for name, counts in seen.items() if counts.get(robot, 0) > 0]
                   for robot in ROBOTS}
        f.check(all(len(h) == 1 for h in holders.values()),
                f"each robot's scans land on one replica: {holders}")
        spread = sorted(set(owner.values()))
        print(f"robots by replica: { {n: sorted(r for r, o in owner.items() if o == n) for n in spread} }")

        # kill -9 the replica holding the most robots, mid-stream.
        victim = max(replicas, key=lambda r: sum(1 for o in owner.values() if o == r.name))
        moved = sorted(r for r, o in owner.items() if o == victim.name)
        f.check(len(moved) >= 1, f"{victim.name} holds {moved}")
        # What the victim had accepted (durable in its sessions' logs) just before it dies.
        accepted_by_victim = victim.scans()
        killed_at = time.monotonic()
        victim.process.send_signal(signal.SIGKILL)
        victim.process.wait()
        print(f"killed {victim.name} (SIGKILL) holding {moved}", flush=True)
        survivors = [r for r in replicas if r is not victim]
        failover_s: Optional[float] = None
        while time.monotonic() - killed_at < 120 and failover_s is None:
            for r in survivors:
                if any(r.integrated().get(robot, 0) > 0 for robot in moved):
                    failover_s = time.monotonic() - killed_at
                    break
            time.sleep(0.1)
        f.check(failover_s is not None, f"failover: the first scan of {moved} integrated on "
                f"another replica {failover_s if failover_s is None else round(failover_s, 2)} s "
                "after the kill")

        for robot, p in streams.items():
            try:
                code = p.wait(600)
            except subprocess.TimeoutExpired:
                p.kill()
                code = -1
            # A failed stream shows all it printed: its retries and their reasons.
            shown = "".join(outputs[robot][-6:] if code == 0 else outputs[robot]).strip()
            f.check(code == 0, f"rimctl stream {robot} exit {code}: "
                    f"{shown[-1200:] if code == 0 else shown[-6000:]}")
        for t in readers:
            t.join(10)

        acked = 0
        recovered = 0
        in_maps = 0
        for robot in ROBOTS:
            text = "".join(outputs[robot])
            m = re.search(r"accepted: (\d+), integrated: (\d+)", text)
            accepted = int(m.group(1)) if m else 0
            integrated = int(m.group(2)) if m else 0
            acked += accepted
            got = subprocess.run([rimctl, "session", "get", robot], env=via_proxy,
                                 capture_output=True, text=True)
            if got.returncode != 0:
                print(f"session get {robot}: {got.stderr.strip()[:300]}")
            frames_m = re.search(r"map frames: (\d+)", got.stdout)
            frames = int(frames_m.group(1)) if frames_m else -1
            in_maps += max(frames, 0)
            if robot in moved:
                # Every scan the dead replica had accepted is in the new replica's map (the
                # robot's scans are numbered 0..FRAMES-1 and the map holds all FRAMES of them).
                recovered += min(accepted_by_victim.get(robot, 0), max(frames, 0))
            f.check(accepted == FRAMES and integrated == FRAMES and frames == FRAMES,
                    f"{robot}: acked {accepted}, integrated {integrated}, in the map {frames} "
                    f"(of {FRAMES})")
        lost = acked - in_maps
        print(f"acked: {acked}, recovered: {recovered}, lost: {lost}", flush=True)
        print(f"  (acked: scans ACCEPTED to the 6 robots; recovered: scans {victim.name} had "
              f"accepted before SIGKILL, {sum(accepted_by_victim.get(r, 0) for r in moved)}, "
              "found in the maps that other replicas took over; lost: acked minus the frames in "
              "all maps)")
        f.check(lost == 0 and acked == FRAMES * len(ROBOTS), "nothing lost, nothing doubled")
        if failover_s is not None:
            print(f"failover time: {failover_s:.2f} s (SIGKILL to the first scan integrated on "
                  f"the new replica)")

        # Planned move: SIGTERM saves and lets go; the proxy drops the replica from its ring;
        # LoadSession through the proxy opens the sessions elsewhere.
        live = [r for r in replicas if r.alive()]
        owners_now = {}
        for r in live:
            for robot, n in r.scans().items():
                if n > 0:
                    owners_now[robot] = r.name
        leaving = live[0]
        leaving_robots = sorted(r for r, o in owners_now.items() if o == leaving.name)
        leaving.process.send_signal(signal.SIGTERM)
        f.check(leaving.process.wait(120) == 0, f"{leaving.name} exits 0 on SIGTERM")
        time.sleep(3)  # two failed health checks, 1 s apart
        for robot in leaving_robots:
            loaded = subprocess.run([rimctl, "session", "load", robot], env=via_proxy,
                                    capture_output=True, text=True)
            frames_m = re.search(r"map frames: (\d+)", loaded.stdout)
            f.check(loaded.returncode == 0 and frames_m and int(frames_m.group(1)) == FRAMES,
                    f"LoadSession {robot} through the proxy after {leaving.name} left: "
                    f"{loaded.returncode} {loaded.stderr.strip()[:200]}")
        f.check(len(leaving_robots) >= 0, f"planned move of {leaving_robots}")
    finally:
        for p in streams.values():
            if p.poll() is None:
                p.kill()
        proxy.send_signal(signal.SIGTERM)
        try:
            proxy.wait(10)
        except subprocess.TimeoutExpired:
            proxy.kill()
        for r in replicas:
            if r.alive():
                r.process.send_signal(signal.SIGTERM)
                try:
                    r.process.wait(60)
                except subprocess.TimeoutExpired:
                    r.process.kill()
            r.log.close()
        proxy_log.close()
        if f.items:
            for name in sorted(os.listdir(logs)):
                with open(os.path.join(logs, name)) as log:
                    sys.stderr.write(f"---- {name} (tail)\n{log.read()[-3000:]}\n")
        shutil.rmtree(work, ignore_errors=True)
    return f.report("scale_e2e")


if __name__ == "__main__":
    sys.exit(main())
