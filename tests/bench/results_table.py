#!/usr/bin/env python3
"""Regenerates the results tables of BENCHMARK.md from the JSON files in tests/bench/results/.

usage: results_table.py [--write PAGE | --check PAGE] [--results DIR] [TABLE ...]

  (no option)    print the tables (all, or the ones named) as Markdown
  --write PAGE   rewrite what stands between each `<!-- results:NAME -->` and the next
                 `<!-- /results -->` in PAGE (BENCHMARK.md) with the table NAME
  --check PAGE   exit 1, with a diff, where PAGE differs from what the JSON files give

Every number in a table comes from a file under tests/bench/results/; the layout below says which
file and field each row reads, its anchor and its target, and the script works out ranges and
whether the target is met. A file is read as one of:
  - a rim_bench --benchmark_out file (Google Benchmark JSON): one run per benchmark, the
    `median` aggregate where there are repetitions; field `real_time` and the counters, and
    `benchmark` is the run name without `/real_time` (rows match it by prefix);
  - rim_map's timing.json, rim_eval --json, rim_map --probe's probe.json: one run, the file;
  - tests/bench/moving_things.sh's moving_things.json: one run per row;
  - rim_load --json FILE: one run per robot, {"options", "robot", "load": the robot's numbers
    with the phase's "queries", "tiles" and "host_memory_mb", "baseline": the same robot's
    numbers alone (with --baseline), "percent": rays trained per frame period under load against
    alone};
  - tests/bench/fidelity.sh's fidelity.json: one run per row (the table `fidelity` reads every
    results/*fidelity*.json);
  - a long-mode CSV (rim_bench --rim_rss_csv): one run per frame;
  - a transcription: {"source": {...}, "runs": [...]}, each run in one of the shapes above (a
    subset of its fields) or a flat record. Results that were only ever written down as text
    in docs/perf-log.md are kept so, with "transcribed_from" naming the section.
A file's "source" (date, host, build, recorded_in, command, runs_note, transcribed_from or,
for a file the tools wrote, described_in) may also sit in
a sidecar NAME.source.json; rim_bench files take date and commit from their context.
Python 3 standard library only.
"""
import argparse
import csv
import difflib
import glob
import json
import os
import re
import sys

HERE = os.path.dirname(os.path.abspath(__file__))
RESULTS = os.path.join(HERE, "results")
LOG = "docs/perf-log.md"


# ----------------------------------------------------------------------------------------------
# Reading results files

class Results:
    def __init__(self, directory):
        self.directory = directory
        self.cache = {}

    def load(self, name):
        if name in self.cache:
            return self.cache[name]
        path = os.path.join(self.directory, name)
        if name.endswith(".csv"):
            with open(path, newline="") as f:
                runs = [{k: _number(v) for k, v in row.items()} for row in csv.DictReader(f)]
            obj = {}
        else:
            with open(path) as f:
                obj = json.load(f)
            runs = _runs(obj)
        source = dict(obj.get("source", {})) if isinstance(obj, dict) else {}
        sidecar = os.path.splitext(path)[0] + ".source.json"
        if not source and os.path.exists(sidecar):
            with open(sidecar) as f:
                source = json.load(f)
        if isinstance(obj, dict) and "benchmarks" in obj and "context" in obj:
            ctx = obj["context"]
            source.setdefault("date", ctx.get("date", "")[:10])
            if "commit" in ctx:
                source.setdefault("build", ctx["commit"])
        self.cache[name] = (source, runs)
        return self.cache[name]

    def values(self, name, field, **where):
        """The numbers of FIELD (a dotted path) over the runs of NAME that match WHERE."""
        _, runs = self.load(name)
        out = []
        for run in runs:
            if not all(_match(run, k, v) for k, v in where.items()):
                continue
            v = _get(run, field)
            if v is None:
                continue
            out.extend(v if isinstance(v, list) else [v])
        if not out:
            raise SystemExit(f"results_table: {name}: no value of {field} where {where}")
        return [float(x) for x in out]

    def runs(self, name, **where):
        _, runs = self.load(name)
        return [r for r in runs if all(_match(r, k, v) for k, v in where.items())]


def _number(text):
    try:
        return float(text)
    except (TypeError, ValueError):
        return text


def _is_rim_load(obj):
    return isinstance(obj, dict) and "options" in obj and "load" in obj and \
        isinstance(obj["load"], dict) and "robots" in obj["load"]


def _rim_load_runs(obj):
    """rim_load --json: one run per robot of the load phase."""
    def phase_robot(phase, i):
        robot = dict(phase["robots"][i])
        for key in ("queries", "tiles", "host_memory_mb"):
            if key in phase:
                robot[key] = phase[key]
        return robot
    out = []
    for i, robot in enumerate(obj["load"]["robots"]):
        run = {"options": obj["options"], "robot": robot.get("name"),
               "load": phase_robot(obj["load"], i)}
        if "baseline" in obj and i < len(obj["baseline"].get("robots", [])):
            run["baseline"] = phase_robot(obj["baseline"], i)
        for entry in obj.get("alone_vs_load", []):
            if entry.get("robot") == robot.get("name"):
                run["percent"] = entry.get("percent")
        out.append(run)
    return out


def _runs(obj):
    if isinstance(obj, list):                      # moving_things.json
        return obj
    if _is_rim_load(obj):                           # rim_load --json
        return _rim_load_runs(obj)
    if "runs" in obj:                               # a transcription, or rim_load outputs
        out = []
        for run in obj["runs"]:
            out.extend(_rim_load_runs(run) if _is_rim_load(run) else [run])
        return out
    if "benchmarks" in obj:                         # rim_bench --benchmark_out
        medians, singles = {}, {}
        for b in obj["benchmarks"]:
            name = b.get("run_name", b["name"])
            if b.get("aggregate_name") == "median":
                medians[name] = b
            elif b.get("run_type", "iteration") == "iteration" and "aggregate_name" not in b:
                singles.setdefault(name, b)
        out = []
        for name in dict.fromkeys(list(singles) + list(medians)):
            run = dict(medians.get(name, singles.get(name)))
            run["benchmark"] = name.replace("/real_time", "")
            out.append(run)
        return out
    if "rows" in obj:                               # fidelity.json
        return [dict(r, dataset=obj.get("dataset"), preset=obj.get("preset")) for r in obj["rows"]]
    return [obj]                                    # timing.json, rim_eval --json, probe.json


