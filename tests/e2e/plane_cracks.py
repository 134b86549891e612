#!/usr/bin/env python3
"""Open mesh edges along straight lines: a crack in a mesh.

usage: plane_cracks.py MESH.ply AXIS=VALUE [AXIS=VALUE ...] [--max-ratio R] [--slack N]

For each plane (e.g. x=2.0), counts the open edges (used by one triangle, after welding
vertices with identical coordinates) that lie in the plane, and compares the count with the
median over the voxel-face planes (every 0.1 m) within 2 m on either side. A plane where cells
were left out of the mesh has open edges on every surface that crosses it; a plane where the
mesh simply goes on has about as many as its neighbours. Fails (exit 1) when a plane has more
than R x median + N (defaults 3 and 30). Reads binary little-endian PLY with float x, y, z
first among the vertex properties and uchar-counted int faces (what rim writes).
"""
import struct
import sys
from collections import Counter

SIZES = {"char": 1, "uchar": 1, "short": 2, "ushort": 2, "int": 4, "uint": 4, "float": 4,
         "double": 8}


def read_ply(path):
    data = open(path, "rb").read()
    end = data.index(b"end_header\n") + len(b"end_header\n")
    n_vertices = n_faces = 0
    vertex_bytes = 0
    element = None
    for line in data[:end].decode().splitlines():
        parts = line.split()
        if parts[:1] == ["element"]:
            element = parts[1]
            if element == "vertex":
                n_vertices = int(parts[2])
            elif element == "face":
                n_faces = int(parts[2])
        elif parts[:1] == ["property"] and element == "vertex":
            vertex_bytes += SIZES[parts[1]]
    vertices = [struct.unpack_from("<3f", data, end + i * vertex_bytes) for i in range(n_vertices)]
    faces = []
    offset = end + n_vertices * vertex_bytes
    for _ in range(n_faces):
        count = data[offset]
        faces.append(struct.unpack_from("<%di" % count, data, offset + 1))
        offset += 1 + 4 * count
    return vertices, faces


def main(argv):
    planes, max_ratio, slack = [], 3.0, 30.0
    args = iter(argv[2:])
    for a in args:
        if a == "--max-ratio":
            max_ratio = float(next(args))
        elif a == "--slack":
            slack = float(next(args))
        else:
            axis, value = a.split("=")
            planes.append(("xyz".index(axis), float(value)))
    vertices, faces = read_ply(argv[1])
    # Weld identical coordinates: neighbouring tiles write the same vertex twice.
    ids = {}
    welded = [ids.setdefault(v, len(ids)) for v in vertices]
    coords = list(ids)
    failed = False
    for axis, value in planes:
        near = lambda c: abs(c - value) <= 2.05
        uses = Counter()
        for f in faces:
            if not any(near(vertices[i][axis]) for i in f):
                continue
            for k in range(len(f)):
                a, b = welded[f[k]], welded[f[(k + 1) % len(f)]]
                uses[(min(a, b), max(a, b))] += 1
        per_plane = Counter()
        for (a, b), n in uses.items():
            ca, cb = coords[a][axis], coords[b][axis]
            if n == 1 and ca == cb:
                per_plane[round(ca / 0.1)] += abs(ca - round(ca / 0.1) * 0.1) < 1e-4
        centre = round(value / 0.1)
        others = sorted(per_plane[k] for k in range(centre - 20, centre + 21) if k != centre)
        median = others[len(others) // 2]
        count = per_plane[centre]
        ok = count <= max_ratio * median + slack
        failed |= not ok
        print("%s=%.2f: %d open edges in the plane, median %d over the planes within 2 m: %s" %
              ("xyz"[axis], value, count, median, "ok" if ok else "CRACK"))
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))
