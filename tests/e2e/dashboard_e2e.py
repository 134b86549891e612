#!/usr/bin/env python3
"""The browser dashboard (rim_server --http, docs/dashboard.md) in a real headless Chromium.

Starts rim_server with --http on loopback, streams a few frames of the simulated city for two
robots with rimctl, and checks:
  - the JSON API against the gRPC API: sessions (and their levels of detail), tiles at the
    finest and at a coarse level (each tile's .drc bytes equal, byte for byte, to what
    GetMeshTiles returns at that level), trajectory, and the errors for bad input (unknown
    session or tile: 404 with a JSON error; bad `since` or `resolution_m`: 400; paths that try
    to leave the static folder: 404; methods other than GET/HEAD: 405; an oversized request
    line; slow clients that hold connections while gRPC keeps answering);
  - the page, in Debian's Chromium driven over the DevTools protocol (tests/e2e/cdp.py): it must
    start at the coarse default level (the level nearest 0.2 m) and report every tile the API
    lists at that level loaded, with the same tile and triangle counts, and no error; a
    screenshot is saved as the test's artefact. Switching its level select to the finest level
    must show exactly the API's tiles at that level (more triangles), and a link with
    ?resolution_m=R opens it at level R;
  - a failing case: a tile the API lists but that cannot be fetched (the browser answers its
    request with 500) shows an error on the page, and the same check then fails;
  - with --tokens: 401 without a token, the viewer's token reads, a robot's token reads only
    its own session (and, as on gRPC, may not list the sessions).

Usage: dashboard_e2e.py BUILD_DIR [ARTEFACT_DIR]   (with a Python that has rim_client installed)
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
import urllib.error
import urllib.request
from typing import Any, Dict, List, Optional, Tuple

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
import cdp  # noqa: E402
from failures import Failures  # noqa: E402

import rim_client  # noqa: E402

# Two robots in the same simulated city (seed 3), driving along +x from x = 100 m at 1 and 2 m per
# frame: robot -> step.
ROBOTS = {"car_a": 1, "car_b": 2}
FRAMES = 5
SESSION = {"train.iterations": 5, "train.min_iterations": 5}


class Server:
    """rim_server with --http on free loopback ports."""

    def __init__(self, build: str, data_dir: str, *extra: str) -> None:
        self.log = open(os.path.join(data_dir, "server.log"), "w")
        self.process = subprocess.Popen(
            [os.path.join(build, "server", "rim_server"), "--listen", "127.0.0.1:0",
             "--http", "127.0.0.1:0", "--data-dir", data_dir, "--warmup-frames", "0", *extra],
            stdout=subprocess.PIPE, stderr=self.log, text=True)
        lines: Dict[str, str] = {}

        def read() -> None:
            for line in self.process.stdout:
                for name, pattern in (("grpc", r"listening on (\S+)"),
                                      ("http", r"dashboard on (http://\S+)")):
                    match = re.search(pattern, line)
                    if match:
                        lines[name] = match.group(1)
                if len(lines) == 2:
                    return

        reader = threading.Thread(target=read, daemon=True)
        reader.start()
        reader.join(60)
        if len(lines) != 2:
            self.process.kill()
            raise RuntimeError(f"rim_server did not print both addresses: {lines}; see "
                               f"{self.log.name}")
        self.address = lines["grpc"]
        self.url = lines["http"].rstrip("/")
        self.port = int(self.url.rsplit(":", 1)[1])

    def stop(self) -> int:
        self.process.send_signal(signal.SIGTERM)
        try:
            return self.process.wait(60)
        finally:
            if self.process.poll() is None:
                self.process.kill()
            self.log.close()


def http(url: str, token: Optional[str] = None,
         method: str = "GET") -> Tuple[int, Dict[str, str], bytes]:
    request = urllib.request.Request(url, method=method)
    if token:
        request.add_header("Authorization", f"Bearer {token}")
    try:
        with urllib.request.urlopen(request, timeout=60) as response:
            return response.status, dict(response.headers), response.read()
    except urllib.error.HTTPError as error:
        return error.code, dict(error.headers), error.read()


def get_json(url: str, token: Optional[str] = None, expect: int = 200) -> Any:
    status, headers, body = http(url, token)
    if status != expect:
        raise AssertionError(f"GET {url}: status {status}, expected {expect}: {body[:300]!r}")
    if not headers.get("Content-Type", "").startswith("application/json"):
        raise AssertionError(f"GET {url}: Content-Type {headers.get('Content-Type')}")
    return json.loads(body)


def raw_request(port: int, data: bytes, timeout: float = 10.0) -> bytes:
    """Sends bytes as they are (no client-side path clean-up) and returns the whole reply."""
    with socket.create_connection(("127.0.0.1", port), timeout=timeout) as s:
        s.sendall(data)
        reply = b""
        while True:
            try:
                chunk = s.recv(65536)
            except (ConnectionResetError, socket.timeout):
                break
            if not chunk:
                break
            reply += chunk
        return reply


def status_of(reply: bytes) -> int:
    match = re.match(rb"HTTP/1\.[01] (\d{3})", reply)
    return int(match.group(1)) if match else -1


# The dashboard's default level of detail: the level nearest this among those the sessions offer
# (docs/dashboard.md).
DEFAULT_LEVEL_M = 0.2


def same_level(a: Any, b: float) -> bool:
    """Levels are float32 metres on the wire: equal within a micrometre, as the server compares."""
    return isinstance(a, (int, float)) and abs(a - b) < 1e-6


def nearest_level(levels: List[float], want: float) -> float:
    """The level nearest `want` (ties: the finer), as the page picks its default."""
    return min(sorted(levels), key=lambda level: abs(level - want))


def api_counts(url: str, token: Optional[str] = None,
               resolution_m: float = 0.0) -> Dict[str, Tuple[int, int]]:
    """robot -> (tiles, faces) as the API lists them at a level of detail (0: the finest)."""
    out = {}
    for entry in get_json(f"{url}/api/v1/sessions", token)["sessions"]:
        listing = get_json(f"{url}/api/v1/sessions/{entry['robot_id']}/tiles?since=0"
                           f"&resolution_m={resolution_m:g}", token)
        if resolution_m and not same_level(listing.get("resolution_m"), resolution_m):
            raise AssertionError(f"{entry['robot_id']}: asked for tiles at {resolution_m} m, "
                                 f"listed at {listing.get('resolution_m')}")
        tiles = listing["tiles"]
        out[entry["robot_id"]] = (len(tiles), sum(t["face_count"] for t in tiles))
    return out


def page_matches(state: Any, counts: Dict[str, Tuple[int, int]],
                 resolution_m: Optional[float] = None) -> Tuple[bool, str]:
    """Whether the page's published state shows exactly the API's tiles, with no error (and, when
    given, at that level of detail, for the page and every session)."""
    if not isinstance(state, dict):
        return False, f"no state published: {state!r}"
    if state.get("status") != "ok" or state.get("errors"):
        return False, f"page status {state.get('status')}, errors {state.get('errors')}"
    if resolution_m is not None and not same_level(state.get("resolution_m"), resolution_m):
        return False, f"page shows level {state.get('resolution_m')} m, not {resolution_m} m"
    sessions = state.get("sessions", {})
    if set(sessions) != set(counts):
        return False, f"page shows sessions {sorted(sessions)}, API lists {sorted(counts)}"
    for robot, (tiles, faces) in counts.items():
        s = sessions[robot]
        if resolution_m is not None and not same_level(s.get("resolution_m"), resolution_m):
            return False, f"{robot}: page lists tiles at {s.get('resolution_m')} m"
        if s.get("pending") or s.get("tiles_loaded") != tiles or s.get("faces") != faces:
            return False, (f"{robot}: page has {s.get('tiles_loaded')} tiles, {s.get('faces')} "
                           f"triangles, {s.get('pending')} pending; API lists {tiles} tiles, "
                           f"{faces} triangles")
    return True, "page matches the API" + ("" if resolution_m is None else
                                           f" at {resolution_m:g} m")


def page_state(browser: "cdp.Browser") -> Any:
    return browser.evaluate("window.rimDashboard ? JSON.parse(JSON.stringify("
                            "window.rimDashboard)) : null")


def wait_page(browser: "cdp.Browser", counts: Dict[str, Tuple[int, int]],
              timeout_s: float, resolution_m: Optional[float] = None) -> Tuple[bool, str, Any]:
    deadline = time.monotonic() + timeout_s
    ok, why, state = False, "", None
    while time.monotonic() < deadline:
        state = page_state(browser)
        ok, why = page_matches(state, counts, resolution_m)
        if ok or (isinstance(state, dict) and state.get("status") == "error"):
            break
        time.sleep(0.5)
    return ok, why, state


def check_api(server: Server, build: str, f: Failures) -> None:
    url = server.url
    sessions = get_json(f"{url}/api/v1/sessions")["sessions"]
    by_robot = {s["robot_id"]: s for s in sessions}
    f.check(set(by_robot) == set(ROBOTS), f"sessions listed: {sorted(by_robot)}")
    client = rim_client.Client(server.address, timeout=60.0)
    for robot in ROBOTS:
        entry = by_robot.get(robot, {})
        f.check(entry.get("integrated_frames") == FRAMES and entry.get("lag_frames") == 0
                and entry.get("trajectory_length") == FRAMES,
                f"{robot}: integrated {entry.get('integrated_frames')}, lag "
                f"{entry.get('lag_frames')}, trajectory {entry.get('trajectory_length')}")
        pose = entry.get("pose") or {}
        f.check(pose.get("frame") == FRAMES - 1 and len(pose.get("position", [])) == 3,
                f"{robot}: latest pose {pose}")
        info = client.session(robot).get()
        f.check(entry.get("map_version") == info.map_version,
                f"{robot}: map version {entry.get('map_version')} (gRPC {info.map_version})")

        levels = entry.get("mesh_levels_m") or []
        f.check(len(levels) >= 3 and len(levels) == len(info.mesh_levels_m)
                and all(same_level(a, b) for a, b in zip(levels, info.mesh_levels_m))
                and all(b > a for a, b in zip(levels, levels[1:])),
                f"{robot}: levels {levels} m, finest first, as gRPC's {info.mesh_levels_m}")
        if not levels:
            continue
        listed = get_json(f"{url}/api/v1/sessions/{robot}/tiles?since=0")
        f.check(same_level(listed.get("resolution_m"), levels[0]),
                f"{robot}: a listing without resolution_m is at the finest level "
                f"({listed.get('resolution_m')} m)")
        fine_faces = check_tile_bytes(url, client, robot, listed, 0.0, f)
        # A coarse level (the dashboard's default): its own bytes, as GetMeshTiles sends them at
        # that level, and every URL names the level.
        coarse = nearest_level(levels, DEFAULT_LEVEL_M)
        coarse_listed = get_json(f"{url}/api/v1/sessions/{robot}/tiles?since=0"
                                 f"&resolution_m={coarse:g}")
        f.check(same_level(coarse_listed.get("resolution_m"), coarse)
                and all("resolution_m=" in t["url"] for t in coarse_listed["tiles"])
                and not any("resolution_m=" in t["url"] for t in listed["tiles"]),
                f"{robot}: the {coarse:g} m listing says its level and its URLs name it")
        coarse_faces = check_tile_bytes(url, client, robot, coarse_listed, coarse, f)
        f.check(0 < coarse_faces < fine_faces,
                f"{robot}: {coarse_faces} triangles at {coarse:g} m, {fine_faces} at the finest")
        f.check({tuple(t["key"]): t["version"] for t in coarse_listed["tiles"]} ==
                {tuple(t["key"]): t["version"] for t in listed["tiles"]},
                f"{robot}: the same tiles at the same versions at every level")
        newest = max(t["version"] for t in listed["tiles"])
        f.check(listed.get("complete") is True and listed.get("next_since") == newest,
                f"{robot}: a complete listing says so, next_since {listed.get('next_since')}")
        f.check(get_json(f"{url}/api/v1/sessions/{robot}/tiles?since={newest}")["tiles"] == [],
                f"{robot}: nothing newer than version {newest}")

        trajectory = get_json(f"{url}/api/v1/sessions/{robot}/trajectory?since=0")
        xs = [p[0] for p in trajectory["positions"]]
        # The simulated drive runs along +x, `step` metres per frame.
        step = ROBOTS[robot]
        f.check(len(xs) == FRAMES and trajectory["next"] == FRAMES
                and all(abs(b - a - step) < 1e-3 for a, b in zip(xs, xs[1:])),
                f"{robot}: trajectory x {xs}")
        rest = get_json(f"{url}/api/v1/sessions/{robot}/trajectory?since={FRAMES - 2}")
        f.check(len(rest["positions"]) == 2, "trajectory since=N gives frames N, N+1, ...")
    client.close()

    # Bad input: clear JSON errors, and nothing changes. A level that is not the session's (or not
    # a number) is a 400 naming resolution_m.
    for path in ("/api/v1/sessions/car_a/tiles?resolution_m=0.07",
                 "/api/v1/sessions/car_a/tiles?since=0&resolution_m=abc",
                 "/api/v1/sessions/car_a/tiles?resolution_m=-0.2",
                 "/api/v1/sessions/car_a/tiles/0_0_0.drc?resolution_m=0.07"):
        status, headers, body = http(url + path)
        try:
            error = json.loads(body)["error"]
            named = error["code"] == 400 and "resolution_m" in error["message"]
        except (ValueError, KeyError, TypeError):
            named = False
        f.check(status == 400 and named, f"GET {path}: {status} {body[:160]!r}")
    for path, code in (("/api/v1/sessions/nobody", 404), ("/api/v1/sessions/nobody/tiles", 404),
                       ("/api/v1/sessions/car_a/tiles?since=abc", 400),
                       ("/api/v1/sessions/car_a/tiles?since=-1", 400),
                       ("/api/v1/sessions/car_a/trajectory?since=1e3", 400),
                       ("/api/v1/sessions/car_a/tiles/1_2.drc", 404),
                       ("/api/v1/sessions/car_a/tiles/999_999_999.drc", 404),
                       ("/api/v1/nothing", 404), ("/no-such-file.js", 404)):
        status, headers, body = http(url + path)
        try:
            error = json.loads(body)["error"]
            named = error["code"] == code and len(error["message"]) > 5
        except (ValueError, KeyError, TypeError):
            named = False
        f.check(status == code and named, f"GET {path}: {status} {body[:120]!r}")
    status, headers, _ = http(url + "/api/v1/sessions", method="POST")
    f.check(status == 405 and "GET" in headers.get("Allow", ""), f"POST: {status}")
    for path in ("/../../../../etc/passwd", "/%2e%2e/%2e%2e/%2e%2e/etc/passwd",
                 "/vendor/../../../../etc/hostname", "//etc/passwd", "/..%2f..%2fetc%2fpasswd"):
        reply = raw_request(server.port, f"GET {path} HTTP/1.1\r\nHost: x\r\n\r\n".encode())
        f.check(status_of(reply) in (400, 404) and b"root:" not in reply,
                f"GET {path}: {status_of(reply)}")
    status, headers, body = http(url + "/")
    f.check(status == 200 and b"<html" in body.lower() and
            headers.get("Content-Type", "").startswith("text/html"), f"GET /: {status}")

    # An oversized request line, and slow clients holding connections: gRPC keeps answering,
    # and so does the API once they are gone.
    reply = raw_request(server.port, b"GET /" + b"a" * 100000 + b" HTTP/1.1\r\n\r\n")
    f.check(status_of(reply) in (-1, 400, 413, 414, 431), f"100 kB request line: "
            f"{status_of(reply)}")
    slow = []
    for _ in range(24):
        s = socket.create_connection(("127.0.0.1", server.port), timeout=5)
        s.sendall(b"GET /api/v1/sessions HTTP/1.1\r\nHost: x\r\n")  # never finished
        slow.append(s)
    client = rim_client.Client(server.address, timeout=10.0)
    start = time.monotonic()
    info = client.session("car_a").get()
    f.check(info.integrated_frames == FRAMES and time.monotonic() - start < 5,
            f"gRPC with 24 stalled HTTP clients: {time.monotonic() - start:.2f} s")
    client.close()
    for s in slow:
        s.close()
    status, _, _ = http(url + "/api/v1/sessions")
    f.check(status == 200, f"API after the stalled clients left: {status}")


def check_tile_bytes(url: str, client: "rim_client.Client", robot: str, listed: Any,
                     resolution_m: float, f: Failures) -> int:
    """Every tile of an API listing at a level against GetMeshTiles at that level, byte for byte;
    returns the listing's triangles."""
    grpc_tiles = {t.key: t for t in client.session(robot).mesh_tiles(resolution_m=resolution_m)}
    http_tiles = {tuple(t["key"]): t for t in listed["tiles"]}
    level = f"{resolution_m:g} m" if resolution_m else "the finest level"
    f.check(len(http_tiles) > 0 and set(http_tiles) == set(grpc_tiles),
            f"{robot}: {len(http_tiles)} tiles listed at {level}, as GetMeshTiles")
    same = 0
    for key, t in http_tiles.items():
        status, headers, body = http(url + t["url"])
        g = grpc_tiles.get(key)
        if (status == 200 and g is not None and body == g.draco and t["version"] == g.version
                and t["face_count"] == g.face_count and t["bytes"] == len(body)
                and headers.get("X-Rim-Tile-Version") == str(g.version)
                and (not resolution_m or same_level(g.resolution_m, resolution_m))):
            same += 1
    f.check(same == len(http_tiles),
            f"{robot}: {same}/{len(http_tiles)} tiles at {level} byte-identical to GetMeshTiles")
    return sum(t["face_count"] for t in listed["tiles"])


