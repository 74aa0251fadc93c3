"""A glTF 2.0 file as Mitsuba 3 scene-dictionary entries: the converter behind
bench/mitsuba_peer.py's "gltf-metals" and "gltf-glass" scenes, so that tessera's glTF import
is checked against an independent renderer reading the same file.

It reads what those scenes use, the way tessera reads it (docs/scene-format.md, "glTF files"),
and refuses the rest by name:
- the node tree (TRS or matrices), each mesh primitive (triangles; float positions, normals and
  TEXCOORD_0; u8/u16/u32 indices) written as a binary PLY placed by its node's matrix;
- metallic-roughness materials as `principled` (base colour factor or an sRGB texture;
  metallic and roughness factors, or the packed texture's blue and green channels, each
  split into a grey PNG), since where glTF's model and Disney's agree (full metals) the two
  render the same image;
- transmission with a volume as `dielectric` or `roughdielectric` (alpha = roughness²) with a
  purely absorbing `homogeneous` interior (sigma_t = -ln(attenuationColor) /
  attenuationDistance), which needs Mitsuba's `volpath` integrator;
- KHR_lights_punctual point and directional lights (colour x intensity / 683: candela and lux
  to W/sr and W/m², as tessera and Blender convert them), and a perspective camera (yfov
  about the vertical axis).

Texture coordinates are passed as glTF gives them: Mitsuba's bitmaps, like glTF, put v = 0
on the image's top row.
"""
import base64
import json
import math
import os
import struct

import numpy as np

COMPONENT = {5120: np.int8, 5121: np.uint8, 5122: np.int16, 5123: np.uint16, 5125: np.uint32,
             5126: np.float32}
WIDTH = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4}


def read(path):
    """The glTF JSON and its buffers' bytes."""
    with open(path, "rb") as f:
        data = f.read()
    bin_chunk = None
    if data[:4] == b"glTF":
        n = struct.unpack_from("<I", data, 12)[0]
        doc = json.loads(data[20:20 + n])
        at = 20 + n
        if at < len(data):
            m = struct.unpack_from("<I", data, at)[0]
            bin_chunk = data[at + 8:at + 8 + m]
    else:
        doc = json.loads(data)
    buffers = []
    for b in doc.get("buffers", []):
        uri = b.get("uri")
        if uri is None:
            buffers.append(bin_chunk)
        elif uri.startswith("data:"):
            buffers.append(base64.b64decode(uri.split(",", 1)[1]))
        else:
            with open(os.path.join(os.path.dirname(path), uri), "rb") as f:
                buffers.append(f.read())
    return doc, buffers


def view_bytes(doc, buffers, index):
    v = doc["bufferViews"][index]
    start = v.get("byteOffset", 0)
    return buffers[v["buffer"]][start:start + v["byteLength"]], v.get("byteStride")


def accessor(doc, buffers, index):
    a = doc["accessors"][index]
    if "sparse" in a or "bufferView" not in a:
        raise SystemExit(f"accessor {index}: sparse or view-less accessors are not converted")
    dtype = np.dtype(COMPONENT[a["componentType"]]).newbyteorder("<")
    width = WIDTH[a["type"]]
    raw, stride = view_bytes(doc, buffers, a["bufferView"])
    offset = a.get("byteOffset", 0)
    size = dtype.itemsize * width
    stride = stride or size
    count = a["count"]
    if stride == size:
        rows = np.frombuffer(raw, dtype=dtype, count=count * width, offset=offset)
        rows = rows.reshape(count, width).copy()
    else:
        rows = np.empty((count, width), dtype=dtype)
        for i in range(count):
            rows[i] = np.frombuffer(raw, dtype=dtype, count=width, offset=offset + i * stride)
    if a.get("normalized"):
        raise SystemExit(f"accessor {index}: normalized integers are not converted")
    return rows


