#!/usr/bin/env python3
"""Renders a mesh.ply (as written by rim_map / rimctl) to a PNG picture, headless.

Usage: render_mesh.py MESH.ply OUT.png [--view top|oblique] [--size 1200x800]

A z-buffered splat renderer in numpy (Debian's python3-numpy): every face is drawn as its
centroid, shaded by its normal (Lambert with a fixed light) and tinted by height. Good enough to
look at a map; no OpenGL or display needed.
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


def render(verts, faces, width, height, view):
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
    return img


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("mesh")
    ap.add_argument("out")
    ap.add_argument("--view", choices=["top", "oblique"], default="oblique")
    ap.add_argument("--size", default="1200x800")
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
    write_png(a.out, render(verts, faces, w, h, a.view))
    print(f"render_mesh: {len(faces)} faces -> {a.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