def _get(run, field):
    v = run
    for part in field.split("."):
        if not isinstance(v, dict) or part not in v:
            return None
        v = v[part]
    return v


def _match(run, key, want):
    if key == "benchmark":
        name = run.get("benchmark", "")
        return name == want or name.startswith(want + "/")
    if isinstance(want, list):  # any of them
        return _get(run, key) in want
    return _get(run, key) == want


# ----------------------------------------------------------------------------------------------
# Formatting

def fmt_range(values, digits=1, scale=1.0, suffix="", signed=False):
    lo, hi = min(values) * scale, max(values) * scale
    sign = "+" if signed else ""

    def one(v):
        text = f"{v:{sign}.{digits}f}"
        # A value that rounds to zero reads 0, whatever side of it it lay.
        return text.lstrip("+-") if float(text) == 0 else text

    a, b = one(lo), one(hi)
    return (a if a == b else f"{a} to {b}" if signed else f"{a}–{b}") + suffix


def status(values, target):
    """'yes', 'no', or 'in N of M runs' for a target (op, bound)."""
    if target is None:
        return "–"
    op, bound = target
    ok = [(v <= bound) if op == "<=" else (v >= bound) for v in values]
    if all(ok):
        return "yes"
    if not any(ok):
        return "no"
    return f"in {sum(ok)} of {len(ok)}"


def slug(title):
    s = title.strip().lower()
    s = re.sub(r"[^\w\- ]", "", s)
    return s.replace(" ", "-")


class Row:
    """One line of a results table.

    value: a function of Results giving the numbers (one per run or observation);
    anchor: text, or a function of Results giving text; target: (text, (op, bound)) or None;
    sources: the results files the row reads (numbered in the table's source list).
    """

    def __init__(self, measure, value, fmt, anchor="–", target=None, sources=()):
        self.measure, self.value, self.fmt = measure, value, fmt
        self.anchor, self.target, self.sources = anchor, target, list(sources)


def table(results, rows):
    order = []
    for row in rows:
        for s in row.sources:
            if s not in order:
                order.append(s)
    lines = ["| measure | rim now | anchor | target | met | source |",
             "|---|---|---|---|---|---|"]
    for row in rows:
        values = row.value(results)
        anchor = row.anchor(results) if callable(row.anchor) else row.anchor
        target_text, target = row.target if row.target else ("–", None)
        refs = ", ".join(str(order.index(s) + 1) for s in row.sources)
        lines.append(f"| {row.measure} | {fmt_range(values, **row.fmt)} | {anchor} | "
                     f"{target_text} | {status(values, target)} | {refs} |")
    lines.append("")
    lines.append("Sources (`tests/bench/results/`):")
    lines.append("")
    for i, name in enumerate(order, 1):
        lines.append(f"{i}. {source_line(results, name)}")
    return "\n".join(lines)


def source_line(results, name):
    src, _ = results.load(name)
    parts = [f"`{name}`"]
    when = ", ".join(x for x in (src.get("date"), src.get("host")) if x)
    if when:
        parts.append(when)
    build = []
    if src.get("build"):
        b = src["build"]
        build.append(f"build `{b}`" if re.fullmatch(r"[0-9a-f]{7,40}", b) else f"build {b}")
    if src.get("recorded_in"):
        build.append(f"recorded in `{src['recorded_in']}`")
    if build:
        parts.append(", ".join(build))
    text = "; ".join(parts) + "."
    if src.get("command"):
        text += f" Command: `{src['command']}`"
        text += "." if not src.get("runs_note") else f" ({src['runs_note']})."
    for key, verb in (("transcribed_from", "Transcribed from"), ("described_in", "Described in")):
        if src.get(key):
            text += f" {verb} [{LOG}, \"{src[key]}\"]({LOG}#{slug(src[key])})."
    return text


# ----------------------------------------------------------------------------------------------
# The tables: which file and field each row reads

def ratio_pct(results, name, field, num, den, key="seed"):
    """Per KEY: 100 * (NUM run's FIELD / DEN run's FIELD - 1)."""
    out = []
    for base in results.runs(name, run=den):
        other = results.runs(name, run=num, **{key: base[key]})
        for o in other:
            out.append(100 * (_get(o, field) / _get(base, field) - 1))
    return out


def per_km(mib_per_m):
    return [v * 1048576 * 1000 / 1e9 for v in mib_per_m]


def sum_ranges(results, name, fields):
    """Per run: the sum of the fields' lows and the sum of their highs."""
    out = []
    for run in results.runs(name):
        vals = [_get(run, f) for f in fields]
        vals = [v if isinstance(v, list) else [v] for v in vals]
        out += [sum(min(v) for v in vals), sum(max(v) for v in vals)]
    return out


def moving_c_l1_pct(results, name):
    out = []
    # The static city as mapped by default (filter on) where both were run.
    for static in results.runs(name, city="static"):
        if static.get("filter", True) is False:
            continue
        for on in results.runs(name, city="moving", filter=True, streamed=False, earlier=True,
                               seed=static["seed"], preset=static["preset"]):
            out.append(100 * (on["c_l1_cm"] / static["c_l1_cm"] - 1))
    return out


def turn_maps_row(measure, field):
    """A row of the moving-city maps of TRANSIENT_COST: the default build against every point
    judged at every turn (transient.quiet_turns=1)."""
    def maps(r, build):
        return r.values(TRANSIENT_COST, field, kind="map", city="moving", build=build)
    return Row(measure, lambda r: maps(r, "after"), F3,
               lambda r: "every point at every turn: " + fmt_range(maps(r, "before"), digits=3),
               ("≤ 0.1", ("<=", 0.1)), [TRANSIENT_COST])


def moving_gap(results, name, **where):
    out = []
    for r in results.runs(name, city="moving", **where):
        if "floater_pct" not in r:
            continue
        gap = r.get("strict_minus_acc_cm")
        out.append(gap if gap is not None else r["strict_acc_cm"] - r["acc_cm"])
    return out


F1 = {"digits": 1}
F2 = {"digits": 2}
F3 = {"digits": 3}

