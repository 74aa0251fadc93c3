"""Writes the two glTF scenes that tessera renders against Mitsuba 3 (scenes/gltf-metals.toml
and scenes/gltf-glass.toml place them under the HDR sky; bench/gltf_mitsuba.py converts them
for Mitsuba):

- metals.glb: two fully metallic balls of glTF's metallic-roughness material, one with an
  embedded base colour texture and a packed metallic-roughness texture (roughness varies by
  tile, metalness is 1 everywhere), one plain, on a ground square, seen by a perspective
  camera and lit by a point light (KHR_lights_punctual);
- glass.glb: two balls of KHR_materials_transmission + _ior + _volume (a smooth one and a
  rough one, each tinted by its volume's attenuation), on the same ground, with the same camera
  and light.

The ground's material ("ground") is replaced by the TOML scenes with a diffuse one, where the
two renderers' models agree. Standard library only.

    python3 scenes/gltf/make_reference_scenes.py
"""
import math
import os
import struct
import zlib

from gltf_writer import Glb, floor, sphere

HERE = os.path.dirname(os.path.abspath(__file__))


def png_rgb(w, h, texel):
    rows = b"".join(b"\0" + bytes(c for x in range(w) for c in texel(x, y)) for y in range(h))

    def chunk(kind, data):
        return (struct.pack(">I", len(data)) + kind + data
                + struct.pack(">I", zlib.crc32(kind + data) & 0xFFFFFFFF))

    return (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, 8, 2, 0, 0, 0))
            + chunk(b"IDAT", zlib.compress(rows, 9)) + chunk(b"IEND", b""))


def common(g, materials):
    """The ground, the camera and the light, shared by both files: nodes 0 (ground), 1
    (camera), 2 (light); the balls' meshes are 1 and 2."""
    # The camera of scenes/pbr-metals.toml: at (0, 0.6, 4), looking at (0, -0.45, 0).
    down = math.atan2(1.05, 4.0)
    return {
        "asset": {"version": "2.0", "generator": "tessera scenes/gltf/make_reference_scenes.py"},
        "scene": 0,
        "scenes": [{"nodes": [0, 1, 2, 3, 4]}],
        "nodes": [
            {"name": "ground", "mesh": 0, "translation": [0, -1, 0]},
            {"name": "camera", "camera": 0, "translation": [0, 0.6, 4],
             "rotation": [-math.sin(down / 2), 0, 0, math.cos(down / 2)]},
            {"name": "lamp", "extensions": {"KHR_lights_punctual": {"light": 0}},
             "translation": [1.5, 1.5, 2.0]},
            {"name": "left", "mesh": 1, "translation": [-0.6, -0.5, 0]},
            {"name": "right", "mesh": 2, "translation": [0.6, -0.5, 0.2]},
        ],
        "meshes": [g.mesh(*floor(5), 0), g.mesh(*sphere(0.5, 48, 24), 1),
                   g.mesh(*sphere(0.5, 48, 24), 2)],
        "materials": [{"name": "ground", "pbrMetallicRoughness": {"metallicFactor": 0}}] + materials,
        "cameras": [{"name": "main", "type": "perspective",
                     "perspective": {"yfov": math.radians(40), "aspectRatio": 1.0, "znear": 0.1}}],
        "extensions": {"KHR_lights_punctual": {"lights": [
            {"name": "lamp", "type": "point", "color": [1.0, 0.9, 0.8],
             # 4 W/sr in candela (683 lm/W).
             "intensity": 4.0 * 683}]}},
    }


def metals_doc(g):
    """metals.glb's document, its images and meshes in `g` (bench/make_big_gltf.py builds on
    it)."""
    # Roughness (green) 0.25 or 0.65 by 4 x 4 tiles; metalness (blue) 1 everywhere.
    mr = png_rgb(16, 16, lambda x, y: (0, 64 if (x // 4 + y // 4) % 2 else 166, 255))
    base = g.image("checker.png")
    mr_image = {"bufferView": g.view(mr), "mimeType": "image/png", "name": "metals-mr.png"}
    doc = common(g, [
        {"name": "checker-metal", "pbrMetallicRoughness": {
            "baseColorTexture": {"index": 0}, "metallicRoughnessTexture": {"index": 1}}},
        {"name": "copper", "pbrMetallicRoughness": {
            "baseColorFactor": [0.95, 0.64, 0.54, 1], "metallicFactor": 1.0,
            "roughnessFactor": 0.35}},
    ])
    doc.update(images=[base, mr_image], textures=[{"source": 0}, {"source": 1}],
               extensionsUsed=["KHR_lights_punctual"])
    return doc


def metals():
    g = Glb()
    g.write(os.path.join(HERE, "metals.glb"), metals_doc(g))


def glass():
    g = Glb()

    def glass_material(name, roughness, colour, distance):
        return {"name": name,
                "pbrMetallicRoughness": {"metallicFactor": 0.0, "roughnessFactor": roughness},
                "extensions": {
                    "KHR_materials_transmission": {"transmissionFactor": 1.0},
                    "KHR_materials_ior": {"ior": 1.5},
                    "KHR_materials_volume": {"thicknessFactor": 1.0, "attenuationColor": colour,
                                             "attenuationDistance": distance}}}

    doc = common(g, [glass_material("blue-glass", 0.0, [0.6, 0.85, 1.0], 0.5),
                     glass_material("amber-frost", 0.3, [1.0, 0.8, 0.55], 1.0)])
    doc["extensionsUsed"] = ["KHR_lights_punctual", "KHR_materials_ior",
                             "KHR_materials_transmission", "KHR_materials_volume"]
    g.write(os.path.join(HERE, "glass.glb"), doc)


if __name__ == "__main__":
    metals()
    glass()
