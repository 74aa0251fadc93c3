#!/usr/bin/env python3
"""Writes icosphere.ply: a unit sphere as a subdivided icosahedron (3 subdivisions, 1,280
triangles) with vertex normals, in binary little-endian PLY. Run from this directory:

    python3 make_icosphere.py

The file is committed; this script is how it was made (standard library only)."""
import math
import struct

t = (1 + 5 ** 0.5) / 2
verts = [(-1, t, 0), (1, t, 0), (-1, -t, 0), (1, -t, 0), (0, -1, t), (0, 1, t),
         (0, -1, -t), (0, 1, -t), (t, 0, -1), (t, 0, 1), (-t, 0, -1), (-t, 0, 1)]
faces = [(0, 11, 5), (0, 5, 1), (0, 1, 7), (0, 7, 10), (0, 10, 11), (1, 5, 9), (5, 11, 4),
         (11, 10, 2), (10, 7, 6), (7, 1, 8), (3, 9, 4), (3, 4, 2), (3, 2, 6), (3, 6, 8),
         (3, 8, 9), (4, 9, 5), (2, 4, 11), (6, 2, 10), (8, 6, 7), (9, 8, 1)]


def unit(v):
    n = math.sqrt(sum(c * c for c in v))
    return tuple(c / n for c in v)


verts = [unit(v) for v in verts]
for _ in range(3):
    cache = {}

    def mid(a, b):
        key = (min(a, b), max(a, b))
        if key not in cache:
            verts.append(unit(tuple((verts[a][i] + verts[b][i]) / 2 for i in range(3))))
            cache[key] = len(verts) - 1
        return cache[key]

    new = []
    for a, b, c in faces:
        ab, bc, ca = mid(a, b), mid(b, c), mid(c, a)
        new += [(a, ab, ca), (b, bc, ab), (c, ca, bc), (ab, bc, ca)]
    faces = new

with open("icosphere.ply", "wb") as f:
    f.write(("ply\nformat binary_little_endian 1.0\ncomment made by make_icosphere.py\n"
             f"element vertex {len(verts)}\nproperty float x\nproperty float y\nproperty float z\n"
             "property float nx\nproperty float ny\nproperty float nz\n"
             f"element face {len(faces)}\nproperty list uchar int vertex_indices\nend_header\n").encode())
    for v in verts:
        f.write(struct.pack("<6f", *v, *v))
    for a, b, c in faces:
        f.write(struct.pack("<B3i", 3, a, b, c))
