"""Region means of two converged images of one scene, as a Markdown table of their ratios.

    python region_means.py -- NAME CYCLES.exr TESSERA.exr [N]

Reads both with Blender's EXR reader (run it with target/blender-venv's Python) and prints the
whole image's mean and each of N×N blocks (default 4) as tessera / Cycles, top row first.
"""
import sys

import bpy
import numpy as np


def read_rgb(path):
    image = bpy.data.images.load(path, check_existing=False)
    w, h = image.size
    px = np.empty(w * h * 4, dtype=np.float32)
    image.pixels.foreach_get(px)
    return px.reshape(h, w, 4)[::-1, :, :3].astype(np.float64)


def main():
    args = sys.argv[sys.argv.index("--") + 1 :]
    name, cycles, tessera = args[:3]
    n = int(args[3]) if len(args) > 3 else 4
    c, t = read_rgb(cycles), read_rgb(tessera)
    if c.shape != t.shape:
        raise SystemExit(f"{name}: the images differ in size: {c.shape} and {t.shape}")
    h, w, _ = c.shape
    ratios = [
        [t[j * h // n : (j + 1) * h // n, i * w // n : (i + 1) * w // n].mean()
         / c[j * h // n : (j + 1) * h // n, i * w // n : (i + 1) * w // n].mean() for i in range(n)]
        for j in range(n)
    ]
    flat = [r for row in ratios for r in row]
    print(f"**{name}**: mean tessera / Cycles {t.mean() / c.mean():.4f}; {n}×{n} blocks "
          f"{min(flat):.3f} to {max(flat):.3f}, {sum(abs(r - 1) <= 0.02 for r in flat)} of {len(flat)} within 2%")
    print()
    print("| " + " | ".join(f"col {i + 1}" for i in range(n)) + " |")
    print("|" + "---:|" * n)
    for row in ratios:
        print("| " + " | ".join(f"{r:.3f}" for r in row) + " |")
    print()


main()