CITY120 = "2026-11-22-rim-map-city120.json"
FAR = "2026-11-27-frame-far.json"
REFRESH = "2026-11-27-rim-map-refresh.json"
QUERY = "2026-12-01-query.json"
QUERY_HOST_B = "2026-11-26-query.json"
# Distance-only queries searching the nearest disk's bound (3767812), and the build before.
QUERY_NOW = "2026-12-02-query-distance-only.json"
QUERY_AFTER, QUERY_BEFORE = "3767812", "2167a2d"
STREAMED = "2026-11-27-streamed-city.json"
HELDOUT = "2026-11-24-held-out-quality.json"
REFERENCE = "2026-11-22-reference-trainer.json"
PROBE = "2026-11-26-planner-probe.json"
LOAD = "2026-11-27-load.json"
LOAD_LEVELS = "2026-11-27-load-levels.json"
LOAD_BUDGET = "2026-12-01-load-budget.json"
BUDGET_BUILDS = ("81d12d6", "31bb540")  # the meshing budget's default at a tenth of the cores
LOAD_WATCHER = "2026-12-01-load-watcher.json"  # the 0.2 m watcher before and after 307337a
WATCHER_AFTER, WATCHER_BEFORE = ("307337a",), ("b45976d",)
LOAD_NOW = "2026-12-02-load-distance-only.json"  # before and after distance-only queries


def load_percent(results, resolution_m, build=BUDGET_BUILDS, cores=None, name=LOAD_BUDGET):
    """rim_load --baseline: rays trained per frame period under load, % of the robot alone, with
    the dashboard watching at RESOLUTION_M, on BUILD (with the budget at CORES when given)."""
    return [float(r["percent"]) for r in results.runs(name)
            if "options" in r and r["options"].get("tile_resolution_m") == resolution_m
            and r["options"].get("build") in build
            and (cores is None or r["options"].get("meshing_cores") == cores)]


def watcher_ms(results, resolution_m, build=BUDGET_BUILDS, cores=None, name=LOAD_BUDGET):
    """The load's watchers: meshing CPU per integrated frame, from the server's metrics."""
    return [float(r["meshing_cpu_ms_per_frame"]) for r in results.runs(name)
            if r.get("watchers") and r["tile_resolution_m"] == resolution_m
            and r["build"] in build and (cores is None or r["meshing_cores"] == cores)]
MESHING = "2026-11-25-meshing.json"
LEVELS = ["2026-12-01-levels-s746.json", "2026-12-01-levels-s747.json"]
LEVELS_AFTER, LEVELS_BEFORE = "307337a", "b45976d"
LEVEL_RUN = "MeshUpdate/incremental:1/frames_per_push:10/remesh_tolerance_mm:5/level_cm:"


def level_push_ms(results, level_cm, build=LEVELS_AFTER):
    """Meshing and Draco per frame of a watcher at LEVEL_CM, one value per seed and round."""
    out = []
    for name in LEVELS:
        where = {"benchmark": LEVEL_RUN + str(level_cm), "build": build}
        mesh = results.values(name, "mesh_ms_per_frame", **where)
        draco = results.values(name, "encode_ms_per_frame", **where)
        out += [m + d for m, d in zip(mesh, draco)]
    return out


def level_bytes_share(results, level_cm):
    """Draco bytes per pushed tile at LEVEL_CM over the finest level's, one value per seed."""
    out = []
    for name in LEVELS:
        where = {"build": LEVELS_AFTER}
        coarse = results.values(name, "bytes_per_tile", benchmark=LEVEL_RUN + str(level_cm),
                                **where)
        fine = results.values(name, "bytes_per_tile", benchmark=LEVEL_RUN + "0", **where)
        out += [c / f for c, f in zip(coarse, fine)]
    return out
BASELINE = "2026-11-22-default.json"
MEMORY = "2026-11-24-memory.json"
LONG500 = "2026-11-22-long500-half.maicity_online.csv"
MOVING = "2026-11-28-moving-things-earlier.json"
GHOSTS = "2026-12-02-moving-ghosts.json"
PLANNER_RICH = "2026-12-02-planner-rich.json"
TRANSIENT_COST = "2026-12-02-transient-gate.json"  # the turn where things move, and every turn
TSDF_MOVING = "2026-12-02-tsdf-moving.json"  # the TSDF reference on the cities of TRANSIENT_COST
BUSY = "2026-12-02-busy-places.json"  # passes added up in busy places, against the default
BUSY_DEFAULT = "2026-12-03-busy-default.json"  # busy places on and off, fresh seeds 785-787
CROSSINGS = "2026-11-28-planner-crossings.json"
CHECKPOINTS = "2026-11-25-checkpoints.json"
GPU = "2026-11-28-gpu.json"
GPU_MAP = "2026-11-28-gpu-rim-map.json"

QUERY_1M = "Query/points:1000000/gradient:{}/neural:0"
QUERY_PLANNER = "QueryPlanner/neural:0"


def query_mpoints(results, benchmark, points, build=None, name=QUERY_NOW, scale=1.0):
    """Points a second of a query benchmark of POINTS points (real_time in ms), times SCALE
    (1e6: points/s; 1: M points/s), over the runs of BUILD (all when None) in NAME."""
    where = {"benchmark": benchmark}
    if build is not None:
        where["build"] = build
    return [points * 1e3 / v / 1e6 * scale for v in results.values(name, "real_time", **where)]


def query_anchor(results, benchmark, points, host_d):
    """The build before in the same runs, and (HOST_D) host D's runs of 2026-12-01, M points/s."""
    text = "the build before, same runs: " + fmt_range(
        query_mpoints(results, benchmark, points, build=QUERY_BEFORE), digits=2)
    if host_d:
        text += "; host D, 2026-12-01: " + fmt_range(
            query_mpoints(results, benchmark, points, name=QUERY), digits=2)
    return text


