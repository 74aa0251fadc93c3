"""Three scenes built in Blender, for measuring tessera against Cycles (bench/cycles-vs-tessera.sh).

Run with Blender as a Python module (PyPI's bpy, target/blender-venv):

    python blender_scenes.py -- OUT_DIR

For each scene it saves OUT_DIR/NAME.blend (what Cycles renders, with the settings below) and
exports it with the tessera add-on's exporter (blender/tessera/export.py, as "Render on
tessera" does) to OUT_DIR/NAME/NAME.toml, which places OUT_DIR/NAME/NAME.0001.glb:

- blender-interior: a room of diffuse walls (Principled BSDFs with Specular IOR Level 0, one
  red, one green), a white box and a blue ball, lit by a rectangular area light under the
  ceiling, seen from just inside the open front with the light above and behind the view;
- blender-metals-glass: a rough gold ball, a mirror ball and a solid glass ball (Principled,
  transmission 1, exported with its thickness so that tessera refracts through a volume) on a
  grey floor under scenes/textures/sky.exr as the world, turned 30° by a Mapping node;
- blender-textured: a textured glTF asset as Blender makes one: a checker-textured floor, a
  ball with an image base colour and a normal-mapped, textured-roughness box, under a sun lamp
  and the same sky at a quarter strength.

Cycles is set as an unbiased path tracer, to compare with tessera's: CPU, no denoising, no
adaptive sampling, bounces up to 64, no clamping, no glossy filter, a one-pixel box filter,
the Standard view transform (EXR output is linear either way).
"""

import math
import os
import sys

import bpy

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.join(HERE, "..", "blender"))
from tessera import export as addon_export  # noqa: E402

# The Principled BSDF helper the units test builds its scenes with.
sys.path.insert(0, os.path.join(HERE, "..", "tests", "blender"))
from units import material  # noqa: E402

SIZE = (128, 128)
SKY_SIZE = (1024, 512)


def write_sky(path):
    """A 1024×512 equirectangular sky as a Radiance HDR file (which Blender and tessera both
    read as written; Blender's EXR writer applies its view transform): blue brightening towards
    the horizon, a brown ground, and a sun disc 2° in radius 35° up. Fine enough that Blender's
    and tessera's different texel placement (docs/blender.md) moves nothing measurable."""
    import numpy as np

    w, h = SKY_SIZE
    theta = (np.arange(h) + 0.5) / h * np.pi
    phi = (np.arange(w) + 0.5) / w * 2 * np.pi
    th, ph = np.meshgrid(theta, phi, indexing="ij")
    up = th < np.pi / 2
    t = np.clip(th / (np.pi / 2), 0, 1)[..., None]
    rgb = np.where(up[..., None], np.array([0.25, 0.45, 0.9]) * (0.5 + 0.9 * t * t), np.array([0.22, 0.17, 0.12]))
    d = np.stack([np.sin(th) * np.cos(ph), np.cos(th), np.sin(th) * np.sin(ph)], -1)
    sun = np.array([np.cos(np.radians(35)) * np.cos(1.0), np.sin(np.radians(35)), np.cos(np.radians(35)) * np.sin(1.0)])
    rgb = np.where((d @ sun > np.cos(np.radians(2.0)))[..., None], np.array([60.0, 52.0, 40.0]), rgb)
    m = rgb.max(-1)
    mant, exp = np.frexp(m)
    scale = np.where(m > 1e-32, mant * 256.0 / np.maximum(m, 1e-32), 0.0)
    rgbe = np.zeros((h, w, 4), dtype=np.uint8)
    rgbe[..., :3] = np.clip(rgb * scale[..., None], 0, 255).astype(np.uint8)
    rgbe[..., 3] = np.where(m > 1e-32, exp + 128, 0).astype(np.uint8)
    # A flat scanline must not open as a run-length one does (2, 2, then a width byte).
    assert not np.any((rgbe[:, 0, 0] == 2) & (rgbe[:, 0, 1] == 2)), "a scanline reads as RLE"
    with open(path, "wb") as f:
        f.write(f"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n-Y {h} +X {w}\n".encode())
        f.write(rgbe.tobytes())


def setup():
    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene
    scene.render.engine = "CYCLES"
    c = scene.cycles
    c.device = "CPU"
    c.use_denoising = False
    c.use_adaptive_sampling = False
    c.max_bounces = c.diffuse_bounces = c.glossy_bounces = c.transmission_bounces = 64
    c.transparent_max_bounces = 64
    c.sample_clamp_direct = c.sample_clamp_indirect = 0.0
    c.blur_glossy = 0.0
    c.pixel_filter_type = "BOX"
    c.filter_width = 1.0
    scene.render.resolution_x, scene.render.resolution_y = SIZE
    scene.render.resolution_percentage = 100
    scene.render.use_persistent_data = True
    scene.render.image_settings.file_format = "OPEN_EXR"
    scene.render.image_settings.color_depth = "32"
    scene.view_settings.view_transform = "Standard"
    scene.world = bpy.data.worlds.new("world")
    scene.world.use_nodes = True
    scene.world.node_tree.nodes["Background"].inputs["Strength"].default_value = 0.0
    return scene


