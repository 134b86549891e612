#!/usr/bin/env python3
"""clients/tools/render_mesh.py draws a mesh and, with --missing-in, marks and counts the faces
that another mesh lacks: two squares of two faces each, one of them only in the first mesh,
give 2 missing faces of 1 m² in all (at 1 m), drawn red, and an empty mesh lacks all 4; a bad
distance or a missing file fails with the problem named.

Usage: render_mesh_test.py RENDER_MESH_PY
"""

import os
import struct
import subprocess
import sys
import tempfile
import zlib


def write_ply(path, verts, faces):
    header = (
        "ply\nformat binary_little_endian 1.0\n"
        f"element vertex {len(verts)}\nproperty float x\nproperty float y\nproperty float z\n"
        f"element face {len(faces)}\nproperty list uchar int vertex_indices\nend_header\n"
    )
    with open(path, "wb") as f:
        f.write(header.encode("ascii"))
        for v in verts:
            f.write(struct.pack("<3f", *v))
        for t in faces:
            f.write(struct.pack("<B3i", 3, *t))


def square(x0, y0):
    return [(x0, y0, 0.0), (x0 + 1, y0, 0.0), (x0 + 1, y0 + 1, 0.0), (x0, y0 + 1, 0.0)]


def red_pixels(png):
    data = open(png, "rb").read()
    assert data[:8] == b"\x89PNG\r\n\x1a\n"
    w, h = struct.unpack(">II", data[16:24])
    pos, idat = 8, b""
    while pos < len(data):
        n = struct.unpack(">I", data[pos:pos + 4])[0]
        tag = data[pos + 4:pos + 8]
        if tag == b"IDAT":
            idat += data[pos + 8:pos + 8 + n]
        pos += 12 + n
    raw = zlib.decompress(idat)
    count = 0
    for y in range(h):
        row = raw[y * (3 * w + 1) + 1:(y + 1) * (3 * w + 1)]
        for x in range(w):
            r, g, b = row[3 * x:3 * x + 3]
            count += r > 200 and g < 60 and b < 60
    return count


def main(script):
    with tempfile.TemporaryDirectory() as d:
        both = os.path.join(d, "both.ply")
        one = os.path.join(d, "one.ply")
        png = os.path.join(d, "out.png")
        write_ply(both, square(0, 0) + square(5, 0), [(0, 1, 2), (0, 2, 3), (4, 5, 6), (4, 6, 7)])
        write_ply(one, square(0, 0), [(0, 1, 2), (0, 2, 3)])
        run = lambda *args: subprocess.run([sys.executable, script, *args], capture_output=True,
                                           text=True)
        r = run(both, png, "--view", "top", "--size", "200x100", "--missing-in", one,
                "--missing-m", "1")
        assert r.returncode == 0, r.stderr
        assert "2 of 4 faces (1.00 m2) have no vertex of" in r.stdout, r.stdout
        assert red_pixels(png) > 0, "no red pixel drawn"
        r = run(both, png, "--view", "top", "--size", "200x100", "--missing-in", both,
                "--missing-m", "1")
        assert r.returncode == 0 and "0 of 4 faces (0.00 m2)" in r.stdout, r.stdout
        assert red_pixels(png) == 0
        empty = os.path.join(d, "empty.ply")
        write_ply(empty, [], [])
        r = run(both, png, "--missing-in", empty, "--missing-m", "1")
        assert r.returncode == 0 and "4 of 4 faces (2.00 m2)" in r.stdout, r.stdout + r.stderr
        r = run(both, png, "--missing-in", one, "--missing-m", "0")
        assert r.returncode == 1 and "--missing-m must be > 0" in r.stderr, r.stderr
        r = run(both, png, "--missing-in", os.path.join(d, "absent.ply"))
        assert r.returncode == 1 and "absent.ply" in r.stderr, r.stderr
    print("render_mesh_test: passed")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1]))