TABLES = {
    "speed": [
        Row("`rim_map`, 120-frame city, `maicity` (30 iterations), ms a frame",
            lambda r: r.values(CITY120, "ms_per_frame", preset="maicity"), F1,
            "paper, RTX 3070 Ti: 253", ("≤ 200", ("<=", 200)), [CITY120]),
        Row("`rim_map`, 120-frame city, `maicity_online` (10 iterations), ms a frame",
            lambda r: r.values(CITY120, "ms_per_frame", preset="maicity_online"), F1,
            "paper, RTX 3070 Ti: 85", ("≤ 80", ("<=", 80)), [CITY120]),
        Row("`Frame/far/maicity` (facades beyond the box), ms a frame",
            lambda r: r.values(FAR, "real_time", benchmark="Frame/far/maicity"), {"digits": 0},
            lambda r: "first build: " + fmt_range(
                r.values(BASELINE, "real_time", benchmark="Frame/maicity"), digits=0)
            + " (`Frame/maicity`)", ("≤ 150", ("<=", 150)), [FAR, BASELINE]),
        Row("`Frame/far/maicity_online`, ms a frame",
            lambda r: r.values(FAR, "real_time", benchmark="Frame/far/maicity_online"), F1,
            lambda r: "first build: " + fmt_range(
                r.values(BASELINE, "real_time", benchmark="Frame/maicity_online"), digits=0)
            + " (`Frame/maicity_online`)", ("≤ 60", ("<=", 60)), [FAR, BASELINE]),
        Row("the distance field's refresh in `Frame/far/maicity_online`, ms a frame",
            lambda r: r.values(FAR, "distance_ms", benchmark="Frame/far/maicity_online"), F1,
            "–", None, [FAR]),
        Row("real campus scans, `rim_map --preset campus` (20 iterations), ms a frame",
            lambda r: r.values(REFRESH, "ms_per_frame", preset="campus"), F1,
            "–", None, [REFRESH]),
        Row("distance queries, 1M points, distance only, M points/s",
            lambda r: query_mpoints(r, QUERY_1M.format(0), 1e6, build=QUERY_AFTER, scale=1e6),
            {"digits": 2, "scale": 1e-6},
            lambda r: query_anchor(r, QUERY_1M.format(0), 1e6, host_d=True),
            ("≥ 1", (">=", 1e6)), [QUERY_NOW, QUERY]),
        Row("the same with the gradient, M points/s",
            lambda r: query_mpoints(r, QUERY_1M.format(1), 1e6, build=QUERY_AFTER, scale=1e6),
            {"digits": 2, "scale": 1e-6},
            lambda r: query_anchor(r, QUERY_1M.format(1), 1e6, host_d=False),
            None, [QUERY_NOW]),
        Row("distance queries where a planner asks (`QueryPlanner`, 100k points), M points/s",
            lambda r: query_mpoints(r, QUERY_PLANNER, 1e5, build=QUERY_AFTER, scale=1e6),
            {"digits": 2, "scale": 1e-6},
            lambda r: query_anchor(r, QUERY_PLANNER, 1e5, host_d=True),
            None, [QUERY_NOW, QUERY]),
    ],
    "quality": [
        Row("C-L1 offline, `maicity`, held-out cities 211, 223, 227, 229, cm",
            lambda r: r.values(STREAMED, "standard.chamfer_l1_cm", run="offline"), F2,
            "–", ("≤ 2.0", ("<=", 2.0)), [STREAMED]),
        Row("C-L1 streamed at 10 Hz beside a planner and a dashboard, above offline, %",
            lambda r: ratio_pct(r, STREAMED, "standard.chamfer_l1_cm", "streamed", "offline"),
            {"digits": 1, "signed": True}, "offline", ("≤ +10", ("<=", 10)), [STREAMED]),
        Row("C-L1 offline, held-out cities 21–23, cm",
            lambda r: r.values(HELDOUT, "standard.chamfer_l1_cm"), F2,
            "–", ("≤ 2.0", ("<=", 2.0)), [HELDOUT]),
        Row("recall (10 cm), held-out cities 21–23, %",
            lambda r: r.values(HELDOUT, "standard.recall_pct"), F2,
            "–", ("≥ 98", (">=", 98)), [HELDOUT]),
        Row("F-score (10 cm), held-out cities 21–23, %",
            lambda r: r.values(HELDOUT, "standard.fscore_pct"), F2,
            "–", ("≥ 98.5", (">=", 98.5)), [HELDOUT]),
        Row("C-L1 of the fast path above the dense reference trainer (e2e city), cm",
            lambda r: [r.values(REFERENCE, "standard.chamfer_l1_cm", step="fast")[0]
                       - r.values(REFERENCE, "standard.chamfer_l1_cm", step="reference")[0]],
            F2, lambda r: "`train.step=reference`: " + fmt_range(
                r.values(REFERENCE, "standard.chamfer_l1_cm", step="reference"), digits=3),
            ("≤ 0.2", ("<=", 0.2)), [REFERENCE]),
    ],
    "distances": [
        Row("median \\|error\\|, every bin 0–2 m, cm",
            lambda r: r.values(PROBE, "median_abs_error_cm_per_bin"), F2,
            "ESDFs at 10 cm voxels: Voxfield 2.7, FIESTA 4.0, voxblox 6.0 (published)",
            ("≤ 2 (≤ 4 beyond 0.3 m)", ("<=", 2)), [PROBE]),
        Row("points more than 10 cm too far, %",
            lambda r: r.values(PROBE, "too_far_pct"), F2,
            "–", ("≤ 0.5", ("<=", 0.5)), [PROBE]),
        Row("points with the wrong sign, %",
            lambda r: r.values(PROBE, "wrong_sign_pct"), F2,
            "–", ("≤ 0.5", ("<=", 0.5)), [PROBE]),
        Row("gradient within 10° of the truth, 0.1–2 m, %",
            lambda r: r.values(PROBE, "gradient_within_10deg_pct"), F1,
            "–", ("≥ 95", (">=", 95)), [PROBE]),
    ],
    "load": [
        Row("target load, the dashboard at 0.2 m (its default): rays trained per frame period, % "
            "of the robot alone in the same run",
            lambda r: load_percent(r, 0.2, (QUERY_AFTER,), name=LOAD_NOW), {"digits": 0},
            lambda r: "the build before, same rounds: " + fmt_range(
                load_percent(r, 0.2, (QUERY_BEFORE,), name=LOAD_NOW), digits=0)
            + "; host D, 2026-12-01: " + fmt_range(
                load_percent(r, 0.2, WATCHER_AFTER, name=LOAD_WATCHER), digits=0),
            ("≥ 80", (">=", 80)), [LOAD_NOW, LOAD_WATCHER]),
        Row("the same, the dashboard at the finest level (5 cm)", lambda r: load_percent(r, 0.0),
            {"digits": 0},
            lambda r: "meshing budget 0.5 (the default before): " + fmt_range(
                load_percent(r, 0.0, ("5a02c04",), 0.5), digits=0),
            ("≥ 80", (">=", 80)), [LOAD_BUDGET]),
        Row("target load through `rim_server`, a watcher at the finest level (5 cm): its meshing "
            "and Draco CPU per integrated frame, ms", lambda r: watcher_ms(r, 0.0), F1,
            lambda r: "meshing budget 0.5 (the default before): " + fmt_range(
                watcher_ms(r, 0.0, ("5a02c04",), 0.5), digits=1),
            ("≤ 20", ("<=", 20)), [LOAD_BUDGET]),
        Row("the same, a watcher at 0.2 m",
            lambda r: watcher_ms(r, 0.2, WATCHER_AFTER, name=LOAD_WATCHER), F1,
            lambda r: "the build before, same rounds: " + fmt_range(
                watcher_ms(r, 0.2, WATCHER_BEFORE, name=LOAD_WATCHER), digits=1),
            ("≤ 5", ("<=", 5)), [LOAD_WATCHER]),
        Row("target load, the dashboard at 0.2 m: robot integrates, frames/s",
            lambda r: [x["load"]["frames_per_s"] for x in r.runs(LOAD_WATCHER)
                       if "options" in x and x["options"]["tile_resolution_m"] == 0.2
                       and x["options"].get("build") in WATCHER_AFTER], F2,
            "the robot's rate: 10", ("≥ 9.5", (">=", 9.5)), [LOAD_WATCHER]),
        Row("target load: robot integrates, frames/s",
            lambda r: r.values(LOAD, "frames_per_s", load="target"), F2,
            "the robot's rate: 10", ("≥ 9.5", (">=", 9.5)), [LOAD]),
        Row("target load: median rays trained per frame period, k",
            lambda r: r.values(LOAD, "median_rays_per_frame_period", load="target"),
            {"digits": 1, "scale": 1e-3}, "10 iterations of 2048 rays",
            ("≥ 20.5", (">=", 20480)), [LOAD]),
        Row("target load: median iterations a frame (of 512 rays)",
            lambda r: r.values(LOAD, "median_iterations", load="target"), {"digits": 0},
            "–", None, [LOAD]),
        Row("target load, full batches (`sampler.paced_rays_per_iteration=0`): median rays "
            "per frame period, k",
            lambda r: r.values(LOAD, "median_rays_per_frame_period", load="target, full batches"),
            {"digits": 1, "scale": 1e-3}, "10 iterations of 2048 rays",
            ("≥ 20.5", (">=", 20480)), [LOAD]),
        Row("target load: query p99 (10k points), ms",
            lambda r: r.values(LOAD, "query_p99_ms", load="target"), F1,
            "–", ("≤ 50", ("<=", 50)), [LOAD]),
        Row("target load: tile latency p95, s",
            lambda r: r.values(LOAD, "tile_p95_ms", load="target"),
            {"digits": 2, "scale": 1e-3}, "–", ("≤ 2", ("<=", 2000)), [LOAD]),
        Row("2 robots, 2 planners, 1 dashboard: each robot, frames/s",
            lambda r: r.values(LOAD, "frames_per_s", load="2 robots"), F2,
            "–", None, [LOAD]),
        Row("4 robots, 2 planners, 2 dashboards: each robot, frames/s",
            lambda r: r.values(LOAD, "frames_per_s", load="4 robots"), F2,
            "–", None, [LOAD]),
        Row("2 and 4 robots: query p99, ms",
            lambda r: r.values(LOAD, "query_p99_ms", load="2 robots")
            + r.values(LOAD, "query_p99_ms", load="4 robots"), F1,
            "–", None, [LOAD]),
        Row("2 and 4 robots: tile latency p95, s",
            lambda r: r.values(LOAD, "tile_p95_ms", load="2 robots")
            + r.values(LOAD, "tile_p95_ms", load="4 robots"),
            {"digits": 2, "scale": 1e-3}, "–", None, [LOAD]),
    ],
    "meshing": [
        Row("a watcher at the finest level (5 cm), push every 10 frames: meshing and Draco, ms a "
            "frame", lambda r: level_push_ms(r, 0), F1,
            lambda r: "the build before: " + fmt_range(level_push_ms(r, 0, LEVELS_BEFORE)),
            ("≤ 20", ("<=", 20)), LEVELS),
        Row("the same at 0.1 m", lambda r: level_push_ms(r, 10), F1,
            lambda r: "the build before: " + fmt_range(level_push_ms(r, 10, LEVELS_BEFORE)),
            None, LEVELS),
        Row("the same at 0.2 m", lambda r: level_push_ms(r, 20), F1,
            lambda r: "the build before: " + fmt_range(level_push_ms(r, 20, LEVELS_BEFORE)),
            ("≤ 5", ("<=", 5)), LEVELS),
        Row("Draco bytes of a pushed tile at 0.2 m, share of the 5 cm tile's",
            lambda r: level_bytes_share(r, 20), F2, "–", ("≤ 0.33", ("<=", 0.33)), LEVELS),
        Row("a tile re-encoded (its changed blocks meshed, then Draco), ms",
            lambda r: sum_ranges(r, MESHING, ["tile_mesh_ms", "tile_draco_ms"]), {"digits": 0},
            "–", ("≤ 50", ("<=", 50)), [MESHING]),
        Row("`MeshTile`: the fullest 5 cm tile from scratch, ms",
            lambda r: r.values(MESHING, "mesh_tile_ms"), F1,
            lambda r: "first build: " + fmt_range(
                r.values(BASELINE, "real_time", benchmark="MeshTile"), digits=0),
            ("≤ 400 (no slower than before)", ("<=", 400)), [MESHING, BASELINE]),
    ],
    "memory": [
        Row("global map (sub-map store and deferred rays), GB per km of drive",
            lambda r: per_km([sum(r.values(MEMORY, f)[0] for f in
                                  ("store_mib_per_m", "deferred_mib_per_m"))]), F3,
            "official code: about 11 (40 GB for KITTI 00's 3.7 km)", ("≤ 1.5", ("<=", 1.5)),
            [MEMORY]),
        Row("distance field, GB per km of drive",
            lambda r: r.values(PROBE, "distance_mb_per_m", preset="maicity_online"), F3,
            "–", None, [PROBE]),
        Row("RSS less the sub-map store, growth from frame 100 to 499, MiB",
            lambda r: [(r.values(LONG500, "rss_bytes", frame=499.0)[0]
                        - r.values(LONG500, "submap_bytes", frame=499.0)[0]
                        - r.values(LONG500, "rss_bytes", frame=100.0)[0]
                        + r.values(LONG500, "submap_bytes", frame=100.0)[0]) / 1048576],
            {"digits": 0}, "–", None, [LONG500]),
    ],
    "moving": [
        Row("floaters (mesh area beyond 20 cm of any true surface), filter off, %",
            lambda r: r.values(MOVING, "floater_pct", city="moving", filter=False,
                               streamed=False), F2, "–", None, [MOVING]),
        Row("floaters, filter on (the default), %",
            lambda r: r.values(MOVING, "floater_pct", city="moving", filter=True, earlier=True,
                               streamed=False), F2,
            lambda r: "without earlier evidence: " + fmt_range(
                r.values(MOVING, "floater_pct", city="moving", filter=True, earlier=False,
                         streamed=False), digits=2),
            ("≤ 0.1", ("<=", 0.1)), [MOVING]),
        Row("floaters, filter on, the build of 2026-12-02: fresh seeds 766–768 and 701–703 "
            "again, `maicity` and `maicity_online`, %",
            lambda r: r.values(GHOSTS, "floater_pct"), F3, "–", ("≤ 0.1", ("<=", 0.1)),
            [GHOSTS]),
        Row("ghosts: those floaters also beyond 20 cm of what moves, where the last scan saw it "
            "(`rim_eval --present gt_moving_last.ply`), %",
            lambda r: r.values(GHOSTS, "ghost_pct"), F3,
            lambda r: "the same runs' floaters: " + fmt_range(r.values(GHOSTS, "floater_pct"),
                                                               digits=3),
            ("≤ 0.1", ("<=", 0.1)), [GHOSTS]),
        turn_maps_row("floaters, filter on, the build of 2026-12-02 that judges every point "
                      "where things move and a quarter as often elsewhere: fresh seeds 776–778 "
                      "(`maicity` and `maicity_online`) and 779–781 (`maicity_online`), %",
                      "floater_pct"),
        turn_maps_row("ghosts of those runs, %", "ghost_pct"),
        Row("floaters of the TSDF reference with space carving (`rim_tsdf --carve`, 10 cm "
            "voxels) on the cities of seeds 776–778, %",
            lambda r: r.values(TSDF_MOVING, "floater_pct", run="tsdf_carve"), F3,
            lambda r: "rim, same cities: " + fmt_range(
                [m["floater_pct"] for m in r.runs(TRANSIENT_COST, kind="map", city="moving",
                                                  build="after") if m["seed"] in (776, 777, 778)],
                digits=3) + "; the TSDF without carving: " + fmt_range(
                r.values(TSDF_MOVING, "floater_pct", run="tsdf_no_carve"), digits=1),
            None, [TSDF_MOVING, TRANSIENT_COST]),
        Row("floaters, filter on (the default), fresh seeds 782–784, `maicity` and "
            "`maicity_online`, %",
            lambda r: [m["floater_pct"] for m in r.runs(BUSY, kind="map", city="moving",
                                                         build="default")
                       if m["seed"] in (782, 783, 784)], F3, "–", ("≤ 0.1", ("<=", 0.1)),
            [BUSY]),
        Row("the same with passes added up in busy places (`transient.busy_drops=6`, not the "
            "default), %",
            lambda r: [m["floater_pct"] for m in r.runs(BUSY, kind="map", build="busy")
                       if m["seed"] in (782, 783, 784)], F3,
            lambda r: "tuning seed 778, `maicity_online`: 0.226 by default, " + fmt_range(
                [m["floater_pct"] for m in r.runs(BUSY, kind="map", build="busy", seed=778)],
                digits=3), ("≤ 0.1", ("<=", 0.1)), [BUSY]),
        Row("floaters with busy places on (not the default), fresh seeds 785–787, `maicity` and "
            "`maicity_online`, %",
            lambda r: [m["floater_pct"] for m in r.runs(BUSY_DEFAULT, city="moving", busy="on")],
            F3,
            lambda r: "the default (busy places off), same cities: " + fmt_range(
                [m["floater_pct"] for m in r.runs(BUSY_DEFAULT, city="moving", busy="off")],
                digits=3), ("≤ 0.1", ("<=", 0.1)), [BUSY_DEFAULT]),
        Row("C-L1 of those runs above the same city without movers, %",
            lambda r: [100 * (m["c_l1_cm"] / s["c_l1_cm"] - 1)
                       for s in r.runs(BUSY_DEFAULT, city="static", busy="on")
                       for m in r.runs(BUSY_DEFAULT, city="moving", busy="on", seed=s["seed"],
                                       preset=s["preset"])],
            {"digits": 1, "signed": True},
            lambda r: "the default (off): " + fmt_range(
                [100 * (m["c_l1_cm"] / s["c_l1_cm"] - 1)
                 for s in r.runs(BUSY_DEFAULT, city="static", busy="off")
                 for m in r.runs(BUSY_DEFAULT, city="moving", busy="off", seed=s["seed"],
                                 preset=s["preset"])], digits=1, signed=True),
            ("≤ +3", ("<=", 3)), [BUSY_DEFAULT]),
        Row("the filter (`transient`) with busy places on, over the default in the same rounds, "
            "ms a frame (`maicity_online`)",
            lambda r: [on["transient_ms"] - off["transient_ms"]
                       for on in r.runs(BUSY, kind="stage", variant="busy")
                       for off in r.runs(BUSY, kind="stage", variant="default",
                                         round=on["round"], seed=on["seed"])],
            {"digits": 1, "signed": True}, "–", None, [BUSY]),
        Row("C-L1 of the runs on seeds 776–778 above the same city without movers, %",
            lambda r: [100 * (m["c_l1_cm"] / s["c_l1_cm"] - 1)
                       for s in r.runs(TRANSIENT_COST, kind="map", city="static")
                       for m in r.runs(TRANSIENT_COST, kind="map", city="moving", build="after",
                                       seed=s["seed"], preset=s["preset"])],
            {"digits": 1, "signed": True}, "the static city", ("≤ +3", ("<=", 3)),
            [TRANSIENT_COST]),
        Row("floaters, filter on, streamed at 10 Hz through `rim_server`, %",
            lambda r: r.values(MOVING, "floater_pct", city="moving", filter=True, earlier=True,
                               streamed=True), F2, "–", ("≤ 0.1", ("<=", 0.1)), [MOVING]),
        Row("strict accuracy less accuracy, filter on, cm",
            lambda r: moving_gap(r, MOVING, filter=True, earlier=True, streamed=False), F2,
            lambda r: "without earlier evidence: " + fmt_range(
                moving_gap(r, MOVING, filter=True, earlier=False, streamed=False), digits=2),
            ("≤ 0.3", ("<=", 0.3)), [MOVING]),
        Row("C-L1, filter on, above the same city without movers, %",
            lambda r: moving_c_l1_pct(r, MOVING), {"digits": 1, "signed": True},
            "the static city", ("≤ +3", ("<=", 3)), [MOVING]),
        Row("planner points on the crossing lines within 5 cm of the static scene, %",
            lambda r: r.values(CROSSINGS, "within_5cm_pct", build="after"), F1,
            lambda r: "the build before: " + fmt_range(
                r.values(CROSSINGS, "within_5cm_pct", build="before")), ("≥ 95", (">=", 95)),
            [CROSSINGS]),
        Row("planner points on the crossing lines more than 10 cm too near",
            lambda r: r.values(CROSSINGS, "too_near", build="after"), {"digits": 0},
            lambda r: "the build before: " + fmt_range(
                r.values(CROSSINGS, "too_near", build="before"), digits=0), ("0", ("<=", 0)),
            [CROSSINGS]),
        Row("the same on rim_sim's default rich city (rows of cars at the kerb), held-out seeds "
            "767 and 769–771 offline, 766 and 767 streamed, %",
            lambda r: r.values(PLANNER_RICH, "within_5cm_pct", mode=["offline", "streamed"]), F1,
            lambda r: "seed 767 without movers, same points: " + fmt_range(
                r.values(PLANNER_RICH, "within_5cm_pct", mode="static city, same points")),
            ("≥ 95", (">=", 95)), [PLANNER_RICH]),
        Row("the same, points more than 10 cm too near",
            lambda r: r.values(PLANNER_RICH, "too_near", mode=["offline", "streamed"]),
            {"digits": 0}, "–", ("0", ("<=", 0)), [PLANNER_RICH]),
        Row("a `maicity_online` frame with the filter, above the same without it, alternating, %",
            lambda r: [100 * (p["on_ms"] / p["off_ms"] - 1)
                       for p in r.runs(TRANSIENT_COST, kind="pair", build="after")],
            {"digits": 0, "signed": True},
            lambda r: "every point at every turn, same rounds: " + fmt_range(
                [100 * (p["on_ms"] / p["off_ms"] - 1)
                 for p in r.runs(TRANSIENT_COST, kind="pair", build="before")],
                digits=0, signed=True), ("≤ +10", ("<=", 10)), [TRANSIENT_COST]),
        Row("the filter's own time (`transient`) in those rounds, over the frame without it, %",
            lambda r: [100 * p["transient_ms"] / p["off_ms"]
                       for p in r.runs(TRANSIENT_COST, kind="pair", build="after")],
            {"digits": 0, "signed": True},
            lambda r: "every point at every turn: " + fmt_range(
                [100 * p["transient_ms"] / p["off_ms"]
                 for p in r.runs(TRANSIENT_COST, kind="pair", build="before")],
                digits=0, signed=True), ("≤ +10", ("<=", 10)), [TRANSIENT_COST]),
        Row("the filter (`transient`) in those rounds, ms a frame (`maicity_online`)",
            lambda r: r.values(TRANSIENT_COST, "transient_ms", kind="pair", build="after"), F1,
            lambda r: "every point at every turn: " + fmt_range(
                r.values(TRANSIENT_COST, "transient_ms", kind="pair", build="before")), None,
            [TRANSIENT_COST]),
        Row("preprocessing with the filter, ms a frame (`maicity_online`)",
            lambda r: r.values(MOVING, "preprocess_ms", filter=True, earlier=True,
                               preset="maicity_online"), F1,
            lambda r: "filter off: " + fmt_range(r.values(MOVING, "preprocess_ms", filter=False,
                                                          preset="maicity_online")),
            None, [MOVING]),
    ],
    "gpu": [
        Row("SDF queries, 16.8 M points on the device, M points/s",
            lambda r: r.values(GPU, "query_sdf_mpoints_s"), {"digits": 0}, "–",
            ("≥ 100", (">=", 100)), [GPU]),
        Row("SDF and gradient queries, the same points, M points/s",
            lambda r: r.values(GPU, "query_gradient_mpoints_s"), {"digits": 0}, "–",
            ("≥ 50", (">=", 50)), [GPU]),
        Row("SDF and gradient of 1 M points from host memory and back, M points/s",
            lambda r: r.values(GPU, "query_host_roundtrip.mpoints_s"), {"digits": 0}, "–",
            None, [GPU]),
        Row("one training iteration, 18 432 rows (the decoder training), ms",
            lambda r: r.values(GPU, "training.gpu_ms_decoder_training"), F3,
            lambda r: "CPU path on the same host: " + fmt_range(
                r.values(GPU, "training.cpu_ms_threads_16"), digits=2) + " (16 threads), " +
            fmt_range(r.values(GPU, "training.cpu_ms_threads_2"), digits=2) + " (2)",
            None, [GPU]),
        Row("30 iterations, a `maicity` frame's training without its sampling, ms",
            lambda r: r.values(GPU, "training.gpu_ms_30_iterations"), F2,
            "the whole frame: 253 (paper, RTX 3070 Ti); target 10", None, [GPU]),
        Row("device memory (one map, its batch, buffers for 16.8 M query points) after 500 more "
            "iterations, MB",
            lambda r: [v / 1e6 for v in r.values(GPU, "memory_after_500")], {"digits": 0},
            lambda r: "before: " + fmt_range([v / 1e6 for v in r.values(GPU, "memory_before_500")],
                                             digits=0), None, [GPU]),
        Row("`rim_map --device cuda`, `maicity`, an 80-frame rim_sim city, ms a frame",
            lambda r: r.values(GPU_MAP, "ms_per_frame", run="cuda"), F1,
            lambda r: "`--device cpu` on the same host: " + fmt_range(
                r.values(GPU_MAP, "ms_per_frame", run="cpu-16")) + " (16 threads), " + fmt_range(
                r.values(GPU_MAP, "ms_per_frame", run="cpu-2")) + " (2)",
            ("≤ 10", ("<=", 10)), [GPU_MAP]),
        Row("of which on the device: 30 iterations and the syncs with the host map (`step`), ms",
            lambda r: r.values(GPU_MAP, "stages_ms_per_frame.step", run="cuda"), F1,
            lambda r: "the CPU's encode, forward, backward and step, 16 threads: " + fmt_range(
                [sum(r.values(GPU_MAP, f"stages_ms_per_frame.{k}", run="cpu-16")[0]
                     for k in ("encode", "forward", "backward", "step"))]),
            None, [GPU_MAP]),
        Row("C-L1 of `rim_map --device cuda` (`rim_eval --box 10,10,-3,3`), cm",
            lambda r: r.values(GPU_MAP, "c_l1_cm", run="cuda"), F2,
            lambda r: "`--device cpu`: " + fmt_range(r.values(GPU_MAP, "c_l1_cm", run="cpu-2"),
                                                     digits=2),
            None, [GPU_MAP]),
        Row("a frame's syncs in `rim_gpu_bench`: entering rows and flags over, changed rows back, ms",
            lambda r: [a + b for a, b in zip(r.values(GPU, "frame_sync.sync_from_host_ms"),
                                             r.values(GPU, "frame_sync.sync_to_host_ms"))], F1,
            lambda r: "30 iterations: " + fmt_range(r.values(GPU, "frame_sync.iterations_30_ms")),
            None, [GPU]),
        Row("robots per GPU, each 30 iterations a frame at 10 Hz (training only)",
            lambda r: r.values(GPU, "robots_real_time"), {"digits": 0}, "–",
            ("≥ 20", (">=", 20)), [GPU]),
    ],
    "checkpoints": [
        Row("a periodic checkpoint of a 30 s city drive at 10 Hz, s",
            lambda r: [v / 3 for v in r.values(CHECKPOINTS, "checkpoints_total_s",
                                               build="writes from the grids")], F2,
            lambda r: "whole map written each time: " + fmt_range(
                [v / 3 for v in r.values(CHECKPOINTS, "checkpoints_total_s",
                                         build="whole map")]),
            None, [CHECKPOINTS]),
        Row("the robot's rate with checkpoints every 100 frames, frames/s",
            lambda r: r.values(CHECKPOINTS, "frames_per_s", build="writes from the grids"), F2,
            lambda r: "no checkpoints: " + fmt_range(
                r.values(CHECKPOINTS, "frames_per_s", build="no checkpoints"), digits=2),
            None, [CHECKPOINTS]),
        Row("the last checkpoint on disk, MB",
            lambda r: r.values(CHECKPOINTS, "last_checkpoint_mb", build="changed sub-maps"),
            {"digits": 0}, lambda r: "whole map: " + fmt_range(
                r.values(CHECKPOINTS, "last_checkpoint_mb", build="whole map"), digits=0),
            None, [CHECKPOINTS]),
        Row("`Session/Save` (`rim_bench`), ms",
            lambda r: r.values(CHECKPOINTS, "real_time", benchmark="Session/Save"),
            {"digits": 0}, "–", None, [CHECKPOINTS]),
    ],
}


