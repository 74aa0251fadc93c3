"""Mitsuba 3 as a peer for `tessera bench`: renders Mitsuba's built-in Cornell box (the scene of
tests/data/cornell-box-reference.exr and scenes/cornell-box.toml: box filter, unbiased path
tracer with max_depth = -1) at 4, 16, ... spp with several seeds, times each render, and
writes CSV rows in `tessera bench`'s format (renderer,scene,spp,seed,threads,seconds,
msamples_per_s,relmse), relMSE against the same reference.

Usage: python mitsuba_peer.py --reference REF.exr --out OUT.csv [--variants V ...]
       [--max-spp N] [--seeds K]

Each variant renders once untimed first, so JIT compilation (llvm_ad_rgb) is not timed. The
timed span is mi.render plus the copy to a NumPy array, which forces the lazy evaluation.
"""
import argparse
import os
import sys
import time

import numpy as np


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--reference", required=True)
    ap.add_argument("--out", required=True)
    ap.add_argument("--variants", nargs="+", default=["llvm_ad_rgb", "scalar_rgb"])
    ap.add_argument("--max-spp", type=int, default=4096)
    ap.add_argument("--seeds", type=int, default=2)
    ap.add_argument("--size", type=int, default=256)
    ap.add_argument("--scalar-max-spp", type=int, default=1024,
                    help="cap for scalar_rgb, ~3x slower than llvm_ad_rgb; its relMSE*s is "
                         "already flat by then")
    a = ap.parse_args()

    import mitsuba as mi

    rows = []
    threads = os.cpu_count()
    for variant in a.variants:
        try:
            mi.set_variant(variant)
        except Exception as e:  # a variant this build or machine cannot run
            print(f"skipping {variant}: {e}", file=sys.stderr)
            continue
        ref = np.array(mi.Bitmap(a.reference).convert(
            mi.Bitmap.PixelFormat.RGB, mi.Struct.Type.Float32, False), dtype=np.float64)
        d = mi.cornell_box()
        d["sensor"]["film"].update(width=a.size, height=a.size, rfilter={"type": "box"})
        d["sensor"]["sampler"] = {"type": "independent", "sample_count": 4}
        d["integrator"] = {"type": "path", "max_depth": -1}
        scene = mi.load_dict(d)
        np.array(mi.render(scene, spp=4, seed=999))  # warm-up: JIT compilation, not timed
        top = min(a.max_spp, a.scalar_max_spp) if variant.startswith("scalar") else a.max_spp
        spp = 4
        while spp <= top:
            for seed in range(1, a.seeds + 1):
                t = time.perf_counter()
                img = np.array(mi.render(scene, spp=spp, seed=seed), dtype=np.float64)
                dt = time.perf_counter() - t
                rel = float(np.mean((img[..., :3] - ref) ** 2 / (ref ** 2 + 0.01)))
                row = (f"mitsuba-{variant},cornell-box,{spp},{seed},{threads},{dt:.6f},"
                       f"{a.size * a.size * spp / dt / 1e6:.4f},{rel:.6e}")
                print(row, file=sys.stderr, flush=True)
                rows.append(row)
            spp *= 4
    with open(a.out, "w") as f:
        f.write("renderer,scene,spp,seed,threads,seconds,msamples_per_s,relmse\n")
        f.write("".join(r + "\n" for r in rows))


if __name__ == "__main__":
    main()