def node_matrix(n):
    if "matrix" in n:
        return np.array(n["matrix"], dtype=np.float64).reshape(4, 4).T
    t = np.eye(4)
    t[:3, 3] = n.get("translation", [0, 0, 0])
    x, y, z, w = n.get("rotation", [0, 0, 0, 1])
    r = np.eye(4)
    r[:3, :3] = [[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                 [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                 [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]]
    s = np.diag(list(n.get("scale", [1, 1, 1])) + [1])
    return t @ r @ s


def walk(doc):
    """(node, world matrix) for every node of the file's scene, parents first."""
    scene = doc["scenes"][doc.get("scene", 0)]
    out = []
    stack = [(i, np.eye(4)) for i in reversed(scene["nodes"])]
    while stack:
        i, parent = stack.pop()
        n = doc["nodes"][i]
        world = parent @ node_matrix(n)
        out.append((n, world))
        for c in reversed(n.get("children", [])):
            stack.append((c, world))
    return out


def write_ply(path, positions, normals, uvs, indices):
    header = ["ply", "format binary_little_endian 1.0", f"element vertex {len(positions)}",
              "property float x", "property float y", "property float z"]
    cols = [positions.astype("<f4")]
    if normals is not None:
        header += ["property float nx", "property float ny", "property float nz"]
        cols.append(normals.astype("<f4"))
    if uvs is not None:
        header += ["property float u", "property float v"]
        cols.append(uvs.astype("<f4"))
    header += [f"element face {len(indices) // 3}", "property list uchar uint vertex_indices",
               "end_header"]
    verts = np.hstack(cols).astype("<f4")
    faces = np.zeros(len(indices) // 3, dtype=[("n", "u1"), ("i", "<u4", 3)])
    faces["n"] = 3
    faces["i"] = np.asarray(indices, dtype=np.uint32).reshape(-1, 3)
    with open(path, "wb") as f:
        f.write(("\n".join(header) + "\n").encode())
        f.write(verts.tobytes())
        f.write(faces.tobytes())


def image_file(mi, doc, buffers, tex_index, out_dir, channel=None):
    """The PNG of texture `tex_index` as a file (embedded images are written out), or one of
    its channels as a grey PNG (Mitsuba reads no single channel of a packed image)."""
    image = doc["images"][doc["textures"][tex_index]["source"]]
    src = os.path.join(out_dir, f"image{doc['textures'][tex_index]['source']}.png")
    if not os.path.exists(src):
        if "bufferView" in image:
            data, _ = view_bytes(doc, buffers, image["bufferView"])
        else:
            raise SystemExit("only embedded images are converted")
        with open(src, "wb") as f:
            f.write(data)
    if channel is None:
        return src
    out = src[:-4] + f"-{channel}.png"
    if not os.path.exists(out):
        bmp = mi.Bitmap(src)
        arr = np.array(bmp)[..., "rgb".index(channel)]
        mi.Bitmap(np.ascontiguousarray(arr)).write(out)
    return out


def material(mi, doc, buffers, index, out_dir):
    """(bsdf, interior medium or None) for glTF material `index`."""
    m = doc["materials"][index]
    ext = m.get("extensions", {})
    pbr = m.get("pbrMetallicRoughness", {})
    roughness = pbr.get("roughnessFactor", 1.0)
    metallic = pbr.get("metallicFactor", 1.0)
    if "KHR_materials_volume" in ext:
        ior = ext.get("KHR_materials_ior", {}).get("ior", 1.5)
        vol = ext["KHR_materials_volume"]
        colour = np.array(vol.get("attenuationColor", [1, 1, 1]))
        distance = vol.get("attenuationDistance", math.inf)
        # A channel of σ = 0 gives NaN in Mitsuba's volpath (its distance sampling divides by
        # it): 1e-4 per unit length instead, which dims a path of length 1 by 0.01%.
        sigma = np.maximum(-np.log(np.clip(colour, 1e-6, 1)) / distance, 1e-4)
        # tessera's outside is vacuum; Mitsuba's default ext_ior is air.
        if roughness ** 2 < 1e-4:
            bsdf = {"type": "dielectric", "int_ior": ior, "ext_ior": 1.0}
        else:
            bsdf = {"type": "roughdielectric", "distribution": "ggx", "alpha": roughness ** 2,
                    "int_ior": ior, "ext_ior": 1.0}
        # An RGB texture here is read as a reflectance in [0, 1]: the largest σ goes in `scale`.
        top = float(sigma.max()) or 1.0
        medium = {"type": "homogeneous", "albedo": 0.0, "scale": top,
                  "sigma_t": {"type": "rgb", "value": [float(s) / top for s in sigma]}}
        return bsdf, medium
    bsdf = {"type": "principled", "metallic": metallic, "roughness": roughness}
    if "baseColorTexture" in pbr:
        bsdf["base_color"] = {"type": "bitmap", "filter_type": "bilinear",
                              "filename": image_file(mi, doc, buffers,
                                                     pbr["baseColorTexture"]["index"], out_dir)}
    else:
        bsdf["base_color"] = {"type": "rgb", "value": pbr.get("baseColorFactor", [1, 1, 1, 1])[:3]}
    if "metallicRoughnessTexture" in pbr:
        t = pbr["metallicRoughnessTexture"]["index"]
        if metallic != 1.0 or roughness != 1.0:
            raise SystemExit("a packed texture is converted with factors of 1 only")
        for key, channel in (("metallic", "b"), ("roughness", "g")):
            bsdf[key] = {"type": "bitmap", "raw": True, "filter_type": "bilinear",
                         "filename": image_file(mi, doc, buffers, t, out_dir, channel)}
    return bsdf, None


def convert(mi, path, out_dir, overrides=None):
    """Mitsuba dictionary entries for glTF file `path` (shapes, lights and a `sensor`), writing
    its meshes and images under `out_dir`. `overrides` maps glTF material names to Mitsuba
    BSDFs, as a TOML scene's materials_map does."""
    overrides = overrides or {}
    os.makedirs(out_dir, exist_ok=True)
    doc, buffers = read(path)
    T = mi.ScalarTransform4f
    entries = {}
    lights = doc.get("extensions", {}).get("KHR_lights_punctual", {}).get("lights", [])
    for k, (n, world) in enumerate(walk(doc)):
        xf = T(world.tolist())
        if "camera" in n:
            cam = doc["cameras"][n["camera"]]
            if cam["type"] != "perspective":
                raise SystemExit("only perspective cameras are converted")
            # Mitsuba's camera looks along +z with +x to the image's left; glTF's along -z
            # with +x to the right: a half turn about y.
            flip = np.diag([-1.0, 1.0, -1.0, 1.0])
            entries["sensor"] = {"type": "perspective", "fov_axis": "y",
                                 "fov": math.degrees(cam["perspective"]["yfov"]),
                                 "to_world": T((world @ flip).tolist()),
                                 "film": {"type": "hdrfilm"}}
        light = n.get("extensions", {}).get("KHR_lights_punctual")
        if light is not None:
            l = lights[light["light"]]
            # glTF's candela (point) and lux (directional) to W/sr and W/m², with 683 lm/W
            # as Blender and tessera convert.
            power = [c * (l.get("intensity", 1.0) / 683.0) for c in l.get("color", [1, 1, 1])]
            if l["type"] == "point":
                entries[f"light{k}"] = {"type": "point", "position": world[:3, 3].tolist(),
                                        "intensity": {"type": "rgb", "value": power}}
            elif l["type"] == "directional":
                d = world[:3, :3] @ np.array([0.0, 0.0, -1.0])
                entries[f"light{k}"] = {"type": "directional", "direction": d.tolist(),
                                        "irradiance": {"type": "rgb", "value": power}}
            else:
                raise SystemExit(f"{l['type']} lights are not converted")
        if "mesh" not in n:
            continue
        for p, prim in enumerate(doc["meshes"][n["mesh"]]["primitives"]):
            if prim.get("mode", 4) != 4:
                raise SystemExit("only triangle lists are converted")
            attrs = prim["attributes"]
            pos = accessor(doc, buffers, attrs["POSITION"])
            nor = accessor(doc, buffers, attrs["NORMAL"]) if "NORMAL" in attrs else None
            uv = accessor(doc, buffers, attrs["TEXCOORD_0"]) if "TEXCOORD_0" in attrs else None
            idx = (accessor(doc, buffers, prim["indices"]).ravel() if "indices" in prim
                   else np.arange(len(pos)))
            ply = os.path.join(out_dir, f"mesh{n['mesh']}-{p}.ply")
            write_ply(ply, pos, nor, uv, idx)
            mat = prim.get("material")
            name = doc["materials"][mat].get("name") if mat is not None else None
            if name in overrides:
                bsdf, medium = overrides[name], None
            elif mat is None:
                bsdf, medium = {"type": "principled", "metallic": 1.0, "roughness": 1.0}, None
            else:
                bsdf, medium = material(mi, doc, buffers, mat, out_dir)
            shape = {"type": "ply", "filename": ply, "to_world": xf, "bsdf": bsdf,
                     "face_normals": nor is None}
            if medium is not None:
                shape["interior"] = medium
            entries[f"shape{k}-{p}"] = shape
    return entries