def fidelity_table(results):
    head = ("| city, host, date | run | ms/frame | peak MiB | Acc (cm) | Comp (cm) | C-L1 (cm) "
            "| recall % | F % | floaters % |\n|---|---|---|---|---|---|---|---|---|---|")
    names = sorted(os.path.basename(p) for p in
                   glob.glob(os.path.join(results.directory, "*fidelity*.json"))
                   if not p.endswith(".source.json"))
    if not names:
        return head + "\n\n(numbers being measured, see docs/perf-log.md)"
    lines = [head]
    sources = []
    for i, name in enumerate(names, 1):
        src, runs = results.load(name)
        city = src.get("city") or os.path.basename(str(runs[0].get("dataset", "")))
        where = ", ".join(x for x in (city, src.get("host"), src.get("date")) if x)
        for run in runs:
            def n(key, spec):
                v = run.get(key)
                return "n/a" if v is None else format(v, spec)
            lines.append(
                f"| {where} ({i}) | {run.get('label', run.get('run'))} | {n('ms_per_frame', '.1f')} "
                f"| {n('peak_mib', '.0f')} | {n('acc_cm', '.2f')} | {n('comp_cm', '.2f')} "
                f"| {n('c_l1_cm', '.2f')} | {n('recall_pct', '.2f')} | {n('f_pct', '.2f')} "
                f"| {format(100 * run['floater_share'], '.2f') if run.get('floater_share') is not None else 'n/a'} |")
        sources.append(f"{i}. {source_line(results, name)}")
    return "\n".join(lines + ["", "Sources (`tests/bench/results/`):", ""] + sources)


