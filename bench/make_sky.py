"""Writes scenes/textures/sky.exr: a small procedural HDR sky for the environment-map scenes.

64 x 32 texels, equirectangular as tessera and Mitsuba 3 read it (row 0 the zenith, the last
row the nadir; crates/render/src/envmap.rs): a blue sky brightening towards the horizon, a
dim brown ground, and a sun of 2 x 2 bright texels about 30 degrees above the horizon (soft
enough that the caustics it casts through the balls of scenes/envmap-balls.toml converge in
the time CI has; tests/envmap.rs tests a one-texel sun 10^7 times the sky). Run with
any Python that has NumPy and Mitsuba 3 (the bench venv: bench/peer-env.sh):

    python bench/make_sky.py scenes/textures/sky.exr
"""
import sys

import numpy as np


def sky(width=64, height=32):
    img = np.zeros((height, width, 3), dtype=np.float32)
    for j in range(height):
        theta = np.pi * j / (height - 1)
        if theta < np.pi / 2:
            t = theta / (np.pi / 2)
            img[j, :] = np.array([0.25, 0.45, 0.9]) * (0.5 + 0.9 * t * t)
        else:
            img[j, :] = [0.22, 0.17, 0.12]
    # The sun: 2 x 2 texels, about 30 degrees up, from the +x, +z quarter.
    img[10:12, 20:22] = [225.0, 195.0, 150.0]
    return img


def main():
    import mitsuba as mi
    mi.set_variant("scalar_rgb")
    out = sys.argv[1] if len(sys.argv) > 1 else "scenes/textures/sky.exr"
    bmp = mi.Bitmap(sky(), pixel_format=mi.Bitmap.PixelFormat.RGB)
    bmp.write(out)
    print(out)


if __name__ == "__main__":
    main()
