"""Mitsuba 3 as a peer for `tessera bench`.

These scenes have exact Mitsuba counterparts, built here as dictionaries:
- cornell-box: Mitsuba's built-in Cornell box, the scene of tests/data/cornell-box-reference.exr
  and scenes/cornell-box.toml;
- glass-mirror: the same box with the two cuboids replaced by the spheres of
  scenes/glass-mirror.toml (a perfect mirror of reflectance 0.95 and a smooth dielectric of
  index 1.5 in vacuum);
- mesh-glass: scenes/mesh-glass.toml, from the same OBJ and PLY files;
- metals-box: scenes/metals-box.toml, the box with a gold and an aluminium ball of GGX
  roughness alpha 0.09 (`roughconductor`, RGB eta and k; its masking term is the separable
  G1(o)G1(i), tessera's the height-correlated one: docs/renderer.md, "Metals");
- envmap-balls: scenes/envmap-balls.toml, three balls (`plastic`, `roughconductor` gold,
  `roughdielectric` glass, GGX alpha 0.09) on a ground square under `envmap` of
  scenes/textures/sky.exr (bench/make_sky.py), turned 30 degrees about +y;
- materials: scenes/materials.toml, the material showcase: its two glTF (`pbr`) materials as
  Mitsuba's `principled` under `normalmap` (the Disney model, not glTF's: the two render
  different images, so each renderer is measured against its own reference), rough gold,
  frosted glass and `roughplastic`, under the same sky;
- pbr-metals: scenes/pbr-metals.toml, two fully metallic `pbr` balls as `principled` with
  metallic 1 (Schlick's Fresnel of F0 = base colour over GGX in both models) under the sky;
- gltf-metals, gltf-glass: scenes/gltf-metals.toml and gltf-glass.toml, glTF files converted
  by bench/gltf_mitsuba.py (full metals as `principled`, one textured; volume glass as
  `dielectric` and `roughdielectric` with an absorbing interior, under `volpath`), their
  ground replaced by a diffuse one as the TOML scenes do, under the same sky; gltf-big:
  bench/make_big_gltf.py's 2-million-triangle textured metal ball in gltf-metals' place
  (target/bench-cache/gltf-big, made by bench/gltf-speed.sh);
- mesh-million: bench/make_million.py's million triangles in the box, and
  mesh-million-analytic, the same with an analytic sphere in the mesh's place.
All use a box filter and the unbiased path tracer (max_depth = -1).

Peer mode renders each scene at 4, 16, ... spp with several seeds, times each render, and
writes CSV rows in `tessera bench`'s format (renderer,scene,spp,seed,threads,seconds,
msamples_per_s,relmse), relMSE against the reference given for that scene:

    python mitsuba_peer.py --reference cornell-box=REF.exr [--reference glass-mirror=REF2.exr]
        --out OUT.csv [--variants V ...] [--max-spp N] [--seeds K]

Serve mode measures one point at a time for `tessera bench --peer-command`, which asks for each
point right after measuring its own, so both renderers face the same minute of the machine. It
reads `SCENE SPP SEED` lines on stdin and answers each with one CSV row per variant that renders
that point (none for a scene it has no counterpart of, or above a variant's spp cap), then
`done`; `error: MESSAGE` for a request it cannot serve. It exits when stdin closes:

    python mitsuba_peer.py --serve --reference cornell-box=REF.exr [--reference ...]
        [--variants V ...]

Reference mode renders a converged reference of one scene (the mean of independent passes,
so no single render holds every sample in memory), as an RGB float32 EXR:

    python mitsuba_peer.py --make-reference glass-mirror=OUT.exr --reference-spp 16384

Block mode averages a reference over BxB pixel blocks, small enough to commit as test data
(tests/data/glass-mirror-reference-4x4.exr was made this way, with --block 4):

    python mitsuba_peer.py --block-means FULL.exr=OUT.exr --block 4

Each variant renders once untimed first, so JIT compilation (llvm_ad_rgb) is not timed. The
timed span is mi.render plus the copy to a NumPy array, which forces the lazy evaluation.
"""
import argparse
import os
import sys
import time