def diffuse(name, rgb):
    return material(name, **{"Base Color": (*rgb, 1), "Roughness": 1.0, "Specular IOR Level": 0.0})


def place(op, m, smooth=False, **kw):
    op(**kw)
    obj = bpy.context.object
    if smooth:
        bpy.ops.object.shade_smooth()
    obj.data.materials.append(m)
    return obj


def camera(scene, location, rotation_deg, lens=35):
    data = bpy.data.cameras.new("camera")
    data.lens = lens
    obj = bpy.data.objects.new("camera", data)
    obj.location = location
    obj.rotation_euler = tuple(math.radians(a) for a in rotation_deg)
    scene.collection.objects.link(obj)
    scene.camera = obj


def sky_world(scene, strength, turn_deg):
    tree = scene.world.node_tree
    env = tree.nodes.new("ShaderNodeTexEnvironment")
    path = os.path.join(OUT, "sky.hdr")
    if not os.path.exists(path):
        write_sky(path)
    env.image = bpy.data.images.load(path)
    mapping = tree.nodes.new("ShaderNodeMapping")
    mapping.inputs["Rotation"].default_value = (0, 0, math.radians(turn_deg))
    tree.links.new(tree.nodes.new("ShaderNodeTexCoord").outputs["Generated"], mapping.inputs["Vector"])
    tree.links.new(mapping.outputs["Vector"], env.inputs["Vector"])
    tree.links.new(env.outputs["Color"], tree.nodes["Background"].inputs["Color"])
    tree.nodes["Background"].inputs["Strength"].default_value = strength


def interior(scene):
    white, red, green = diffuse("white", (0.8, 0.8, 0.8)), diffuse("red", (0.7, 0.1, 0.1)), diffuse("green", (0.1, 0.6, 0.1))
    # The room: x in [-2, 2], y in [-3, 2], z in [0, 4], open at y = -3.
    walls = [
        ((0, -0.5, 0), (0, 0, 0), (4, 5), white),
        ((0, -0.5, 4), (180, 0, 0), (4, 5), white),
        ((0, 2, 2), (90, 0, 0), (4, 4), white),
        ((-2, -0.5, 2), (0, 90, 0), (4, 5), red),
        ((2, -0.5, 2), (0, -90, 0), (4, 5), green),
    ]
    for location, rotation, (sx, sy), m in walls:
        bpy.ops.mesh.primitive_plane_add(size=1, location=location, rotation=tuple(math.radians(a) for a in rotation))
        obj = bpy.context.object
        obj.scale = (sx, sy, 1)
        obj.data.materials.append(m)
    place(bpy.ops.mesh.primitive_cube_add, white, size=1.2, location=(0.7, 0.6, 0.6), rotation=(0, 0, math.radians(20)))
    place(bpy.ops.mesh.primitive_uv_sphere_add, diffuse("blue", (0.1, 0.2, 0.7)), smooth=True,
          radius=0.6, location=(-0.8, -0.6, 0.6), segments=48, ring_count=24)
    data = bpy.data.lights.new("panel", type="AREA")
    data.shape, data.size, data.size_y, data.energy = "RECTANGLE", 1.0, 0.6, 120.0
    light = bpy.data.objects.new("panel", data)
    light.location = (0, -2.3, 3.95)
    scene.collection.objects.link(light)
    # Inside the open front, under the light: the light is out of view (Cycles does not show an
    # area light to the camera; tessera's emitting rectangle would be seen).
    camera(scene, (0, -2.9, 2), (90, 0, 0), lens=24)


def glass(name):
    """A solid glass Principled BSDF, with the glTF Material Output's thickness that makes the
    exporter write KHR_materials_volume (else glTF's glass is a thin sheet)."""
    m = material(name, **{"Base Color": (1, 1, 1, 1), "Roughness": 0.0, "Transmission Weight": 1.0, "IOR": 1.5})
    group = bpy.data.node_groups.get("glTF Material Output")
    if group is None:
        group = bpy.data.node_groups.new("glTF Material Output", "ShaderNodeTree")
        group.interface.new_socket("Thickness", in_out="INPUT", socket_type="NodeSocketFloat")
    node = m.node_tree.nodes.new("ShaderNodeGroup")
    node.node_tree = group
    node.inputs["Thickness"].default_value = 1.0
    return m


def metals_glass(scene):
    place(bpy.ops.mesh.primitive_plane_add, diffuse("floor", (0.5, 0.5, 0.5)), size=8)
    gold = material("gold", **{"Base Color": (1.0, 0.77, 0.34, 1), "Metallic": 1.0, "Roughness": 0.3})
    mirror = material("mirror", **{"Base Color": (0.95, 0.95, 0.95, 1), "Metallic": 1.0, "Roughness": 0.0})
    for m, x in ((gold, -1.2), (mirror, 0.0), (glass("glass"), 1.2)):
        place(bpy.ops.mesh.primitive_uv_sphere_add, m, smooth=True, radius=0.5, location=(x, 0, 0.5),
              segments=64, ring_count=32)
    sky_world(scene, 1.0, 30)
    camera(scene, (0, -4.5, 1.6), (75, 0, 0), lens=40)


