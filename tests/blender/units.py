"""Blender scenes that pin tessera's glTF light and emission units against Cycles.

Run by tests/blender/run.sh with Blender as a Python module (PyPI's `bpy`):

    python units.py -- OUT_DIR

For each light kind (a point light, a spot with a hard edge and one with a soft blend, a sun,
and an emissive quad), for three Principled BSDFs with a glossy layer (Blender's default
material, a rough blue one, and a rough gold metal) and two under a Coat under a sun, for a closed box of such
materials with every bounce counted, for a camera whose clip start cuts away a wall before it and one whose clip end cuts away the
far floor, for a rectangular and a disk area light and a floor under a world map turned by a Mapping node
(which glTF cannot carry: these go through the add-on's exporter, blender/tessera/export.py, to
OUT_DIR/KIND.0001.toml placing OUT_DIR/KIND.0001.glb), and for a portrait and a landscape film (Blender's sensor fit, which its
exporter turns into glTF's yfov and aspect ratio), it builds the same small scene: a white diffuse floor (a Principled BSDF
with Specular IOR Level 0, which Blender exports as KHR_materials_specular's factor 0) under
that light, seen from above. It exports the scene with Blender's own glTF exporter (its
default, photometric lighting mode) to OUT_DIR/KIND.glb and renders it with Cycles to
OUT_DIR/KIND-cycles.exr: one bounce, no denoising, a one-pixel box filter (tessera's); the
film's size goes to OUT_DIR/KIND.size ("WxH") for tessera to render at.
"""

import math
import os
import sys

import bpy

# The add-on's exporter, for what glTF cannot carry (area lights, the world).
sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "blender"))
from tessera import export as addon_export  # noqa: E402

SIZE = 64
SAMPLES = 256


def setup(size):
    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene
    scene.render.engine = "CYCLES"
    scene.cycles.device = "CPU"
    scene.cycles.samples = SAMPLES
    scene.cycles.use_denoising = False
    scene.cycles.use_adaptive_sampling = False
    scene.cycles.max_bounces = 1
    scene.cycles.pixel_filter_type = "BOX"
    scene.cycles.filter_width = 1.0
    scene.render.resolution_x, scene.render.resolution_y = size
    scene.render.image_settings.file_format = "OPEN_EXR"
    scene.render.image_settings.color_depth = "32"
    scene.view_settings.view_transform = "Standard"
    floor = bpy.data.materials.new("floor")
    floor.use_nodes = True
    p = floor.node_tree.nodes["Principled BSDF"]
    p.inputs["Base Color"].default_value = (0.8, 0.8, 0.8, 1)
    p.inputs["Roughness"].default_value = 1.0
    p.inputs["Specular IOR Level"].default_value = 0.0
    bpy.ops.mesh.primitive_plane_add(size=4, location=(0, 0, 0))
    bpy.context.object.data.materials.append(floor)
    cam = bpy.data.cameras.new("camera")
    cam.lens = 35
    co = bpy.data.objects.new("camera", cam)
    co.location = (0, -3, 3)
    co.rotation_euler = (math.radians(45), 0, 0)
    scene.collection.objects.link(co)
    scene.camera = co
    scene.world = bpy.data.worlds.new("world")
    scene.world.use_nodes = True
    scene.world.node_tree.nodes["Background"].inputs["Strength"].default_value = 0.0
    return scene


def light(scene, kind, energy, **settings):
    data = bpy.data.lights.new(kind.lower(), type=kind)
    data.energy = energy
    for k, v in settings.items():
        setattr(data, k, v)
    obj = bpy.data.objects.new(kind.lower(), data)
    obj.location = (0, 0, 2)
    scene.collection.objects.link(obj)
    return obj


def emitter(scene):
    glow = bpy.data.materials.new("glow")
    glow.use_nodes = True
    p = glow.node_tree.nodes["Principled BSDF"]
    p.inputs["Base Color"].default_value = (0, 0, 0, 1)
    p.inputs["Specular IOR Level"].default_value = 0.0
    p.inputs["Emission Color"].default_value = (1.0, 0.9, 0.7, 1)
    p.inputs["Emission Strength"].default_value = 5.0
    # A quad at 1.5 facing down at the floor.
    bpy.ops.mesh.primitive_plane_add(size=1, location=(0, 0, 1.5), rotation=(math.pi, 0, 0))
    bpy.context.object.data.materials.append(glow)


def point(scene):
    light(scene, "POINT", 1000.0, shadow_soft_size=0.0)