import numpy as np

from peer_protocol import requests


SCENES = ("cornell-box", "glass-mirror", "mesh-glass", "metals-box", "envmap-balls", "materials", "pbr-metals",
          "gltf-metals", "gltf-glass", "gltf-big", "mesh-million", "mesh-million-analytic",
          "envmap-balls-4k-cloudy", "envmap-balls-4k-sun", "envmap-balls-wide")

HERE = os.path.dirname(os.path.abspath(__file__))
# bench/make_big_sky.py's 4096 x 2048 skies, by the scene that uses each.
BIG_SKIES = {f"envmap-balls-4k-{k}": os.path.join(HERE, "..", "target", "bench-cache", "big-sky", f"{k}.exr")
             for k in ("cloudy", "sun")}
# envmap-balls under other skies than sky.exr, by scene: the big ones and
# scenes/envmap-balls-wide.toml's 512-wide one (bench/make_sky.py --wide).
SKIES = {**BIG_SKIES,
         "envmap-balls-wide": os.path.join(HERE, "..", "scenes", "textures", "sky-wide.exr")}
MESHES = os.path.join(HERE, "..", "scenes", "meshes")


def obj_groups(path, out_dir):
    """Splits an OBJ by `usemtl` group into one file per group (Mitsuba's OBJ reader makes one
    shape of a whole file), returning {group: path}. Vertices are shared, so each part keeps
    them all."""
    verts, groups, current = [], {}, None
    for line in open(path):
        w = line.split()
        if not w:
            continue
        if w[0] == "v":
            verts.append(line)
        elif w[0] == "usemtl":
            current = w[1]
        elif w[0] == "f":
            groups.setdefault(current, []).append(line)
    out = {}
    for g, faces in groups.items():
        p = os.path.join(out_dir, f"{os.path.basename(path)}.{g}.obj")
        with open(p, "w") as f:
            f.writelines(verts + faces)
        out[g] = p
    return out


def mesh_glass(mi, d):
    """scenes/mesh-glass.toml: the box's walls with an OBJ lamp (emitting panel, white housing)
    and two smooth-shaded icospheres from the same PLY, one diffuse blue, one glass."""
    import tempfile

    for k in ("small-box", "large-box", "light"):
        d.pop(k, None)
    white = d["white"] if "white" in d else {"type": "diffuse", "reflectance": {
        "type": "rgb", "value": [0.885809, 0.698859, 0.666422]}}
    parts = obj_groups(os.path.join(MESHES, "lamp.obj"), tempfile.mkdtemp())
    up = mi.ScalarTransform4f().translate([0, 0.97, 0])
    d["lamp-glow"] = {"type": "obj", "filename": parts["glow"], "to_world": up,
                      "face_normals": True, "bsdf": white,
                      "emitter": {"type": "area", "radiance": {
                          "type": "rgb", "value": [18.387, 13.9873, 6.75357]}}}
    d["lamp-housing"] = {"type": "obj", "filename": parts["housing"], "to_world": up,
                         "face_normals": True, "bsdf": white}
    ply = os.path.join(MESHES, "icosphere.ply")
    d["blue-ball"] = {"type": "ply", "filename": ply,
                      "to_world": mi.ScalarTransform4f().translate([0.3, -0.65, -0.35]).scale(0.35),
                      "bsdf": {"type": "diffuse", "reflectance": {
                          "type": "rgb", "value": [0.2, 0.3, 0.7]}}}
    d["glass-ball"] = {"type": "ply", "filename": ply,
                       "to_world": mi.ScalarTransform4f().translate([-0.05, -0.7, 0.35]).scale(0.3),
                       "bsdf": {"type": "dielectric", "int_ior": 1.5, "ext_ior": 1.0}}


