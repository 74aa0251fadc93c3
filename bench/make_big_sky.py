"""Writes two 4096 x 2048 HDR skies and envmap-balls scenes under them, for measuring what a
full-size map costs (scenes/textures/sky.exr is 64 x 32, which stays in cache):

    target/bench-cache/big-sky/envmap-balls-4k-cloudy.toml  a blue sky with 16-texel cloud
                                                            blocks, no sun (cloudy.exr)
    target/bench-cache/big-sky/envmap-balls-4k-sun.toml     the same sky with a sun of 32 x 32
                                                            texels that holds about 70% of the
                                                            map's power (sun.exr)

Needs NumPy and Mitsuba 3, whose Bitmap writes the EXR (the bench venv: bench/peer-env.sh).
Run from the repository root:

    python bench/make_big_sky.py
"""
import os
import re

import numpy as np

W, H = 4096, 2048
OUT = "target/bench-cache/big-sky"


def sky(sun):
    rng = np.random.default_rng(1)
    theta = np.pi * np.arange(H)[:, None] / (H - 1)
    t = np.clip(theta / (np.pi / 2), 0, 1)
    blue = np.array([0.25, 0.45, 0.9])[None, None, :] * (0.5 + 0.9 * t * t)[..., None]
    ground = np.array([0.22, 0.17, 0.12])[None, None, :] * np.ones((H, W, 1))
    noise = np.kron(rng.random((H // 16 + 1, W // 16 + 1)), np.ones((16, 16)))[:H, :W]
    img = np.where(
        (theta < np.pi / 2)[..., None],
        blue * (0.6 + 0.8 * noise[..., None]),
        ground * (0.7 + 0.6 * noise[..., None]),
    ).astype(np.float32)
    if sun:
        w = np.sin(theta)
        sky_power = (img.sum(axis=2) * w).sum()
        sj, si, r = H // 3, int(W * 0.33), 16
        value = 2.3 * sky_power / (w[sj - r : sj + r, 0].sum() * 2 * r) / 3
        img[sj - r : sj + r, si - r : si + r] = np.array([1.1, 1.0, 0.85]) * value
    return img


def main():
    import mitsuba as mi

    mi.set_variant("scalar_rgb")
    os.makedirs(OUT, exist_ok=True)
    base = open("scenes/envmap-balls.toml").read()
    for name, sun in [("cloudy", False), ("sun", True)]:
        mi.Bitmap(sky(sun), pixel_format=mi.Bitmap.PixelFormat.RGB).write(f"{OUT}/{name}.exr")
        scene = re.sub(r'file = "textures/sky.exr"', f'file = "{name}.exr"', base)
        toml = f"{OUT}/envmap-balls-4k-{name}.toml"
        open(toml, "w").write(scene)
        print(toml)


if __name__ == "__main__":
    main()
