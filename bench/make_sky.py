"""Writes scenes/textures/sky.exr: a small procedural HDR sky for the environment-map scenes.

64 x 32 texels, equirectangular as tessera and Mitsuba 3 read it (row 0 the zenith, the last
row the nadir; crates/render/src/envmap.rs): a blue sky brightening towards the horizon, a
dim brown ground, and a sun of 2 x 2 bright texels about 30 degrees above the horizon (soft
enough that the caustics it casts through the balls of scenes/envmap-balls.toml converge in
the time CI has; tests/envmap.rs tests a one-texel sun 10^7 times the sky). Run with
any Python that has NumPy and Mitsuba 3 (the bench venv: bench/peer-env.sh):

    python bench/make_sky.py scenes/textures/sky.exr
    python bench/make_sky.py scenes/textures/sky-wide.exr --wide
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


def sky_wide(width=512, height=16):
    """The same sky 512 texels wide (and 16 high), wide enough that tessera draws its columns
    from alias tables (crates/render/src/envmap.rs, ALIAS_MIN_WIDTH), with the brightness
    varying around the horizon (bands of cloud) so that the columns' distribution matters, and
    the sun 16 x 1 texels: scenes/envmap-balls-wide.toml's sky, for the Mitsuba check of that
    path."""
    img = np.zeros((height, width, 3), dtype=np.float32)
    phi = 2.0 * np.pi * (np.arange(width) + 0.5) / width
    clouds = (1.0 + 0.6 * np.sin(3.0 * phi) + 0.3 * np.sin(11.0 * phi)).astype(np.float32)
    for j in range(height):
        theta = np.pi * j / (height - 1)
        if theta < np.pi / 2:
            t = theta / (np.pi / 2)
            img[j, :] = np.outer(clouds, np.array([0.25, 0.45, 0.9]) * (0.5 + 0.9 * t * t))
        else:
            img[j, :] = [0.22, 0.17, 0.12]
    img[5, 160:176] = [225.0, 195.0, 150.0]
    return img


def main():
    import mitsuba as mi
    mi.set_variant("scalar_rgb")
    out = sys.argv[1] if len(sys.argv) > 1 else "scenes/textures/sky.exr"
    image = sky_wide() if "--wide" in sys.argv else sky()
    bmp = mi.Bitmap(image, pixel_format=mi.Bitmap.PixelFormat.RGB)
    bmp.write(out)
    print(out)


if __name__ == "__main__":
    main()