def envmap_balls(mi, sky=None):
    """scenes/envmap-balls.toml: its own camera, no box; `sky` another map in sky.exr's place."""
    T = mi.ScalarTransform4f

    def rgb(v):
        return {"type": "rgb", "value": v}

    def ball(center, bsdf):
        return {"type": "sphere", "center": center, "radius": 0.45, "bsdf": bsdf}

    return {
        "type": "scene",
        "sensor": {"type": "perspective", "fov": 40.0,
                   "to_world": T().look_at(origin=[0.0, 0.6, 4.0], target=[0.0, -0.45, 0.0],
                                           up=[0.0, 1.0, 0.0]),
                   "film": {"type": "hdrfilm"}},
        "sky": {"type": "envmap",
                "filename": sky or os.path.join(HERE, "..", "scenes", "textures", "sky.exr"),
                "to_world": T().rotate([0, 1, 0], 30.0)},
        "ground": {"type": "rectangle",
                   "to_world": T([[10, 0, 0, 0], [0, 0, 10, -1], [0, -10, 0, 0], [0, 0, 0, 1]]),
                   "bsdf": {"type": "diffuse", "reflectance": rgb([0.5, 0.5, 0.5])}},
        # tessera's plastic is Mitsuba's model (linear, specular_reflectance 1).
        "plastic": ball([-1.05, -0.55, 0.0],
                        {"type": "plastic", "int_ior": 1.5, "ext_ior": 1.0,
                         "diffuse_reflectance": rgb([0.7, 0.15, 0.1])}),
        # crates/render/src/bsdf/conductor.rs's "gold".
        "gold": ball([0.0, -0.55, 0.35],
                     {"type": "roughconductor", "distribution": "ggx", "alpha": 0.09,
                      "eta": rgb([0.18299, 0.42108, 1.3734]), "k": rgb([3.4242, 2.3459, 1.7704])}),
        # tessera's outside is vacuum; Mitsuba's default ext_ior is air (1.000277).
        "frosted": ball([1.05, -0.55, 0.0],
                        {"type": "roughdielectric", "distribution": "ggx", "alpha": 0.09,
                         "int_ior": 1.5, "ext_ior": 1.0}),
    }


def channel_png(mi, src, channel, out):
    """One channel of the 8-bit PNG `src` as a grey 8-bit PNG `out` (Mitsuba's bitmap reads no
    single channel of a packed image)."""
    if not os.path.exists(out):
        os.makedirs(os.path.dirname(out), exist_ok=True)
        texels = np.array(mi.Bitmap(src))
        mi.Bitmap(np.ascontiguousarray(texels[..., channel:channel + 1])).write(out)
    return out