def choose_level(browser: "cdp.Browser", resolution_m: float) -> Any:
    """Picks a level in the page's level select as a user does (its value, then 'change'); the
    select's options as (value, label) pairs."""
    return browser.evaluate(
        "(() => { const select = document.getElementById('level');"
        " const options = [...select.options].map((o) => [o.value, o.textContent]);"
        f" select.value = {json.dumps(f'{resolution_m:g}')};"
        " select.dispatchEvent(new Event('change'));"
        " return options; })()")


def check_page(server: Server, artefacts: str, f: Failures) -> None:
    levels = get_json(f"{server.url}/api/v1/sessions")["sessions"][0]["mesh_levels_m"]
    default = nearest_level(levels, DEFAULT_LEVEL_M)
    finest, middle = levels[0], levels[1]
    f.check(default != finest, f"the default level {default:g} m is coarser than {finest:g} m")
    counts = api_counts(server.url, resolution_m=default)
    fine_counts = api_counts(server.url, resolution_m=finest)
    with cdp.Browser(width=1280, height=800) as browser:
        browser.navigate(server.url + "/")
        ok, why, state = wait_page(browser, counts, timeout_s=120, resolution_m=default)
        f.check(ok, f"page loaded the API's tiles at the default level: {why}")
        if state:
            print("page state:", json.dumps({k: state.get(k) for k in
                                             ("status", "polls", "frame_ms", "heap_bytes",
                                              "resolution_m", "mesh_levels_m")}))
            f.check(len(state.get("mesh_levels_m") or []) == len(levels) and
                    all(same_level(a, b) for a, b in zip(state["mesh_levels_m"], levels)),
                    f"the page offers the sessions' levels: {state.get('mesh_levels_m')}")
        shot = os.path.join(artefacts, "dashboard.png")
        browser.screenshot(shot)
        f.check(os.path.getsize(shot) > 10000, f"screenshot {shot}")

        # The level select: every level, coarsest first; picking the finest drops the coarse
        # tiles and loads exactly the API's tiles at the finest level, with more triangles.
        options = choose_level(browser, finest)
        f.check([label for _, label in options] == [f"{level:g} m" for level in reversed(levels)],
                f"the level select lists {options}")
        ok, why, state = wait_page(browser, fine_counts, timeout_s=120, resolution_m=finest)
        f.check(ok, f"after switching to {finest:g} m the page shows the API's tiles: {why}")
        f.check(all(fine_counts[r][1] > counts[r][1] for r in counts),
                f"more triangles at {finest:g} m {fine_counts} than at {default:g} m {counts}")
        search = browser.evaluate("location.search")
        f.check(f"resolution_m={finest:g}" in search, f"the URL names the level: {search!r}")
        # And back to the coarsest: the fine tiles go, the coarse ones come (fewer triangles).
        coarsest = levels[-1]
        choose_level(browser, coarsest)
        coarsest_counts = api_counts(server.url, resolution_m=coarsest)
        ok, why, state = wait_page(browser, coarsest_counts, timeout_s=120, resolution_m=coarsest)
        f.check(ok, f"after switching to {coarsest:g} m the page shows the API's tiles: {why}")
        f.check(all(coarsest_counts[r][1] < counts[r][1] for r in counts)
                and (state or {}).get("level_switches") == 2,
                f"fewer triangles at {coarsest:g} m {coarsest_counts}, "
                f"{(state or {}).get('level_switches')} level switches")
        for message in browser.console_messages():
            print("console:", message)

    # A link to a level: ?resolution_m=R opens the page at R.
    with cdp.Browser(width=1280, height=800) as browser:
        middle_counts = api_counts(server.url, resolution_m=middle)
        browser.navigate(f"{server.url}/?resolution_m={middle:g}")
        ok, why, _ = wait_page(browser, middle_counts, timeout_s=120, resolution_m=middle)
        f.check(ok, f"?resolution_m={middle:g} opens the page at that level: {why}")

    # A tile the API lists but that cannot be fetched: the page shows an error and the same
    # check fails.
    with cdp.Browser(width=1280, height=800) as browser:
        robot = sorted(counts)[0]
        tiles = get_json(f"{server.url}/api/v1/sessions/{robot}/tiles?since=0"
                         f"&resolution_m={default:g}")["tiles"]
        broken = next(t for t in tiles if t["face_count"] > 0)
        name = "_".join(str(k) for k in broken["key"])
        browser.fail_requests(f"*/{robot}/tiles/{name}.drc*")
        browser.navigate(server.url + "/")
        ok, why, state = wait_page(browser, counts, timeout_s=120)
        f.check(not ok, f"the check fails when tile {name} cannot be fetched: {why}")
        panel = browser.evaluate("document.getElementById('errors') ? "
                                 "document.getElementById('errors').innerText : ''")
        f.check(name.replace("_", ",") in panel.replace(" ", "") or name in panel,
                f"the page names the tile in its error panel: {panel[:200]!r}")
        browser.screenshot(os.path.join(artefacts, "dashboard-error.png"))