def render(results, name):
    if name == "fidelity":
        return fidelity_table(results)
    return table(results, TABLES[name])


ALL = list(TABLES) + ["fidelity"]
MARKER = re.compile(r"(<!-- results:([\w-]+) -->\n)(.*?)(<!-- /results -->)", re.S)


def rewrite(page_text, results, only):
    def sub(m):
        name = m.group(2)
        if name not in ALL:
            raise SystemExit(f"results_table: unknown table {name!r} in the page")
        if only and name not in only:
            return m.group(0)
        return f"{m.group(1)}\n{render(results, name)}\n\n{m.group(4)}"
    return MARKER.sub(sub, page_text)


def main():
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    g = p.add_mutually_exclusive_group()
    g.add_argument("--write", metavar="PAGE")
    g.add_argument("--check", metavar="PAGE")
    p.add_argument("--results", default=RESULTS, help="the results folder (default: %(default)s)")
    p.add_argument("tables", nargs="*", metavar="TABLE",
                   help="tables to print or rewrite: " + ", ".join(ALL))
    a = p.parse_args()
    for name in a.tables:
        if name not in ALL:
            p.error(f"unknown table {name!r} (tables: {', '.join(ALL)})")
    results = Results(a.results)
    if not (a.write or a.check):
        for name in a.tables or ALL:
            print(f"<!-- results:{name} -->\n\n{render(results, name)}\n\n<!-- /results -->\n")
        return 0
    page = a.write or a.check
    with open(page) as f:
        old = f.read()
    found = {m.group(2) for m in MARKER.finditer(old)}
    missing = [t for t in (a.tables or ALL) if t not in found]
    if missing:
        print(f"results_table: {page} has no markers for {', '.join(missing)}", file=sys.stderr)
        return 1
    new = rewrite(old, results, a.tables)
    if a.write:
        if new != old:
            with open(page, "w") as f:
                f.write(new)
        return 0
    if new != old:
        sys.stdout.writelines(difflib.unified_diff(
            old.splitlines(True), new.splitlines(True), page, page + " (from the JSON)"))
        print(f"results_table: {page} differs from tests/bench/results/; run "
              f"`python3 tests/bench/results_table.py --write {page}`", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