def materials(mi):
    """scenes/materials.toml: the material showcase."""
    T = mi.ScalarTransform4f
    scenes = os.path.join(HERE, "..", "scenes")
    tex = os.path.join(scenes, "textures")
    cache = os.path.join(HERE, "..", "target", "bench-cache", "materials")
    # glTF packs roughness in green and metallic in blue.
    rough = channel_png(mi, os.path.join(tex, "tiles-mr.png"), 1, os.path.join(cache, "roughness.png"))
    metal = channel_png(mi, os.path.join(tex, "tiles-mr.png"), 2, os.path.join(cache, "metallic.png"))

    def rgb(v):
        return {"type": "rgb", "value": v}

    def bitmap(path, raw):
        return {"type": "bitmap", "filename": path, "raw": raw, "filter_type": "bilinear"}

    def pbr(base_color, metallic, normal_scale):
        bsdf = {"type": "principled", "base_color": base_color, "metallic": metallic,
                "roughness": bitmap(rough, True), "eta": 1.5}
        # Mitsuba's normal map has no scale; the cube's 0.7 is left at 1.
        del normal_scale
        return {"type": "normalmap", "normalmap": bitmap(os.path.join(tex, "tiles-normal.png"), True),
                "bsdf": bsdf}

    def ball(center, radius, bsdf):
        return {"type": "sphere", "center": center, "radius": radius, "bsdf": bsdf}

    return {
        "type": "scene",
        "sensor": {"type": "perspective", "fov": 40.0,
                   "to_world": T().look_at(origin=[0.0, 1.1, 4.2], target=[0.0, -0.5, 0.0],
                                           up=[0.0, 1.0, 0.0]),
                   "film": {"type": "hdrfilm"}},
        "sky": {"type": "envmap", "filename": os.path.join(tex, "sky.exr"),
                "to_world": T().rotate([0, 1, 0], 30.0)},
        "ground": {"type": "rectangle",
                   "to_world": T([[10, 0, 0, 0], [0, 0, 10, -1], [0, -10, 0, 0], [0, 0, 0, 1]]),
                   "bsdf": {"type": "diffuse", "reflectance": rgb([0.45, 0.45, 0.45])}},
        "pad": {"type": "obj", "filename": os.path.join(scenes, "meshes", "quad.obj"),
                "to_world": T().translate([0, -0.995, 0]).rotate([1, 0, 0], -90).scale([1.6, 1.6, 1]),
                "bsdf": pbr(rgb([0.8, 0.75, 0.7]), bitmap(metal, True), 1.0)},
        "cube": {"type": "obj", "filename": os.path.join(scenes, "meshes", "textured-cube.obj"),
                 "to_world": T().translate([0.0, -0.675, -0.55]).rotate([0, 1, 0], 30).scale(0.32),
                 "bsdf": pbr(bitmap(os.path.join(tex, "checker.png"), False), 0.0, 0.7)},
        "gold": ball([-1.0, -0.6, 0.15], 0.4,
                     {"type": "roughconductor", "distribution": "ggx", "alpha": 0.35 ** 2,
                      "eta": rgb([0.18299, 0.42108, 1.3734]), "k": rgb([3.4242, 2.3459, 1.7704])}),
        "frosted": ball([1.0, -0.6, 0.15], 0.4,
                        {"type": "roughdielectric", "distribution": "ggx", "alpha": 0.09,
                         "int_ior": 1.5, "ext_ior": 1.0}),
        "plastic": ball([0.0, -0.75, 0.75], 0.25,
                        {"type": "roughplastic", "distribution": "ggx", "alpha": 0.0625,
                         "int_ior": 1.5, "ext_ior": 1.0,
                         "diffuse_reflectance": rgb([0.7, 0.12, 0.08])}),
    }


def pbr_metals(mi):
    """scenes/pbr-metals.toml: envmap-balls' camera, sky and ground, two principled metals."""
    d = envmap_balls(mi)
    for k in ("plastic", "gold", "frosted"):
        del d[k]

    def metal(center, color, roughness):
        return {"type": "sphere", "center": center, "radius": 0.5,
                "bsdf": {"type": "principled", "base_color": {"type": "rgb", "value": color},
                         "metallic": 1.0, "roughness": roughness}}
    d["brass"] = metal([-0.6, -0.5, 0.0], [0.9, 0.6, 0.3], 0.5)
    d["steel"] = metal([0.6, -0.5, 0.0], [0.6, 0.62, 0.65], 0.25)
    return d


def gltf_scene(mi, name):
    """scenes/gltf-metals.toml, gltf-glass.toml or gltf-big.toml: the glTF file converted,
    under the sky."""
    import gltf_mitsuba
    T = mi.ScalarTransform4f
    d = {"type": "scene",
         "sky": {"type": "envmap", "to_world": T().rotate([0, 1, 0], 30.0),
                 "filename": os.path.join(HERE, "..", "scenes", "textures", "sky.exr")}}
    stem = name.split("-", 1)[1]
    out = os.path.join(HERE, "..", "target", "bench-cache", name)
    # gltf-big's file is bench/make_big_gltf.py's, made by bench/gltf-speed.sh.
    glb = (os.path.join(out, "big.glb") if name == "gltf-big"
           else os.path.join(HERE, "..", "scenes", "gltf", stem + ".glb"))
    ground = {"type": "diffuse", "reflectance": {"type": "rgb", "value": [0.5, 0.5, 0.5]}}
    d.update(gltf_mitsuba.convert(mi, glb, out, overrides={"ground": ground}))
    return d


