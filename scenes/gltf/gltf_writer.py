"""A minimal glTF 2.0 writer for the generators beside it (make_sample.py,
make_reference_scenes.py): one binary buffer, float attributes, u16 indices, embedded PNG
images, written as a .glb. Standard library only."""
import json
import math
import os
import struct

TEXTURES = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "textures")


class Glb:
    def __init__(self):
        self.buf = bytearray()
        self.views = []
        self.accessors = []

    def _pad(self):
        while len(self.buf) % 4:
            self.buf.append(0)

    def view(self, data, target=None):
        self._pad()
        v = {"buffer": 0, "byteOffset": len(self.buf), "byteLength": len(data)}
        if target:
            v["target"] = target
        self.buf.extend(data)
        self.views.append(v)
        return len(self.views) - 1

    def floats(self, rows, kind):
        flat = [x for r in rows for x in r]
        v = self.view(struct.pack("<%df" % len(flat), *flat), 34962)
        acc = {"bufferView": v, "componentType": 5126, "count": len(rows), "type": kind}
        if kind == "VEC3":
            acc["min"] = [min(r[i] for r in rows) for i in range(3)]
            acc["max"] = [max(r[i] for r in rows) for i in range(3)]
        self.accessors.append(acc)
        return len(self.accessors) - 1

    def indices(self, idx):
        v = self.view(struct.pack("<%dH" % len(idx), *idx), 34963)
        self.accessors.append({"bufferView": v, "componentType": 5123, "count": len(idx),
                               "type": "SCALAR"})
        return len(self.accessors) - 1

    def mesh(self, p, n, uv, idx, material):
        attrs = {"POSITION": self.floats(p, "VEC3"), "NORMAL": self.floats(n, "VEC3")}
        if uv:
            attrs["TEXCOORD_0"] = self.floats(uv, "VEC2")
        return {"primitives": [{"attributes": attrs, "indices": self.indices(idx),
                                "material": material}]}

    def image(self, name):
        with open(os.path.join(TEXTURES, name), "rb") as f:
            return {"bufferView": self.view(f.read()), "mimeType": "image/png", "name": name}

    def write(self, path, doc):
        self._pad()
        doc = dict(doc, bufferViews=self.views, accessors=self.accessors,
                   buffers=[{"byteLength": len(self.buf)}])
        js = json.dumps(doc, separators=(",", ":")).encode()
        js += b" " * (-len(js) % 4)
        out = bytearray(b"glTF")
        out += struct.pack("<II", 2, 12 + 8 + len(js) + 8 + len(self.buf))
        out += struct.pack("<I", len(js)) + b"JSON" + js
        out += struct.pack("<I", len(self.buf)) + b"BIN\0" + self.buf
        with open(path, "wb") as f:
            f.write(out)
        print("%s: %d bytes" % (os.path.basename(path), len(out)))


def sphere(r, slices=32, stacks=16):
    """A UV sphere about the origin: positions, normals, texture coordinates, indices."""
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
    """A cube of half-size h, flat-shaded, no texture coordinates."""
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


def floor(half, repeat=1.0):
    """A square of side 2·half in the y = 0 plane, facing +y."""
    return (
        [[-half, 0, -half], [half, 0, -half], [half, 0, half], [-half, 0, half]],
        [[0, 1, 0]] * 4,
        [[0, 0], [repeat, 0], [repeat, repeat], [0, repeat]],
        [0, 2, 1, 0, 3, 2],
    )
