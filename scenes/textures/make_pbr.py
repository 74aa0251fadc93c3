"""Writes the pbr textures of scenes/materials.toml: tiles-normal.png, a tangent-space normal
map of 4 x 4 bevelled tiles (red along u, green up the image, blue out of the surface, 8-bit
linear codes), and tiles-mr.png, glTF's packed metallic-roughness image (green roughness:
0.25 on the tiles, 0.9 in the grout; blue metallic: every other tile metal). 64 x 64 texels
each. Standard library only.

    python3 make_pbr.py [DIR]
"""
import math
import os
import struct
import sys
import zlib

SIZE = 64
TILE = 16
GROUT = 1
BEVEL = 4
TILT = math.radians(35)


def tile_of(x, y):
    return x // TILE, y // TILE


def normal(x, y):
    """The normal at texel (x, y), row 0 at the top: flat in the grout and on each tile's
    face, tipped away from the tile's middle on its bevel."""
    lx, ly = x % TILE, y % TILE
    if lx < GROUT or ly < GROUT:
        return (0.0, 0.0, 1.0)
    # Distance in from each edge; the nearest edge decides the bevel's direction. Up the image
    # is +v, so the top edge (small ly) tips the normal towards +y.
    edges = [(lx - GROUT, (-1, 0)), (TILE - 1 - lx, (1, 0)), (ly - GROUT, (0, 1)), (TILE - 1 - ly, (0, -1))]
    d, (dx, dy) = min(edges, key=lambda e: e[0])
    if d >= BEVEL:
        return (0.0, 0.0, 1.0)
    s, c = math.sin(TILT), math.cos(TILT)
    return (dx * s, dy * s, c)


def code(v):
    return max(0, min(255, round((v + 1.0) * 127.5)))


def mr(x, y):
    lx, ly = x % TILE, y % TILE
    grout = lx < GROUT or ly < GROUT
    tx, ty = tile_of(x, y)
    metal = 255 if (tx + ty) % 2 == 0 and not grout else 0
    rough = 230 if grout else 64
    return (0, rough, metal)


def chunk(kind, data):
    body = kind + data
    return struct.pack(">I", len(data)) + body + struct.pack(">I", zlib.crc32(body))


def write_png(path, texel):
    rows = b"".join(b"\0" + bytes(c for x in range(SIZE) for c in texel(x, y)) for y in range(SIZE))
    png = (b"\x89PNG\r\n\x1a\n"
           + chunk(b"IHDR", struct.pack(">IIBBBBB", SIZE, SIZE, 8, 2, 0, 0, 0))
           + chunk(b"IDAT", zlib.compress(rows, 9))
           + chunk(b"IEND", b""))
    with open(path, "wb") as f:
        f.write(png)


def main(out):
    write_png(os.path.join(out, "tiles-normal.png"), lambda x, y: tuple(code(c) for c in normal(x, y)))
    write_png(os.path.join(out, "tiles-mr.png"), mr)


if __name__ == "__main__":
    main(sys.argv[1] if len(sys.argv) > 1 else os.path.dirname(os.path.abspath(__file__)))