def scene_dict(mi, name, size):
    """The Mitsuba scene dictionary of `name` at `size`x`size` pixels."""
    if name in ("gltf-metals", "gltf-glass", "gltf-big"):
        d = gltf_scene(mi, name)
    elif name == "materials":
        d = materials(mi)
    elif name == "pbr-metals":
        d = pbr_metals(mi)
    else:
        d = envmap_balls(mi, SKIES.get(name)) if name.startswith("envmap-balls") else mi.cornell_box()
    if name == "glass-mirror":
        # scenes/glass-mirror.toml: the box, lit as before, with two balls for the cuboids.
        del d["small-box"], d["large-box"]
        d["mirror-ball"] = {
            "type": "sphere", "center": [-0.42, -0.68, -0.3], "radius": 0.32,
            # material "none": a perfect conductor (F = 1), scaled by the reflectance.
            "bsdf": {"type": "conductor", "material": "none",
                     "specular_reflectance": {"type": "rgb", "value": [0.95, 0.95, 0.95]}},
        }
        d["glass-ball"] = {
            "type": "sphere", "center": [0.42, -0.68, 0.3], "radius": 0.32,
            # tessera's outside is vacuum; Mitsuba's default ext_ior is air (1.000277).
            "bsdf": {"type": "dielectric", "int_ior": 1.5, "ext_ior": 1.0},
        }
    elif name == "metals-box":
        del d["small-box"], d["large-box"]

        def metal(eta, k):
            return {"type": "roughconductor", "distribution": "ggx", "alpha": 0.09,
                    "eta": {"type": "rgb", "value": eta}, "k": {"type": "rgb", "value": k}}

        # crates/render/src/bsdf/conductor.rs's "gold", and aluminium's values given as eta, k.
        d["gold-ball"] = {"type": "sphere", "center": [-0.42, -0.68, -0.3], "radius": 0.32,
                          "bsdf": metal([0.18299, 0.42108, 1.3734], [3.4242, 2.3459, 1.7704])}
        d["aluminium-ball"] = {"type": "sphere", "center": [0.42, -0.68, 0.3], "radius": 0.32,
                               "bsdf": metal([1.3456, 0.96521, 0.61722],
                                             [7.4746, 6.3995, 5.3031])}
    elif name == "mesh-glass":
        mesh_glass(mi, d)
    elif name == "mesh-million":
        # bench/make_million.py's scene: the walls and light around its bumpy sphere.
        del d["small-box"], d["large-box"]
        ply = os.path.join(HERE, "..", "target", "bench-cache", "mesh-million", "bumpy-sphere.ply")
        d["bumpy-sphere"] = {"type": "ply", "filename": ply, "face_normals": True,
                             "to_world": mi.ScalarTransform4f().translate([0, -0.5, 0]).scale(0.45),
                             "bsdf": {"type": "ref", "id": "white"}}
    elif name == "mesh-million-analytic":
        # The same, with an analytic sphere in the mesh's place (make_million.py).
        del d["small-box"], d["large-box"]
        d["sphere"] = {"type": "sphere", "center": [0, -0.5, 0], "radius": 0.45,
                       "bsdf": {"type": "ref", "id": "white"}}
    elif name not in ("cornell-box", "envmap-balls", "materials", "pbr-metals", "gltf-metals",
                      "gltf-glass", "gltf-big", *SKIES):
        raise SystemExit(f"no Mitsuba counterpart for scene {name!r}; known: {SCENES}")
    d["sensor"]["film"].update(width=size, height=size, rfilter={"type": "box"})
    d["sensor"]["sampler"] = {"type": "independent", "sample_count": 4}
    # Glass that absorbs inside needs the volumetric path tracer (without media, the same).
    d["integrator"] = {"type": "volpath" if name == "gltf-glass" else "path", "max_depth": -1}
    return d


