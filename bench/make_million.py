"""Writes the mesh benchmark's scene: the Cornell box's walls and light around a bumpy sphere
of 1,048,576 triangles (a UV sphere of 512 rings by 1,024 segments, its radius modulated),
as DIR/mesh-million.toml and DIR/bumpy-sphere.ply (binary PLY, about 20 MB), and the same
scene with an analytic sphere in the mesh's place as DIR/mesh-million-analytic.toml, and with
the bumpy sphere emitting as DIR/mesh-million-emissive.toml. Not committed:
bench/mesh-speed.sh makes them under target/bench-cache.

    python make_million.py DIR
"""
import os
import sys

import numpy as np

RINGS, SEGMENTS = 512, 1024


def main(out):
    os.makedirs(out, exist_ok=True)
    theta = np.linspace(0, np.pi, RINGS + 1)[:, None]
    phi = np.linspace(0, 2 * np.pi, SEGMENTS, endpoint=False)[None, :]
    r = 1 + 0.04 * np.sin(12 * theta) * np.cos(9 * phi) + 0.01 * np.sin(47 * phi)
    r[0, :] = r[-1, :] = 1
    pos = np.stack([r * np.sin(theta) * np.cos(phi), r * np.cos(theta),
                    r * np.sin(theta) * np.sin(phi)], axis=-1).reshape(-1, 3).astype("<f4")
    i = np.arange(RINGS)[:, None]
    k = np.arange(SEGMENTS)[None, :]
    a = i * SEGMENTS + k
    b = i * SEGMENTS + (k + 1) % SEGMENTS
    c = a + SEGMENTS
    d = b + SEGMENTS
    # Counter-clockwise seen from outside.
    tris = np.concatenate([np.stack([a, b, d], -1).reshape(-1, 3),
                           np.stack([a, d, c], -1).reshape(-1, 3)])
    faces = np.zeros(len(tris), dtype=[("n", "u1"), ("v", "<i4", 3)])
    faces["n"] = 3
    faces["v"] = tris
    with open(os.path.join(out, "bumpy-sphere.ply"), "wb") as f:
        f.write((f"ply\nformat binary_little_endian 1.0\nelement vertex {len(pos)}\n"
                 "property float x\nproperty float y\nproperty float z\n"
                 f"element face {len(tris)}\nproperty list uchar int vertex_indices\n"
                 "end_header\n").encode())
        f.write(pos.tobytes())
        f.write(faces.tobytes())
    here = os.path.dirname(os.path.abspath(__file__))
    box = open(os.path.join(here, "..", "scenes", "cornell-box.toml")).read()
    box = box[:box.index("[[objects]] # large box")]
    box = box.replace(box[:box.index("version = 1")],
                      "# tessera's mesh benchmark (bench/make_million.py): the Cornell box's walls and light\n"
                      f"# around a bumpy sphere of {len(tris):,} triangles.\n")
    box += ('[[objects]] # the bumpy sphere\nshape = "mesh"\nfile = "bumpy-sphere.ply"\n'
            'material = "white"\ntransform = { scale = [0.45, 0.45, 0.45], translate = [0, -0.5, 0] }\n')
    with open(os.path.join(out, "mesh-million.toml"), "w") as f:
        f.write(box)
    # The same scene with an analytic sphere in the mesh's place (the bumps are 5% of its
    # radius): what the mesh costs a sample is the difference of the two.
    stand_in = box[:box.index("[[objects]] # the bumpy sphere")]
    stand_in = stand_in.replace("around a bumpy sphere of",
                                "with an analytic sphere in place of the bumpy sphere of")
    stand_in += ('[[objects]] # an analytic sphere where mesh-million.toml has its bumpy one\n'
                 'shape = "sphere"\nmaterial = "white"\ncenter = [0.0, -0.5, 0.0]\nradius = 0.45\n')
    with open(os.path.join(out, "mesh-million-analytic.toml"), "w") as f:
        f.write(stand_in)
    # And with the bumpy sphere emitting, a light of a million triangles, for timing light
    # sampling (no Mitsuba counterpart).
    glow = box.replace("around a bumpy sphere of", "around an emitting bumpy sphere of")
    glow = glow.replace("[materials.light]", '[materials.glow]\ntype = "diffuse"\n'
                        'albedo = [0.5, 0.5, 0.5]\nemission = [1.0, 0.8, 0.6]\n\n[materials.light]')
    glow = glow.replace('file = "bumpy-sphere.ply"\nmaterial = "white"',
                        'file = "bumpy-sphere.ply"\nmaterial = "glow"')
    assert glow.count('"glow"') == 1, "the sphere's material was not replaced"
    with open(os.path.join(out, "mesh-million-emissive.toml"), "w") as f:
        f.write(glow)
    print(f"{len(tris)} triangles -> {out}")


main(sys.argv[1])