def check_tokens(build: str, f: Failures) -> None:
    data = tempfile.mkdtemp(prefix="rim_dashboard_tokens_")
    rim_server = os.path.join(build, "server", "rim_server")
    lines = []
    for role, subject, token in (("admin", "ops", "admin-token"), ("viewer", "wall", "view-token"),
                                 ("robot", "car_a", "car-a-token")):
        digest = subprocess.run([rim_server, "--hash-token", token], capture_output=True,
                                text=True, check=True).stdout.strip()
        lines.append(f"{role} {subject} {digest}")
    tokens = os.path.join(data, "tokens")
    with open(tokens, "w") as out:
        out.write("\n".join(lines) + "\n")
    server = Server(build, data, "--tokens", tokens)
    try:
        client = rim_client.Client(server.address, token="admin-token", timeout=30.0)
        client.wait_ready(60)
        for robot in ("car_a", "car_b"):
            client.create_session(robot, overrides=SESSION)
        client.close()
        url = server.url
        status, headers, body = http(url + "/api/v1/sessions")
        f.check(status == 401 and "Bearer" in headers.get("WWW-Authenticate", ""),
                f"no token: {status}")
        status, _, _ = http(url + "/api/v1/sessions", token="wrong-token")
        f.check(status == 401, f"unknown token: {status}")
        status, _, _ = http(url + "/")
        f.check(status == 200, f"the page itself needs no token: {status}")
        viewer = get_json(url + "/api/v1/sessions", token="view-token")["sessions"]
        f.check(sorted(s["robot_id"] for s in viewer) == ["car_a", "car_b"],
                "the viewer's token lists every session")
        # A robot's token reads its own session, as on gRPC, and lists none.
        status, _, _ = http(url + "/api/v1/sessions", token="car-a-token")
        f.check(status == 403, f"a robot's token on the session list: {status}")
        own = get_json(url + "/api/v1/sessions/car_a", token="car-a-token")
        f.check(own["robot_id"] == "car_a", "a robot's token reads its own session")
        status, _, _ = http(url + "/api/v1/sessions/car_a/tiles", token="car-a-token")
        f.check(status == 200, f"a robot's token on its own tiles: {status}")
        status, _, _ = http(url + "/api/v1/sessions/car_b/tiles", token="car-a-token")
        f.check(status == 403, f"a robot's token on another robot's tiles: {status}")
    finally:
        f.check(server.stop() == 0, "rim_server with tokens exits 0 on SIGTERM")
        shutil.rmtree(data, ignore_errors=True)


