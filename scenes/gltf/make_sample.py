"""Writes sample.glb, the glTF scene of the README's quick start: a tiled floor (a base colour
texture, glTF's packed metallic-roughness image and a tangent-space normal map, all embedded,
repeated by KHR_texture_transform), a gold ball placed twice (one mesh, two nodes, under a
parent that is moved and turned), a glass ball (KHR_materials_transmission + _ior + _volume:
refracting, tinted by its attenuation) and a rough red box placed by a matrix, seen by a
perspective camera and lit by a sun and a point light (KHR_lights_punctual). Its textures
are scenes/textures/*.png. Standard library only.

    python3 scenes/gltf/make_sample.py
"""
import math
import os

from gltf_writer import Glb, box, floor, sphere

HERE = os.path.dirname(os.path.abspath(__file__))
g = Glb()
repeat = {"KHR_texture_transform": {"scale": [3, 3]}}
materials = [
    {
        "name": "tiles",
        "pbrMetallicRoughness": {
            "baseColorTexture": {"index": 0, "extensions": repeat},
            "metallicRoughnessTexture": {"index": 1, "extensions": repeat},
        },
        "normalTexture": {"index": 2, "scale": 1.0, "extensions": repeat},
    },
    {
        "name": "gold",
        "pbrMetallicRoughness": {
            "baseColorFactor": [1.0, 0.78, 0.34, 1],
            "metallicFactor": 1.0,
            "roughnessFactor": 0.3,
        },
    },
    {
        "name": "glass",
        "pbrMetallicRoughness": {"metallicFactor": 0.0, "roughnessFactor": 0.0},
        "extensions": {
            "KHR_materials_transmission": {"transmissionFactor": 1.0},
            "KHR_materials_ior": {"ior": 1.5},
            "KHR_materials_volume": {
                "thicknessFactor": 1.0,
                "attenuationColor": [0.7, 0.9, 1.0],
                "attenuationDistance": 1.0,
            },
        },
    },
    {
        "name": "red",
        "pbrMetallicRoughness": {
            "baseColorFactor": [0.8, 0.1, 0.08, 1],
            "metallicFactor": 0.0,
            "roughnessFactor": 0.45,
        },
    },
]
meshes = [
    g.mesh(*floor(3), 0),
    g.mesh(*sphere(0.6), 1),
    g.mesh(*sphere(0.6), 2),
    g.mesh(*box(0.45), 3),
]
images = [g.image("checker.png"), g.image("tiles-mr.png"), g.image("tiles-normal.png")]
textures = [{"source": i} for i in range(3)]
c, s = math.cos(math.radians(30)), math.sin(math.radians(30))
nodes = [
    {"name": "floor", "mesh": 0},
    {"name": "golds", "translation": [-0.6, 0, -0.4], "rotation": [0, s / 2, 0, math.sqrt(1 - s * s / 4)], "children": [2, 3]},
    {"name": "gold-a", "mesh": 1, "translation": [-0.7, 0.6, 0]},
    {"name": "gold-b", "mesh": 1, "translation": [0.7, 0.6, -0.9], "scale": [0.8, 0.8, 0.8]},
    {"name": "glass", "mesh": 2, "translation": [0.9, 0.6, 0.7]},
    # A column-major matrix: turned 30° about y, moved to (1.5, 0.45, -1).
    {"name": "box", "mesh": 3, "matrix": [c, 0, -s, 0, 0, 1, 0, 0, s, 0, c, 0, 1.5, 0.45, -1.0, 1]},
    {"name": "camera", "camera": 0, "translation": [0, 2.2, 6.2],
     "rotation": [-math.sin(math.radians(9)), 0, 0, math.cos(math.radians(9))]},
    {"name": "sun", "extensions": {"KHR_lights_punctual": {"light": 0}},
     "rotation": [-0.3535534, 0.3535534, 0.1464466, 0.8535534]},
    {"name": "lamp", "extensions": {"KHR_lights_punctual": {"light": 1}}, "translation": [-2, 2.5, 2]},
]
doc = {
    "asset": {"version": "2.0", "generator": "tessera scenes/gltf/make_sample.py"},
    "extensionsUsed": [
        "KHR_lights_punctual",
        "KHR_materials_ior",
        "KHR_materials_transmission",
        "KHR_materials_volume",
        "KHR_texture_transform",
    ],
    "scene": 0,
    "scenes": [{"nodes": [0, 1, 4, 5, 6, 7, 8]}],
    "nodes": nodes,
    "meshes": meshes,
    "materials": materials,
    "images": images,
    "textures": textures,
    "samplers": [],
    "cameras": [{"name": "main", "type": "perspective",
                 "perspective": {"yfov": 0.6, "aspectRatio": 16 / 9, "znear": 0.1}}],
    "extensions": {"KHR_lights_punctual": {"lights": [
        # 2.5 W/m² in lux and 12 W/sr in candela (683 lm/W).
        {"type": "directional", "color": [1.0, 0.95, 0.85], "intensity": 2.5 * 683},
        {"type": "point", "color": [1.0, 0.9, 0.8], "intensity": 12.0 * 683},
    ]}},
}
del doc["samplers"]
g.write(os.path.join(HERE, "sample.glb"), doc)
