"""Writes four sky-lit scenes that are not among the bundled ones, for checking a rule that
decides the default tracer (the lanes or one path at a time) on scenes it was not developed
on: that it gains where the lanes win and costs nothing where they lose (docs/renderer.md,
"The tracer measured on the scene", where a measured choice failed that check):

    target/bench-cache/probe/v1-metal-balls.toml   envmap-balls with its three balls metals
                                                   (copper, gold, aluminium)
    target/bench-cache/probe/v2-spheres-rect.toml  spheres.toml, its infinite plane a 40 x 40
                                                   rectangle (so one BVH leaf)
    target/bench-cache/probe/v3-point-pbr.toml     envmap-balls with a small pbr metal ball and
                                                   a point light added
    target/bench-cache/probe/v4-metals-rect.toml   metals.toml, its plane a rectangle likewise

Standard library only. Run from the repository root:

    python3 bench/make_probe_scenes.py
"""
import os
import shutil

OUT = "target/bench-cache/probe"
RECT = ('shape = "rect"\nmaterial = "%s"\n'
        'transform.matrix = [[20, 0, 0, 0], [0, 0, 20, 0], [0, -20, 0, 0], [0, 0, 0, 1]]\n')
PLANE = 'shape = "plane"\nmaterial = "%s"\npoint = [0.0, 0.0, 0.0]\nnormal = [0.0, 1.0, 0.0]\n'


def read(name):
    with open(os.path.join("scenes", name)) as f:
        return f.read()


def swap(text, old, new):
    if old not in text:
        raise SystemExit(f"the bundled scene changed: {old!r} not found")
    return text.replace(old, new)


def main():
    os.makedirs(os.path.join(OUT, "textures"), exist_ok=True)
    shutil.copy("scenes/textures/sky.exr", os.path.join(OUT, "textures", "sky.exr"))
    balls = read("envmap-balls.toml")
    v1 = swap(balls, 'type = "plastic"\nalbedo = [0.7, 0.15, 0.1]\nior = 1.5',
              'type = "conductor"\nmetal = "copper"\nroughness = 0.1')
    v1 = swap(v1, 'type = "dielectric"\nior = 1.5\nroughness = 0.3',
              'type = "conductor"\nmetal = "aluminium"\nroughness = 0.05')
    v3 = balls + """
[materials.pbr1]
type = "pbr"
base_color = [0.8, 0.8, 0.8]
metallic = 1.0
roughness = 0.2

[[objects]]
shape = "sphere"
material = "pbr1"
center = [0.5, -0.75, 1.0]
radius = 0.25

[[lights]]
type = "point"
position = [1.5, 1.5, 2.0]
intensity = [6.0, 6.0, 6.0]
"""
    scenes = {
        "v1-metal-balls.toml": v1,
        "v2-spheres-rect.toml": swap(read("spheres.toml"), PLANE % "ground", RECT % "ground"),
        "v3-point-pbr.toml": v3,
        "v4-metals-rect.toml": swap(read("metals.toml"), PLANE % "floor", RECT % "floor"),
    }
    for name, text in scenes.items():
        path = os.path.join(OUT, name)
        with open(path, "w") as f:
            f.write(text)
        print(path)


if __name__ == "__main__":
    main()
