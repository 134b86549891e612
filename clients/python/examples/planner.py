#!/usr/bin/env python3
"""Checks a straight-line path for collision against a robot's rim map.

Samples points every --step metres from --start to --goal, queries their signed Euclidean
distance to the mapped surfaces and reports the first sample where a sphere of --radius would
touch a surface (sdf < radius) or where the map knows nothing (never observed; with
--unknown-is-free such samples count as free if their distance to the mapped surfaces allows it).

    planner.py --server localhost:50051 --robot robot_1 --start 0,0,0.5 --goal 3,0,0.5 --radius 0.3

Exit status: 0 the path is free, 1 it is blocked, 2 the check could not be made (bad arguments,
server errors).
"""

from __future__ import annotations

import argparse
import math
import sys
from typing import List, Optional

import numpy as np

import rim_client


def parse_point(text: str) -> np.ndarray:
    try:
        values = [float(v) for v in text.split(",")]
    except ValueError:
        values = []
    if len(values) != 3 or not all(math.isfinite(v) for v in values):
        raise argparse.ArgumentTypeError(f"expected x,y,z in metres, got '{text}'")
    return np.array(values)


def positive(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        value = math.nan
    if not value > 0.0 or not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"expected a positive number of metres, got '{text}'")
    return value


def parse_args(argv: Optional[List[str]]) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--server", required=True, help="rim server address, host:port")
    parser.add_argument("--robot", required=True, help="robot id of the session to plan in")
    parser.add_argument("--start", required=True, type=parse_point, help="x,y,z (world, m)")
    parser.add_argument("--goal", required=True, type=parse_point, help="x,y,z (world, m)")
    parser.add_argument("--radius", type=positive, default=0.3, help="robot radius, m")
    # The SDF is a distance, so it changes by at most `step` between samples: a step well below
    # the radius keeps a thin obstacle from slipping between two samples.
    parser.add_argument("--step", type=positive, default=0.05, help="sample spacing, m")
    parser.add_argument("--unknown-is-free", action="store_true",
                        help="plan optimistically: never-observed space blocks only by its "
                             "distance to the mapped surfaces")
    parser.add_argument("--token", help="bearer token for the server")
    parser.add_argument("--timeout", type=positive, default=30.0, help="call deadline, s")
    return parser.parse_args(argv)


def fmt(point: np.ndarray) -> str:
    return "(" + ", ".join(f"{c:.3f}" for c in point) + ")"


def main(argv: Optional[List[str]] = None) -> int:
    args = parse_args(argv)
    length = float(np.linalg.norm(args.goal - args.start))
    samples = max(2, int(math.ceil(length / args.step)) + 1)
    points = np.linspace(args.start, args.goal, samples)

    try:
        with rim_client.Client(args.server, token=args.token, timeout=args.timeout) as client:
            result = client.session(args.robot).query(points)
    except rim_client.RimError as error:
        print(f"planner: {error}", file=sys.stderr)
        return 2

    too_close = result.sdf < args.radius
    unknown = ~result.observed
    blocked = too_close if args.unknown_is_free else too_close | unknown
    if not blocked.any():
        nearest = int(np.argmin(result.sdf))
        # A saturated distance is a lower bound: no surface lies within the session's bound.
        at_least = (" (at least: no surface nearer)"
                    if result.saturated is not None and result.saturated[nearest] else "")
        print(f"free: {samples} samples over {length:.3f} m from {fmt(args.start)} to "
              f"{fmt(args.goal)}, min clearance {float(result.sdf[nearest]):.3f} m{at_least} >= "
              f"radius {args.radius:.3f} m (map version {result.map_version})")
        return 0
    i = int(np.argmax(blocked))
    along = float(np.linalg.norm(points[i] - args.start))
    if too_close[i]:
        why = f"sdf {float(result.sdf[i]):.3f} m < radius {args.radius:.3f} m"
        if unknown[i]:
            why += " (never observed)"
    else:
        why = "never observed: the map knows nothing there"
    print(f"blocked at {fmt(points[i])}, {along:.3f} m from the start (sample {i + 1} of "
          f"{samples}): {why} (map version {result.map_version})")
    return 1


if __name__ == "__main__":
    sys.exit(main())
