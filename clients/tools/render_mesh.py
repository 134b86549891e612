#!/usr/bin/env python3
"""Renders a mesh.ply (as written by rim_map / rimctl) to a PNG picture, headless.

Usage: render_mesh.py MESH.ply OUT.png [--view top|oblique] [--size 1200x800]
                      [--missing-in OTHER.ply [--missing-m 0.1]]

A z-buffered splat renderer in numpy (Debian's python3-numpy): every face is drawn as its
centroid, shaded by its normal (Lambert with a fixed light) and tinted by height. Good enough to
look at a map; no OpenGL or display needed.

With --missing-in, the faces of MESH that OTHER lacks are drawn red, over the rest and three
pixels wide, and counted (faces and area):
those with no vertex of OTHER in the cube of cells of --missing-m around their centroid, so none
within that distance. For example MESH mapped without a filter and OTHER with it: red is what the
filter removed.
"""
import argparse
import struct
import sys
import zlib

import numpy as np


def read_ply(path):
    with open(path, "rb") as f:
        header = []
        while True:
            line = f.readline()
            if not line:
                raise ValueError(f"{path}: truncated header")
            line = line.decode("ascii").strip()
            header.append(line)
            if line == "end_header":
                break
        body = f.read()
    fmt = next(l.split()[1] for l in header if l.startswith("format"))
    if fmt != "binary_little_endian":
        raise ValueError(f"{path}: only binary_little_endian PLY is supported")
    nv = nf = 0
    vprops = []
    element = None
    for l in header:
        p = l.split()
        if p[0] == "element":
            element = p[1]
            if element == "vertex":
                nv = int(p[2])
            elif element == "face":
                nf = int(p[2])
        elif p[0] == "property" and element == "vertex":
            vprops.append(p[1])
    if any(t not in ("float", "float32") for t in vprops):
        raise ValueError(f"{path}: expected float vertex properties")
    vsize = 4 * len(vprops)
    verts = np.frombuffer(body[: nv * vsize], dtype="<f4").reshape(nv, len(vprops))[:, :3]
    faces = np.frombuffer(body[nv * vsize: nv * vsize + nf * 13], dtype=np.uint8).reshape(nf, 13)
    idx = faces[:, 1:].copy().view("<i4").reshape(nf, 3)
    return verts.astype(np.float64), idx


def write_png(path, rgb):
    h, w, _ = rgb.shape
    raw = b"".join(b"\x00" + rgb[y].tobytes() for y in range(h))

    def chunk(tag, data):
        c = struct.pack(">I", len(data)) + tag + data
        return c + struct.pack(">I", zlib.crc32(tag + data) & 0xFFFFFFFF)

    png = b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, 8, 2, 0, 0, 0))
    png += chunk(b"IDAT", zlib.compress(raw, 6)) + chunk(b"IEND", b"")
    with open(path, "wb") as f:
        f.write(png)


def missing_faces(verts, faces, other_verts, cell_m):
    """Faces of (verts, faces) with no vertex of other_verts in the 27 cells of cell_m around
    their centroid (cells of a grid at the origin): none lies within cell_m of the centroid."""
    def keys(cells):
        c = cells.astype(np.int64) + (1 << 20)
        return (c[:, 0] << 42) | (c[:, 1] << 21) | c[:, 2]
    if len(other_verts) == 0:
        return np.ones(len(faces), dtype=bool)
    occupied = np.unique(keys(np.floor(other_verts / cell_m)))
    cells = np.floor(verts[faces].mean(axis=1) / cell_m)
    near = np.zeros(len(faces), dtype=bool)
    for dx in (-1, 0, 1):
        for dy in (-1, 0, 1):
            for dz in (-1, 0, 1):
                k = keys(cells + np.array([dx, dy, dz]))
                i = np.clip(np.searchsorted(occupied, k), 0, len(occupied) - 1)
                near |= occupied[i] == k
    return ~near


