"""Blender's Cycles as a peer for `tessera bench` (bench/cycles-vs-tessera.sh).

Run with Blender as a Python module (PyPI's bpy, target/blender-venv). The scenes are the
.blend files bench/blender_scenes.py saves in --scenes DIR, each rendered as saved there (CPU,
the unbiased settings that script gives), at the film size the .blend sets.

Serve mode answers `tessera bench --peer-command`: it reads `SCENE SPP SEED` lines on stdin
and answers each with one CSV row (renderer `cycles`, in tessera bench's columns) for a scene
it has a reference of, none for others, then `done`; `error: MESSAGE` for a bad line. It exits
when stdin closes. relMSE is against the reference given for the scene, Cycles' own:

    python cycles_peer.py --scenes DIR --serve --reference NAME=REF.exr [--reference ...]

Reference mode renders a converged reference in one render (Cycles' own EXR, linear):

    python cycles_peer.py --scenes DIR --make-reference NAME=OUT.exr --reference-spp 4096

Each scene renders once untimed first (kernel loading, the BVH that persistent data keeps).
The timed span is bpy.ops.render.render, which for an EXR render result holds the image in
memory; reading it back for the error is not timed.
"""

import argparse
import os
import sys
import tempfile
import time

import bpy
import numpy as np

from peer_protocol import requests


def open_scene(scenes, name):
    path = os.path.join(scenes, name + ".blend")
    if bpy.data.filepath != os.path.abspath(path):
        bpy.ops.wm.open_mainfile(filepath=path)
    return bpy.context.scene


def render(scenes, name, spp, seed, out):
    """Renders NAME at spp with seed to the EXR `out`; the seconds the render took."""
    scene = open_scene(scenes, name)
    scene.cycles.samples = spp
    scene.cycles.seed = seed
    scene.render.filepath = out
    start = time.perf_counter()
    bpy.ops.render.render(write_still=True)
    return time.perf_counter() - start


def read_rgb(path):
    """An EXR's RGB as an (H, W, 3) float64 array, top row first."""
    image = bpy.data.images.load(path, check_existing=False)
    w, h = image.size
    px = np.empty(w * h * 4, dtype=np.float32)
    image.pixels.foreach_get(px)
    bpy.data.images.remove(image)
    return px.reshape(h, w, 4)[::-1, :, :3].astype(np.float64)


def relmse(img, ref):
    """tessera bench's relMSE: the mean over pixels and channels of (I − R)² / (R² + 0.01)."""
    return float(np.mean((img - ref) ** 2 / (ref**2 + 0.01)))


def make_reference(a):
    name, out = a.make_reference.split("=", 1)
    seconds = render(a.scenes, name, a.reference_spp, 100_000, out)
    print(f"{name}: {a.reference_spp} spp in {seconds:.1f} s", file=sys.stderr)


def serve(a):
    refs = dict(r.split("=", 1) for r in a.reference)
    loaded = {}
    warm = set()
    threads = os.cpu_count()
    with tempfile.TemporaryDirectory() as tmp:
        out = os.path.join(tmp, "render.exr")
        for name, spp, seed in requests():
            if name in refs and spp <= a.max_spp:
                if name not in loaded:
                    loaded[name] = read_rgb(refs[name])
                if name not in warm:
                    render(a.scenes, name, 1, 0, out)
                    warm.add(name)
                seconds = render(a.scenes, name, spp, seed, out)
                img = read_rgb(out)
                ref = loaded[name]
                if img.shape != ref.shape:
                    print(f"error: {name}: render {img.shape} and reference {ref.shape} differ in size", flush=True)
                    continue
                h, w, _ = img.shape
                rate = w * h * spp / seconds / 1e6
                print(f"cycles,{name},{spp},{seed},{threads},{seconds:.6f},{rate:.4f},{relmse(img, ref):.6e}", flush=True)


def main():
    argv = sys.argv[sys.argv.index("--") + 1 :] if "--" in sys.argv else sys.argv[1:]
    ap = argparse.ArgumentParser()
    ap.add_argument("--scenes", required=True, help="the folder bench/blender_scenes.py wrote")
    ap.add_argument("--serve", action="store_true")
    ap.add_argument("--reference", action="append", default=[], help="NAME=FILE.exr")
    ap.add_argument("--make-reference", help="NAME=OUT.exr")
    ap.add_argument("--reference-spp", type=int, default=4096)
    ap.add_argument("--max-spp", type=int, default=1 << 20)
    a = ap.parse_args(argv)
    # Blender's own messages ("Fra:1 Mem: …", a line per sample) go to stdout; the protocol
    # needs it clean, and nobody needs them.
    sys.stdout = os.fdopen(os.dup(1), "w")
    os.dup2(os.open(os.devnull, os.O_WRONLY), 1)
    if a.make_reference:
        make_reference(a)
    elif a.serve:
        serve(a)
    else:
        ap.error("give --serve or --make-reference")


main()
