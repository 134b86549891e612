#!/usr/bin/env python3
"""Prints the region a robot-centric map was asked to reconstruct along a drive, for rim_eval.

Reads KITTI poses (12 numbers a line, world from sensor) and prints x0,y0,z0,x1,y1,z1: the
bounding box of the sensor positions grown by the local map's half-extent minus a margin
(default: the maicity box, ±10 m horizontally and ±3 m vertically, kept 0.5 m inside its faces).
Walls above the box and streets beyond it were never in any local map, so a score outside this
region measures nothing about the mapper.

Usage: drive_region.py POSES.txt [--half-xy 9.5] [--half-z 2.5]
"""
import argparse


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("poses")
    parser.add_argument("--half-xy", type=float, default=9.5)
    parser.add_argument("--half-z", type=float, default=2.5)
    args = parser.parse_args()
    xs, ys, zs = [], [], []
    with open(args.poses) as f:
        for line in f:
            v = [float(t) for t in line.split()]
            if len(v) != 12:
                raise SystemExit(f"{args.poses}: expected 12 numbers a line, got {len(v)}")
            xs.append(v[3])
            ys.append(v[7])
            zs.append(v[11])
    if not xs:
        raise SystemExit(f"{args.poses}: no poses")
    m, h = args.half_xy, args.half_z
    print(f"{min(xs)-m},{min(ys)-m},{min(zs)-h},{max(xs)+m},{max(ys)+m},{max(zs)+h}")


if __name__ == "__main__":
    main()
