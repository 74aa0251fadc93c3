"""Writes sample.glb, the glTF scene of the README's quick start: a tiled floor (a base colour
texture, glTF's packed metallic-roughness image and a tangent-space normal map, all embedded,
repeated by KHR_texture_transform), a gold ball placed twice (one mesh, two nodes, under a
parent that is moved and turned), a glass ball (KHR_materials_transmission + _ior + _volume:
refracting, tinted by its attenuation) and a rough red box placed by a matrix, seen by a
perspective camera and lit by a sun and a point light (KHR_lights_punctual). Its textures
are scenes/textures/*.png. Standard library only.

    python3 scenes/gltf/make_sample.py
"""
import json
import math
import os
import struct

HERE = os.path.dirname(os.path.abspath(__file__))
TEXTURES = os.path.join(HERE, "..", "textures")

buf = bytearray()
views = []
accessors = []


def pad4():
    while len(buf) % 4:
        buf.append(0)


def view(data, target=None):
    pad4()
    v = {"buffer": 0, "byteOffset": len(buf), "byteLength": len(data)}
    if target:
        v["target"] = target
    buf.extend(data)
    views.append(v)
    return len(views) - 1


def floats(rows, kind):
    flat = [x for r in rows for x in r]
    v = view(struct.pack("<%df" % len(flat), *flat), 34962)
    n = len(rows[0])
    acc = {"bufferView": v, "componentType": 5126, "count": len(rows), "type": kind}
    if kind == "VEC3":
        acc["min"] = [min(r[i] for r in rows) for i in range(n)]
        acc["max"] = [max(r[i] for r in rows) for i in range(n)]
    accessors.append(acc)
    return len(accessors) - 1


def indices(idx):
    v = view(struct.pack("<%dH" % len(idx), *idx), 34963)
    accessors.append({"bufferView": v, "componentType": 5123, "count": len(idx), "type": "SCALAR"})
    return len(accessors) - 1


def mesh(p, n, uv, idx, material):
    attrs = {"POSITION": floats(p, "VEC3"), "NORMAL": floats(n, "VEC3")}
    if uv:
        attrs["TEXCOORD_0"] = floats(uv, "VEC2")
    return {"primitives": [{"attributes": attrs, "indices": indices(idx), "material": material}]}


def sphere(r, slices=32, stacks=16):
    p, n, uv, idx = [], [], [], []
    for i in range(stacks + 1):
        th = math.pi * i / stacks
        for j in range(slices + 1):
            ph = 2 * math.pi * j / slices
            d = (math.sin(th) * math.cos(ph), math.cos(th), -math.sin(th) * math.sin(ph))
            p.append([r * c for c in d])
            n.append(list(d))
            uv.append([j / slices, i / stacks])
    for i in range(stacks):
        for j in range(slices):
            a = i * (slices + 1) + j
            b = a + slices + 1
            idx += [a, b, a + 1, a + 1, b, b + 1]
    return p, n, uv, idx


def box(h):
    p, n, idx = [], [], []
    for axis in range(3):
        for s in (-1, 1):
            nn = [0, 0, 0]
            nn[axis] = s
            u = [0, 0, 0]
            u[(axis + 1) % 3] = 1
            v = [0, 0, 0]
            v[(axis + 2) % 3] = 1
            base = len(p)
            for a, b in ((-1, -1), (1, -1), (1, 1), (-1, 1)):
                p.append([h * (nn[k] + a * u[k] + b * v[k]) for k in range(3)])
                n.append(nn)
            quad = [base, base + 1, base + 2, base, base + 2, base + 3]
            if s < 0:
                quad = [base, base + 2, base + 1, base, base + 3, base + 2]
            idx += quad
    return p, n, None, idx


def image(name):
    with open(os.path.join(TEXTURES, name), "rb") as f:
        return {"bufferView": view(f.read()), "mimeType": "image/png", "name": name}


floor = (
    [[-3, 0, -3], [3, 0, -3], [3, 0, 3], [-3, 0, 3]],
    [[0, 1, 0]] * 4,
    [[0, 0], [1, 0], [1, 1], [0, 1]],
    [0, 2, 1, 0, 3, 2],
)
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
    mesh(*floor, 0),
    mesh(*sphere(0.6), 1),
    mesh(*sphere(0.6), 2),
    mesh(*box(0.45), 3),
]
images = [image("checker.png"), image("tiles-mr.png"), image("tiles-normal.png")]
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
pad4()
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
        {"type": "directional", "color": [1.0, 0.95, 0.85], "intensity": 2.5},
        {"type": "point", "color": [1.0, 0.9, 0.8], "intensity": 12.0},
    ]}},
    "bufferViews": views,
    "accessors": accessors,
    "buffers": [{"byteLength": len(buf)}],
}
del doc["samplers"]
js = json.dumps(doc, separators=(",", ":")).encode()
js += b" " * (-len(js) % 4)
out = bytearray(b"glTF")
out += struct.pack("<II", 2, 12 + 8 + len(js) + 8 + len(buf))
out += struct.pack("<I", len(js)) + b"JSON" + js
out += struct.pack("<I", len(buf)) + b"BIN\0" + buf
with open(os.path.join(HERE, "sample.glb"), "wb") as f:
    f.write(out)
print("sample.glb: %d bytes" % len(out))