def name_file(arg, flag):
    name, sep, path = arg.partition("=")
    if not sep or not name or not path:
        raise SystemExit(f"{flag} {arg!r}: expected NAME=FILE.exr")
    if name not in SCENES:
        raise SystemExit(f"{flag} {arg!r}: no Mitsuba counterpart for {name!r}; known: {SCENES}")
    return name, path


def set_variant(mi, variants):
    """The first of `variants` this build and machine can run."""
    for v in variants:
        try:
            mi.set_variant(v)
            return v
        except Exception as e:
            print(f"skipping {v}: {e}", file=sys.stderr)
    raise SystemExit(f"none of the variants {variants} runs here")


def make_reference(mi, a):
    name, out = name_file(a.make_reference, "--make-reference")
    variant = set_variant(mi, a.variants)
    scene = mi.load_dict(scene_dict(mi, name, a.size))
    passes = max(1, a.reference_spp // a.pass_spp)
    acc = None
    t = time.perf_counter()
    for k in range(passes):
        # Seeds far from the peer runs' 1, 2, ... keep the reference's noise independent.
        img = np.array(mi.render(scene, spp=a.pass_spp, seed=1_000_000 + k), dtype=np.float64)
        acc = img if acc is None else acc + img
    mean = (acc / passes)[..., :3].astype(np.float32)
    write_rgb(mi, mean, out,
              f"independent reference: Mitsuba 3 {variant}, "
              f"{scene_dict(mi, name, 8)['integrator']['type']} integrator, "
              f"{passes * a.pass_spp} spp ({passes} passes of {a.pass_spp}, seeds from 1000000)")
    dt = time.perf_counter() - t
    print(f"{name}: {passes * a.pass_spp} spp with {variant} in {dt:.1f} s -> {out}",
          file=sys.stderr)


def write_rgb(mi, rgb, path, comments):
    """Writes a float32 RGB EXR whose `comments` attribute says how it was made: `tessera bench`
    quotes it when the file is given as a reference."""
    bmp = mi.Bitmap(rgb, pixel_format=mi.Bitmap.PixelFormat.RGB)
    bmp.metadata()["comments"] = comments
    bmp.write(path)


def read_rgb(mi, path):
    """An EXR's RGB channels as a float64 (height, width, 3) array."""
    return rgb_of(mi, mi.Bitmap(path))


def rgb_of(mi, bmp):
    return np.array(bmp.convert(
        mi.Bitmap.PixelFormat.RGB, mi.Struct.Type.Float32, False), dtype=np.float64)


def block_means(mi, a):
    src, sep, out = a.block_means.partition("=")
    if not sep or not src or not out:
        raise SystemExit(f"--block-means {a.block_means!r}: expected FULL.exr=OUT.exr")
    mi.set_variant("scalar_rgb")
    bmp = mi.Bitmap(src)
    img = rgb_of(mi, bmp)
    b = a.block
    h, w = img.shape[:2]
    if b < 1 or h % b or w % b:
        raise SystemExit(f"--block {b} does not divide the {w}x{h} image {src}")
    means = img.reshape(h // b, b, w // b, b, 3).mean(axis=(1, 3)).astype(np.float32)
    source = bmp.metadata()
    origin = source["comments"] if "comments" in source else src
    write_rgb(mi, means, out, f"{b}x{b}-pixel block means of {origin}")


class Peer:
    """One variant's render of one scene, loaded, checked against its reference and warmed up
    (JIT compilation for llvm_ad_rgb is not timed), ready to measure points."""

    def __init__(self, mi, a, variant, name, ref_path):
        self.mi, self.variant, self.name, self.size = mi, variant, name, a.size
        self.ref = read_rgb(mi, ref_path)
        if self.ref.shape[:2] != (a.size, a.size):
            raise SystemExit(f"reference {ref_path} is {self.ref.shape[1]}x{self.ref.shape[0]}, "
                             f"the render {a.size}x{a.size}")
        mi.set_variant(variant)
        self.scene = mi.load_dict(scene_dict(mi, name, a.size))
        np.array(mi.render(self.scene, spp=4, seed=999))  # warm-up, not timed
        self.max_spp = (min(a.max_spp, a.scalar_max_spp) if variant.startswith("scalar")
                        else a.max_spp)
        self.threads = os.cpu_count()

    def measure(self, spp, seed):
        """The CSV row of one timed render."""
        self.mi.set_variant(self.variant)
        t = time.perf_counter()
        img = np.array(self.mi.render(self.scene, spp=spp, seed=seed), dtype=np.float64)
        dt = time.perf_counter() - t
        rel = float(np.mean((img[..., :3] - self.ref) ** 2 / (self.ref ** 2 + 0.01)))
        return (f"mitsuba-{self.variant},{self.name},{spp},{seed},{self.threads},{dt:.6f},"
                f"{self.size * self.size * spp / dt / 1e6:.4f},{rel:.6e}")


def serve(mi, a, references):
    """Answers `SCENE SPP SEED` lines on stdin (see the module's doc) until stdin closes."""
    variants = []
    for v in a.variants:
        try:
            mi.set_variant(v)
            variants.append(v)
        except Exception as e:  # a variant this build or machine cannot run
            print(f"skipping {v}: {e}", file=sys.stderr)
    if not variants:
        raise SystemExit(f"none of the variants {a.variants} runs here")
    refs = dict(references)
    peers = {}  # (variant, scene) -> Peer, made at the first request for it
    for name, spp, seed in requests():
        if name in refs:
            for v in variants:
                if (v, name) not in peers:
                    peers[(v, name)] = Peer(mi, a, v, name, refs[name])
                peer = peers[(v, name)]
                if spp <= peer.max_spp:
                    print(peer.measure(spp, seed), flush=True)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--reference", action="append", default=[],
                    help="NAME=FILE.exr: the scene to render as a peer and its reference")
    ap.add_argument("--out")
    ap.add_argument("--serve", action="store_true",
                    help="measure the points tessera bench --peer-command asks for on stdin")
    ap.add_argument("--make-reference", help="NAME=FILE.exr: render a converged reference")
    ap.add_argument("--reference-spp", type=int, default=16384)
    ap.add_argument("--block-means", help="FULL.exr=OUT.exr: average over --block pixels")
    ap.add_argument("--block", type=int, default=4)
    ap.add_argument("--pass-spp", type=int, default=256)
    ap.add_argument("--variants", nargs="+", default=["llvm_ad_rgb", "scalar_rgb"])
    ap.add_argument("--max-spp", type=int, default=4096)
    ap.add_argument("--seeds", type=int, default=2)
    ap.add_argument("--size", type=int, default=256)
    ap.add_argument("--scalar-max-spp", type=int, default=1024,
                    help="cap for scalar_rgb, ~3x slower than llvm_ad_rgb; its relMSE*s is "
                         "already flat by then")
    a = ap.parse_args()

    import mitsuba as mi

    if a.make_reference:
        make_reference(mi, a)
        return
    if a.block_means:
        block_means(mi, a)
        return
    if not a.reference or not (a.out or a.serve):
        ap.error("peer mode needs --out (or --serve) and at least one --reference NAME=FILE.exr")
    references = [name_file(r, "--reference") for r in a.reference]

    if a.serve:
        serve(mi, a, references)
        return
    rows = []
    for variant in a.variants:
        try:
            mi.set_variant(variant)
        except Exception as e:  # a variant this build or machine cannot run
            print(f"skipping {variant}: {e}", file=sys.stderr)
            continue
        for name, ref_path in references:
            peer = Peer(mi, a, variant, name, ref_path)
            spp = 4
            while spp <= peer.max_spp:
                for seed in range(1, a.seeds + 1):
                    row = peer.measure(spp, seed)
                    print(row, file=sys.stderr, flush=True)
                    rows.append(row)
                spp *= 4
    with open(a.out, "w") as f:
        f.write("renderer,scene,spp,seed,threads,seconds,msamples_per_s,relmse\n")
        f.write("".join(r + "\n" for r in rows))


if __name__ == "__main__":
    main()