def principled(**inputs):
    """The floor's material replaced by a Principled BSDF with Blender's defaults (roughness
    0.5, Specular IOR Level 0.5, IOR 1.5) but `inputs`, under a sun: its glossy layer and the
    albedo-scaled base under it, as Cycles' multiscatter GGX renders them."""
    def build(scene):
        m = bpy.data.materials["floor"]
        p = m.node_tree.nodes["Principled BSDF"]
        p.inputs["Specular IOR Level"].default_value = 0.5
        p.inputs["Roughness"].default_value = 0.5
        for k, v in inputs.items():
            p.inputs[k].default_value = v
        sun = light(scene, "SUN", 3.0, angle=0.0)
        sun.rotation_euler[0] = math.radians(-30)
    return build


def material(name, **inputs):
    """A Principled BSDF with Blender's defaults but `inputs`."""
    m = bpy.data.materials.new(name)
    m.use_nodes = True
    p = m.node_tree.nodes["Principled BSDF"]
    for k, v in inputs.items():
        p.inputs[k].default_value = v
    return m


def box(scene):
    """The issue's box: walls of Blender's default material (two of them coloured), an
    emissive panel under the ceiling, a rough gold ball and a blue one, seen from the open
    front, every bounce counted (Cycles' limits raised to 64, its glossy filter and clamps
    off; tessera's paths end by Russian roulette alone)."""
    c = scene.cycles
    c.max_bounces = c.diffuse_bounces = c.glossy_bounces = c.transmission_bounces = 64
    c.blur_glossy = 0.0
    c.sample_clamp_direct = c.sample_clamp_indirect = 0.0
    floor = bpy.data.materials["floor"].node_tree.nodes["Principled BSDF"]
    floor.inputs["Specular IOR Level"].default_value = 0.5
    floor.inputs["Roughness"].default_value = 0.5
    walls = [
        ((0, 2, 2), (math.radians(90), 0, 0), material("back", **{"Base Color": (0.8, 0.8, 0.8, 1)})),
        ((-2, 0, 2), (0, math.radians(90), 0), material("red", **{"Base Color": (0.8, 0.1, 0.1, 1)})),
        ((2, 0, 2), (0, math.radians(90), 0), material("green", **{"Base Color": (0.1, 0.8, 0.1, 1)})),
        ((0, 0, 4), (math.pi, 0, 0), material("ceiling", **{"Base Color": (0.8, 0.8, 0.8, 1)})),
    ]
    for location, rotation, m in walls:
        bpy.ops.mesh.primitive_plane_add(size=4, location=location, rotation=rotation)
        bpy.context.object.data.materials.append(m)
    glow = material("panel", **{"Base Color": (0, 0, 0, 1), "Specular IOR Level": 0.0,
                                "Emission Color": (1.0, 0.9, 0.8, 1), "Emission Strength": 10.0})
    bpy.ops.mesh.primitive_plane_add(size=1, location=(0, 0, 3.95), rotation=(math.pi, 0, 0))
    bpy.context.object.data.materials.append(glow)
    gold = material("gold", **{"Base Color": (0.95, 0.7, 0.3, 1), "Metallic": 1.0,
                               "Roughness": 0.4})
    blue = material("blue", **{"Base Color": (0.1, 0.2, 0.8, 1)})
    for location, radius, m in [((-0.8, 0.5, 0.7), 0.7, gold), ((0.9, -0.3, 0.6), 0.6, blue)]:
        bpy.ops.mesh.primitive_uv_sphere_add(radius=radius, location=location)
        bpy.ops.object.shade_smooth()
        bpy.context.object.data.materials.append(m)
    scene.camera.location = (0, -7, 2)
    scene.camera.rotation_euler = (math.radians(90), 0, 0)


def area(shape, **size):
    """An area light 2.5 above the floor (out of the camera's view: Cycles does not show a
    light's back, tessera's emitting shape would), turned 30° about the vertical."""
    def build(scene):
        obj = light(scene, "AREA", 300.0, shape=shape, **size)
        obj.location.z = 2.5
        obj.rotation_euler[2] = math.radians(30)
    return build


def clip(scene):
    """The point light's floor seen past a strip of wall just ahead of the camera, which hides
    the top of the frame unless the camera's clip start (1 m, exported as glTF's znear) cuts it
    away, as an interior is filmed from behind its wall."""
    point(scene)
    bpy.ops.mesh.primitive_plane_add(size=1, location=(0, -2.5, 2.8), rotation=(math.radians(90), 0, 0))
    wall = bpy.context.object
    wall.scale = (4, 1, 1)
    wall.data.materials.append(bpy.data.materials["floor"])
    scene.camera.data.clip_start = 1.0


def clip_far(scene):
    """The point light's floor with the camera's clip end (exported as glTF's zfar) cutting
    away its far half, where the (black) world shows instead."""
    point(scene)
    scene.camera.data.clip_end = 4.0


