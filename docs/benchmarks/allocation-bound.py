#!/usr/bin/env python3
"""How much less relMSE than uniform sampling an allocation of samples by tile can give.

Made the table in docs/renderer.md ("How much it can give"). For each scene it needs a 64-spp
pilot and a 2048-spp render with variance channels, made with

    tessera render scenes/SCENE.toml --spp 64 --seed 11 --variance --output /tmp/SCENE-p64.exr
    tessera render scenes/SCENE.toml --spp 2048 --seed 12 --variance --output /tmp/SCENE-t.exr

then `python3 allocation-bound.py cornell-box glass-mirror caustic` (numpy and OpenEXR from
PyPI). V is each pixel's per-sample relative variance, var/(mean² + 0.01), relMSE's measure.
"ideal": Neyman allocation n ∝ √V with V from the 2048-spp render, gain mean(V)/mean(√V)².
"pilot": n = max(64, c·√V_pilot) with the pilot's V, scaled to N samples per pixel on average,
its relMSE taken with the 2048-spp V.
"""
import sys

import numpy as np
import OpenEXR


def load(path, n):
    ch = OpenEXR.File(path).channels()
    rgb = np.asarray(ch["RGB"].pixels, dtype=np.float64)
    var = np.asarray(ch["variance"].pixels, dtype=np.float64) * n
    return rgb, var


for name in sys.argv[1:]:
    prgb, pvar = load(f"/tmp/{name}-p64.exr", 64)
    trgb, tvar = load(f"/tmp/{name}-t.exr", 2048)
    vt = (tvar / (trgb**2 + 0.01)).mean(-1)
    vp = (pvar / (prgb**2 + 0.01)).mean(-1)
    h, w = vt.shape
    print(name)
    for t in [32, 8, 4, 2, 1]:
        def blocks(v):
            return v[: h // t * t, : w // t * t].reshape(h // t, t, w // t, t).mean(axis=(1, 3)).ravel()
        bt, bp = blocks(vt), blocks(vp)
        ideal = bt.mean() / np.sqrt(bt).mean() ** 2
        for n in [256, 1024]:
            a = np.sqrt(bp)
            lo, hi = 0.0, 1e9
            for _ in range(200):
                c = (lo + hi) / 2
                if np.maximum(64, c * a).mean() > n:
                    hi = c
                else:
                    lo = c
            alloc = np.maximum(64, c * a)
            pilot = (bt / n).mean() / (bt / alloc).mean()
            print(f"  tile {t:2} at {n:4} spp: ideal {ideal:.2f}x, from the pilot {pilot:.2f}x")
