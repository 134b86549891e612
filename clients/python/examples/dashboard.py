#!/usr/bin/env python3
"""Mirrors a robot's mesh into a folder of Draco tiles, as a dashboard would.

Polls GetMeshTiles with the newest tile version seen so far, so each round transfers only the
tiles that changed, writes each as tile_<kx>_<ky>_<kz>.drc (replacing the previous version of that
sub-map) and prints one line per round. --resolution-m picks a level of detail (one of the
session's mesh_levels_m; default: the finest).

    dashboard.py --server localhost:50051 --robot robot_1 --out /tmp/tiles [--once | --iterations N]
                 [--resolution-m 0.2]

Exit status: 0 done (or interrupted), 2 on bad arguments or a server error.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from typing import List, Optional

import rim_client


def parse_args(argv: Optional[List[str]]) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--server", required=True, help="rim server address, host:port")
    parser.add_argument("--robot", required=True, help="robot id of the session to mirror")
    parser.add_argument("--out", required=True, help="folder for the .drc tiles (created)")
    rounds = parser.add_mutually_exclusive_group()
    rounds.add_argument("--once", action="store_true", help="one round, then exit")
    rounds.add_argument("--iterations", type=int, help="this many rounds, then exit")
    parser.add_argument("--interval", type=float, default=1.0, help="seconds between rounds")
    parser.add_argument("--token", help="bearer token for the server")
    parser.add_argument("--resolution-m", type=float, default=0.0,
                        help="level of detail: one of the session's mesh_levels_m (0: the finest)")
    args = parser.parse_args(argv)
    if args.iterations is not None and args.iterations < 1:
        parser.error(f"--iterations must be >= 1, got {args.iterations}")
    if args.interval < 0:
        parser.error(f"--interval must be >= 0, got {args.interval}")
    return args


def write_tile(folder: str, tile: rim_client.MeshTile) -> str:
    """Writes the tile next to its final name and renames it, so a viewer never reads half."""
    name = "tile_{}_{}_{}.drc".format(*tile.key)
    path = os.path.join(folder, name)
    with open(path + ".tmp", "wb") as out:
        out.write(tile.draco)
    os.replace(path + ".tmp", path)
    return name


def main(argv: Optional[List[str]] = None) -> int:
    args = parse_args(argv)
    rounds = 1 if args.once else args.iterations  # None: until interrupted
    os.makedirs(args.out, exist_ok=True)
    last_version = 0
    done = 0
    try:
        with rim_client.Client(args.server, token=args.token) as client:
            session = client.session(args.robot)
            if args.resolution_m:
                levels = ", ".join(f"{level:g}" for level in session.get().mesh_levels_m)
                print(f"levels of detail {levels} m; mirroring {args.resolution_m:g} m",
                      flush=True)
            while rounds is None or done < rounds:
                if done > 0:
                    time.sleep(args.interval)
                tiles = session.mesh_tiles(since=last_version, resolution_m=args.resolution_m)
                done += 1
                if not tiles:
                    print(f"round {done}: no change since version {last_version}", flush=True)
                    continue
                for tile in tiles:
                    write_tile(args.out, tile)
                last_version = max(last_version, max(t.version for t in tiles))
                size_kib = sum(len(t.draco) for t in tiles) / 1024.0
                faces = sum(t.face_count for t in tiles)
                print(f"round {done}: version {last_version}: {len(tiles)} tiles changed "
                      f"({faces} faces, {size_kib:.1f} KiB) -> {args.out}", flush=True)
    except rim_client.RimError as error:
        print(f"dashboard: {error}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        pass
    return 0


if __name__ == "__main__":
    sys.exit(main())