def texture(name, w, h, pixel):
    """An sRGB PNG of w×h whose texels are `pixel(i, j)` (NumPy arrays of column and row, from
    the bottom), read back from its file."""
    import numpy as np

    j, i = np.meshgrid(np.arange(h), np.arange(w), indexing="ij")
    rgba = np.ones((h, w, 4), dtype=np.float32)
    rgba[..., :3] = np.stack(np.broadcast_arrays(*pixel(i, j)), -1)
    image = bpy.data.images.new(name, w, h)
    image.pixels.foreach_set(rgba.ravel())
    path = os.path.join(OUT, name + ".png")
    image.filepath_raw = path
    image.file_format = "PNG"
    image.save()
    return bpy.data.images.load(path)


def textured_material(name, image, roughness_image=None, normal_image=None, **inputs):
    m = material(name, **inputs)
    tree = m.node_tree
    p = tree.nodes["Principled BSDF"]
    tex = tree.nodes.new("ShaderNodeTexImage")
    tex.image = image
    tree.links.new(tex.outputs["Color"], p.inputs["Base Color"])
    if roughness_image is not None:
        rough = tree.nodes.new("ShaderNodeTexImage")
        rough.image = roughness_image
        rough.image.colorspace_settings.name = "Non-Color"
        tree.links.new(rough.outputs["Color"], p.inputs["Roughness"])
    if normal_image is not None:
        nt = tree.nodes.new("ShaderNodeTexImage")
        nt.image = normal_image
        nt.image.colorspace_settings.name = "Non-Color"
        nm = tree.nodes.new("ShaderNodeNormalMap")
        tree.links.new(nt.outputs["Color"], nm.inputs["Color"])
        tree.links.new(nm.outputs["Normal"], p.inputs["Normal"])
    return m


def textured(scene):
    # 512-texel textures, as an asset's are (1k–4k): Cycles filters 8-bit sRGB texels before
    # decoding them, tessera after (glTF's rule), which only the texels' blend zones show.
    import numpy as np

    def two(mask, a, b):
        return tuple(np.where(mask, x, y) for x, y in zip(a, b))

    checker = texture("checker", 512, 512, lambda i, j: two((i // 64 + j // 64) % 2 == 1, (0.8, 0.8, 0.8), (0.15, 0.2, 0.3)))
    stripes = texture("stripes", 512, 256, lambda i, j: two((i // 32) % 2 == 1, (0.9, 0.4, 0.1), (0.2, 0.6, 0.9)))
    rough = texture("roughness", 256, 256, lambda i, j: (0.2 + 0.6 * i / 255,) * 3)
    bumps = texture("bumps", 256, 256, lambda i, j: (0.5 + 0.3 * np.sin(i / 16.0), 0.5 + 0 * i, 1.0 + 0 * i))
    place(bpy.ops.mesh.primitive_plane_add, textured_material("floor", checker, **{"Roughness": 1.0, "Specular IOR Level": 0.0}), size=6)
    place(bpy.ops.mesh.primitive_uv_sphere_add, textured_material("ball", stripes, **{"Roughness": 0.4}),
          smooth=True, radius=0.6, location=(-0.8, 0, 0.6), segments=64, ring_count=32)
    place(bpy.ops.mesh.primitive_cube_add, textured_material("box", checker, rough, bumps, **{"Metallic": 0.0}),
          size=1.0, location=(0.8, 0.3, 0.5), rotation=(0, 0, math.radians(30)))
    sun = bpy.data.lights.new("sun", type="SUN")
    # glTF's directional light has no disc: a sun of angle 0 is the same light in both.
    sun.energy, sun.angle = 3.0, 0.0
    obj = bpy.data.objects.new("sun", sun)
    obj.rotation_euler = (math.radians(40), 0, math.radians(30))
    scene.collection.objects.link(obj)
    sky_world(scene, 0.25, 0)
    camera(scene, (0, -4, 2), (65, 0, 0), lens=40)


SCENES = {"blender-interior": interior, "blender-metals-glass": metals_glass, "blender-textured": textured}


def main():
    global OUT
    OUT = os.path.abspath(sys.argv[-1])
    os.makedirs(OUT, exist_ok=True)
    for name, build in SCENES.items():
        scene = setup()
        build(scene)
        bpy.ops.wm.save_as_mainfile(filepath=os.path.join(OUT, name + ".blend"))
        folder = os.path.join(OUT, name)
        frames = addon_export.export(scene, folder, name, [scene.frame_current], None)
        os.replace(os.path.join(folder, frames[0].scene_file), os.path.join(folder, name + ".toml"))
        print(f"{name}: {folder}/{name}.toml")


OUT = ""
main()
