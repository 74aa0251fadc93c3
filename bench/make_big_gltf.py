"""Writes the large glTF scene of the glTF benchmarks: scenes/gltf/metals.glb's ground, camera
and point light around one bumpy ball of 2 x 1024^2 = 2,097,152 triangles (u32 indices,
normals, texture coordinates) wearing metals.glb's textured metal (the checker base colour and
the packed metallic-roughness image), as DIR/big.glb (about 59 MB), and DIR/gltf-big.toml,
which places it under the HDR sky with the diffuse ground, as scenes/gltf-metals.toml does.
Not committed: bench/gltf-speed.sh makes them under target/bench-cache/gltf-big, and
bench/mitsuba_peer.py converts the same file for Mitsuba 3.

    python make_big_gltf.py DIR
"""
import os
import shutil
import sys

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.join(HERE, "..", "scenes", "gltf"))
from gltf_writer import Glb  # noqa: E402
from make_reference_scenes import metals_doc  # noqa: E402

N = 1024  # quads per side of the (rings x segments) grid: 2·N² triangles


def bumpy_ball(g, radius):
    """The ball's mesh: positions on a sphere whose radius varies by ±4%, unit-sphere normals
    (both renderers read the same ones), u around and v down, as glTF's."""
    th = np.linspace(0, np.pi, N + 1)[:, None]
    ph = np.linspace(0, 2 * np.pi, N + 1)[None, :]
    d = np.stack([np.sin(th) * np.cos(ph), np.cos(th) + 0 * ph, -np.sin(th) * np.sin(ph)], -1)
    r = radius * (1 + 0.04 * np.sin(12 * th) * np.cos(9 * ph))
    pos = (d * r[..., None]).reshape(-1, 3).astype("<f4")
    nrm = d.reshape(-1, 3).astype("<f4")
    uv = np.stack(np.broadcast_arrays(ph / (2 * np.pi), th / np.pi), -1).reshape(-1, 2)
    a = (np.arange(N)[:, None] * (N + 1) + np.arange(N)[None, :]).reshape(-1)
    b = a + N + 1
    idx = np.stack([a, b, a + 1, a + 1, b, b + 1], -1).reshape(-1).astype("<u4")

    def add(array, kind, component, target):
        g.accessors.append({"bufferView": g.view(array.tobytes(), target),
                            "componentType": component, "count": len(array), "type": kind})
        if kind == "VEC3":
            g.accessors[-1].update(min=array.min(0).tolist(), max=array.max(0).tolist())
        return len(g.accessors) - 1

    attrs = {"POSITION": add(pos, "VEC3", 5126, 34962), "NORMAL": add(nrm, "VEC3", 5126, 34962),
             "TEXCOORD_0": add(uv.astype("<f4"), "VEC2", 5126, 34962)}
    return {"primitives": [{"attributes": attrs, "indices": add(idx, "SCALAR", 5125, 34963),
                            "material": 1}]}, len(idx) // 3


def main(out):
    os.makedirs(out, exist_ok=True)
    g = Glb()
    doc = metals_doc(g)
    ball, triangles = bumpy_ball(g, 0.7)
    # metals.glb's two balls give way to the one bumpy ball in the textured metal (material
    # 1), centred between them; the small balls' meshes stay in the buffer, unplaced.
    doc["meshes"][1] = ball
    # The plain ball's copper is placed nowhere now: an empty material keeps its index.
    doc["materials"][2] = {"name": "unused", "pbrMetallicRoughness": {}}
    doc["nodes"][3].update(name="ball", translation=[0, -0.3, 0.1])
    doc["scenes"][0]["nodes"] = [0, 1, 2, 3]
    g.write(os.path.join(out, "big.glb"), doc)
    shutil.copy(os.path.join(HERE, "..", "scenes", "textures", "sky.exr"), out)
    with open(os.path.join(HERE, "..", "scenes", "gltf-metals.toml")) as f:
        toml = f.read()
    toml = toml[toml.index("version = 1"):]
    toml = toml.replace('file = "textures/sky.exr"', 'file = "sky.exr"')
    toml = toml.replace('file = "gltf/metals.glb"', 'file = "big.glb"')
    assert toml.count("big.glb") == 1 and toml.count('"sky.exr"') == 1
    with open(os.path.join(out, "gltf-big.toml"), "w") as f:
        f.write(f"# bench/make_big_gltf.py: a glTF ball of {triangles:,} triangles in "
                "scenes/gltf-metals.toml's place.\n" + toml)
    print(f"{triangles} triangles -> {out}")


main(sys.argv[1])