def world(scene):
    """The floor under an equirectangular sky turned 30° by a Mapping node, seen low enough
    that the sky fills the top of the frame: a turn the wrong way shows as the wrong part of
    the sky (its brightness varies by 5× around the horizon)."""
    scene.camera.location = (0, -3, 1)
    scene.camera.rotation_euler = (math.radians(80), 0, 0)
    w, h = 64, 32
    image = bpy.data.images.new("sky", w, h, float_buffer=True)
    pixels = []
    for j in range(h):
        for i in range(w):
            glow = (0.55 + 0.45 * math.sin(2 * math.pi * (i + 0.5) / w)) * (1 + 0.3 * j / h)
            pixels += [glow, 0.9 * glow, 0.7 * glow, 1.0]
    image.pixels = pixels
    image.filepath_raw = os.path.join(sys.argv[-1], "sky.exr")
    image.file_format = "OPEN_EXR"
    image.save()
    # Blender writes the file with its view transform applied: render the file, as tessera does.
    image = bpy.data.images.load(image.filepath_raw)
    tree = scene.world.node_tree
    env = tree.nodes.new("ShaderNodeTexEnvironment")
    env.image = image
    mapping = tree.nodes.new("ShaderNodeMapping")
    mapping.inputs["Rotation"].default_value = (0, 0, math.radians(30))
    tree.links.new(tree.nodes.new("ShaderNodeTexCoord").outputs["Generated"], mapping.inputs["Vector"])
    tree.links.new(mapping.outputs["Vector"], env.inputs["Vector"])
    tree.links.new(env.outputs["Color"], tree.nodes["Background"].inputs["Color"])
    tree.nodes["Background"].inputs["Strength"].default_value = 1.0


SCENES = {
    "point": point,
    "spot": lambda s: light(s, "SPOT", 1000.0, shadow_soft_size=0.0,
                            spot_size=math.radians(60), spot_blend=0.0),
    "spot-blend": lambda s: light(s, "SPOT", 1000.0, shadow_soft_size=0.0,
                                  spot_size=math.radians(60), spot_blend=0.5),
    "sun": lambda s: light(s, "SUN", 3.0, angle=0.0).rotation_euler.__setitem__(0, math.radians(30)),
    "emission": emitter,
    # Blender's default material on the floor, a rough blue one and a rough gold metal, seen
    # at 45° with the sun 30° past the zenith ahead of the camera: its glossy reflection comes
    # towards the camera, 15° off the mirror direction.
    "principled": principled(**{"Base Color": (0.8, 0.8, 0.8, 1)}),
    "principled-blue": principled(**{"Base Color": (0.1, 0.2, 0.8, 1), "Roughness": 0.8}),
    "principled-gold": principled(**{"Base Color": (0.95, 0.7, 0.3, 1), "Metallic": 1.0}),
    # A rough blue under Blender's Coat (exported as KHR_materials_clearcoat), and Blender's
    # default material under half a glossy one. (Blender's default Coat Roughness, 0.03, is
    # under tessera's mirror threshold: docs/blender.md.)
    "principled-coat": principled(**{"Base Color": (0.1, 0.2, 0.8, 1), "Roughness": 0.6,
                                     "Coat Weight": 1.0, "Coat Roughness": 0.3}),
    "principled-coat-glossy": principled(**{"Base Color": (0.8, 0.8, 0.8, 1), "Coat Weight": 0.5,
                                            "Coat Roughness": 0.1}),
    "box": box,
    "clip": clip,
    "clip-far": clip_far,
    # Through the add-on's exporter (a TOML scene placing the glTF file).
    "area": area("RECTANGLE", size=1.0, size_y=0.5),
    "area-disk": area("DISK", size=1.0),
    "world": world,
}
ADDON_SCENES = ("area", "area-disk", "world")


def main():
    out = sys.argv[-1]
    os.makedirs(out, exist_ok=True)
    films = {name: (SIZE, SIZE) for name in SCENES}
    films.update({"point-portrait": (48, 64), "point-landscape": (80, 48)})
    for name, size in films.items():
        scene = setup(size)
        SCENES.get(name, point)(scene)
        with open(os.path.join(out, name + ".size"), "w") as f:
            f.write(f"{size[0]}x{size[1]}")
        if name in ADDON_SCENES:
            addon_export.export(scene, out, name, [scene.frame_current], None)
        else:
            bpy.ops.export_scene.gltf(filepath=os.path.join(out, name + ".glb"),
                                      export_lights=True, export_cameras=True)
        scene.render.filepath = os.path.join(out, name + "-cycles.exr")
        bpy.ops.render.render(write_still=True)


if __name__ == "__main__":
    main()