def render(verts, faces, width, height, view, red=None):
    tri = verts[faces]
    centroid = tri.mean(axis=1)
    normal = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    normal /= np.linalg.norm(normal, axis=1, keepdims=True) + 1e-12
    center = np.median(centroid, axis=0)
    if view == "top":
        R = np.eye(3)
    else:  # oblique: 55 degrees from vertical, looking north-east
        a, b = np.radians(55), np.radians(-35)
        Rx = np.array([[1, 0, 0], [0, np.cos(a), -np.sin(a)], [0, np.sin(a), np.cos(a)]])
        Rz = np.array([[np.cos(b), -np.sin(b), 0], [np.sin(b), np.cos(b), 0], [0, 0, 1]])
        R = Rx @ Rz
    p = (centroid - center) @ R.T
    lo, hi = np.percentile(p[:, :2], 0.5, axis=0), np.percentile(p[:, :2], 99.5, axis=0)
    scale = 0.95 * min(width / (hi[0] - lo[0] + 1e-9), height / (hi[1] - lo[1] + 1e-9))
    u = ((p[:, 0] - (lo[0] + hi[0]) / 2) * scale + width / 2).astype(int)
    v = (height / 2 - (p[:, 1] - (lo[1] + hi[1]) / 2) * scale).astype(int)
    depth = -p[:, 2]
    ok = (u >= 0) & (u < width) & (v >= 0) & (v < height)
    u, v, depth = u[ok], v[ok], depth[ok]
    light = np.array([0.3, -0.4, 0.87])
    shade = np.abs(normal[ok] @ light) * 0.75 + 0.25
    z = centroid[ok, 2]
    t = np.clip((z - np.percentile(z, 2)) / (np.percentile(z, 98) - np.percentile(z, 2) + 1e-9), 0, 1)
    color = np.stack([0.55 + 0.4 * t, 0.7 - 0.1 * t, 0.95 - 0.55 * t], axis=1) * shade[:, None]
    # z-buffer: nearest splat wins. Sort far to near so later writes are nearer.
    order = np.argsort(-depth)
    img = np.full((height, width, 3), 255, dtype=np.uint8)
    img[v[order], u[order]] = (np.clip(color[order], 0, 1) * 255).astype(np.uint8)
    if red is not None:
        # Drawn over the rest, three pixels wide, so that a few small faces still show.
        r = red[ok]
        for du in (-1, 0, 1):
            for dv in (-1, 0, 1):
                img[np.clip(v[r] + dv, 0, height - 1), np.clip(u[r] + du, 0, width - 1)] = \
                    (230, 20, 12)
    return img


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("mesh")
    ap.add_argument("out")
    ap.add_argument("--view", choices=["top", "oblique"], default="oblique")
    ap.add_argument("--size", default="1200x800")
    ap.add_argument("--missing-in", metavar="OTHER.ply",
                    help="draw red, and count, the faces that OTHER.ply lacks")
    ap.add_argument("--missing-m", type=float, default=0.1,
                    help="a face is missing when OTHER has no vertex within this distance (m)")
    a = ap.parse_args()
    w, h = (int(x) for x in a.size.split("x"))
    try:
        verts, faces = read_ply(a.mesh)
    except (OSError, ValueError) as e:
        print(f"render_mesh: {e}", file=sys.stderr)
        return 1
    if len(faces) == 0:
        print(f"render_mesh: {a.mesh} has no faces", file=sys.stderr)
        return 1
    red = None
    if a.missing_in:
        if not a.missing_m > 0:
            print(f"render_mesh: --missing-m must be > 0 (got {a.missing_m})", file=sys.stderr)
            return 1
        try:
            other, _ = read_ply(a.missing_in)
        except (OSError, ValueError) as e:
            print(f"render_mesh: {e}", file=sys.stderr)
            return 1
        red = missing_faces(verts, faces, other, a.missing_m)
        tri = verts[faces[red]]
        area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]),
                                    axis=1).sum()
        print(f"render_mesh: {int(red.sum())} of {len(faces)} faces ({area:.2f} m2) have no "
              f"vertex of {a.missing_in} within {a.missing_m} m (red)")
    write_png(a.out, render(verts, faces, w, h, a.view, red))
    print(f"render_mesh: {len(faces)} faces -> {a.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
