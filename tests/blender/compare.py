"""Compares a Cycles render with tessera's, region by region (the whole image and its four
quadrants): each region's mean must agree within a relative TOLERANCE where Cycles' mean is
above a floor. Reads both EXRs with Blender's image loader (so only `bpy` is needed).

    python compare.py -- CYCLES.exr TESSERA.exr
"""

import sys

import bpy

TOLERANCE = 0.02
FLOOR = 1e-3


def load(path):
    image = bpy.data.images.load(path)
    w, h = image.size
    return w, h, list(image.pixels)


def mean(img, x0, y0, x1, y1):
    w, _, px = img
    total = 0.0
    for y in range(y0, y1):
        for x in range(x0, x1):
            i = (y * w + x) * 4
            total += (px[i] + px[i + 1] + px[i + 2]) / 3
    return total / ((x1 - x0) * (y1 - y0))


def main():
    cycles, tessera = load(sys.argv[-2]), load(sys.argv[-1])
    w, h = cycles[0], cycles[1]
    if (tessera[0], tessera[1]) != (w, h):
        sys.exit(f"sizes differ: {w}x{h} and {tessera[0]}x{tessera[1]}")
    bad = []
    for x0, y0, x1, y1 in [(0, 0, w, h), (0, 0, w // 2, h // 2), (w // 2, 0, w, h // 2),
                           (0, h // 2, w // 2, h), (w // 2, h // 2, w, h)]:
        c, t = mean(cycles, x0, y0, x1, y1), mean(tessera, x0, y0, x1, y1)
        ratio = t / c if c > FLOOR else float("nan")
        print(f"  region {x0},{y0}-{x1},{y1}: cycles {c:.5f} tessera {t:.5f} ratio {ratio:.4f}")
        if c > FLOOR and abs(ratio - 1) > TOLERANCE:
            bad.append((x0, y0, x1, y1, ratio))
    if bad:
        sys.exit(f"regions off by more than {TOLERANCE:.0%}: {bad}")


main()