def main() -> int:
    if len(sys.argv) < 2:
        print(__doc__)
        return 2
    build = os.path.abspath(sys.argv[1])
    artefacts = os.path.abspath(sys.argv[2] if len(sys.argv) > 2 else
                                os.path.join(build, "test-artefacts"))
    os.makedirs(artefacts, exist_ok=True)
    rimctl = os.path.join(build, "clients", "rimctl")
    data = tempfile.mkdtemp(prefix="rim_dashboard_")
    f = Failures()
    server = Server(build, data)
    try:
        client = rim_client.Client(server.address, timeout=60.0)
        client.wait_ready(120)
        for robot in ROBOTS:
            client.create_session(robot, preset="maicity", overrides=SESSION)
        client.close()
        env = dict(os.environ, RIM_SERVER=server.address)
        streams = [subprocess.Popen([rimctl, "stream", robot,
                                     f"sim:city?frames={FRAMES}&seed=3&step={step}"],
                                    env=env, stdout=subprocess.DEVNULL)
                   for robot, step in ROBOTS.items()]
        for p in streams:
            f.check(p.wait(600) == 0, "rimctl stream")
        check_api(server, build, f)
        check_page(server, artefacts, f)
    finally:
        status = server.stop()
        f.check(status == 0, f"rim_server exits 0 on SIGTERM ({status})")
        if f.items:
            with open(os.path.join(data, "server.log")) as log:
                sys.stderr.write(log.read()[-5000:])
        shutil.rmtree(data, ignore_errors=True)
    check_tokens(build, f)
    return f.report("dashboard_e2e")


if __name__ == "__main__":
    sys.exit(main())
