"""The open scene as tessera scene files: for each frame, a glTF binary written by Blender's own
exporter and a TOML scene that places it, frames the film as Blender's output does, and lights
it with the world (docs/blender.md says what is carried over and how).

Everything a frame names lies in one folder, so `tessera render FOLDER/NAME.0001.toml` renders
the frame the farm renders, bit for bit.
"""

import json
import math
import os
import shutil
import struct

import bpy

# Environment images tessera reads (docs/scene-format.md, [environment]).
MAP_EXTENSIONS = (".exr", ".hdr", ".png", ".jpg", ".jpeg")


class ExportError(Exception):
    """Something in the scene tessera cannot carry over, said so an artist can change it."""


class Frame:
    """One exported frame: its TOML scene's file name and every file it names."""

    def __init__(self, number, scene_file, files):
        self.number = number
        self.scene_file = scene_file
        self.files = files


def export(scene, folder, stem, frames, denoise):
    """Writes `frames` of `scene` into `folder` as STEM.####.glb and STEM.####.toml; the
    frames, in order. The world's image, if any, is written once and named by every frame."""
    os.makedirs(folder, exist_ok=True)
    environment, env_files = world_environment(scene, folder)
    film = film_size(scene)
    camera = scene.camera
    if camera is None:
        raise ExportError("the scene has no active camera: tessera renders from the scene's camera")
    kept = scene.frame_current
    out = []
    try:
        for number in frames:
            scene.frame_set(number)
            base = f"{stem}.{number:04d}"
            glb = base + ".glb"
            export_gltf(os.path.join(folder, glb))
            index = camera_index(os.path.join(folder, glb), camera)
            lights, light_files = area_lights(scene, folder)
            text = scene_toml(glb, index, film, denoise, environment, lights)
            with open(os.path.join(folder, base + ".toml"), "w", encoding="utf-8") as f:
                f.write(text)
            out.append(Frame(number, base + ".toml", [glb] + env_files + light_files))
    finally:
        scene.frame_set(kept)
    return out


def export_gltf(path):
    """Blender's glTF exporter as tessera reads its output: cameras and lights in the file's
    photometric units (the exporter's default), modifiers applied, only what renders."""
    result = bpy.ops.export_scene.gltf(
        filepath=path,
        export_format="GLB",
        use_active_scene=True,
        use_renderable=True,
        export_apply=True,
        export_cameras=True,
        export_lights=True,
        export_animations=False,
        export_extras=False,
    )
    if "FINISHED" not in result:
        raise ExportError(f"Blender's glTF exporter did not finish writing {path}")


def camera_index(glb_path, camera):
    """The index in the file's `cameras` of the scene camera's own, so that tessera renders
    through the camera Blender would, whichever the exporter wrote first."""
    with open(glb_path, "rb") as f:
        head = f.read(20)
        length = struct.unpack_from("<I", head, 12)[0]
        doc = json.loads(f.read(length))
    nodes = doc.get("nodes", [])
    for node in nodes:
        if node.get("name") == camera.name and "camera" in node:
            return node["camera"]
    # The exporter names a camera's node after the object; a node with its child camera
    # (the exporter's Y-up correction) carries the camera on the child.
    for node in nodes:
        if node.get("name") == camera.name:
            for child in node.get("children", []):
                if "camera" in nodes[child]:
                    return nodes[child]["camera"]
    raise ExportError(f"the exported glTF file has no camera for the scene camera {camera.name!r}")


def film_size(scene):
    """Blender's output size: the resolution times its percentage, as Cycles renders it."""
    r = scene.render
    scale = r.resolution_percentage / 100.0
    return max(1, int(r.resolution_x * scale)), max(1, int(r.resolution_y * scale))


def world_environment(scene, folder):
    """The `[environment]` table for the scene's world, and the files it names.

    A world is a colour, or an Environment Texture (optionally through a Mapping node turning
    it about Blender's up axis), times the Background's strength. Anything else is refused
    rather than rendered differently from Cycles."""
    world = scene.world
    if world is None:
        return None, []
    if not world.use_nodes or world.node_tree is None:
        return constant(world.color, 1.0), []
    background = background_node(world)
    if background is None:
        return None, []
    strength_input = background.inputs["Strength"]
    if strength_input.is_linked:
        raise ExportError("the world's Background strength is driven by nodes: tessera reads a number there")
    strength = float(strength_input.default_value)
    color = background.inputs["Color"]
    if not color.is_linked:
        return constant(color.default_value, strength), []
    node = color.links[0].from_node
    if node.bl_idname != "ShaderNodeTexEnvironment":
        raise ExportError(
            f"the world's colour comes from a {node.name!r} node: tessera reads a colour or an "
            "Environment Texture (bake anything else to an equirectangular image)"
        )
    if node.projection != "EQUIRECTANGULAR":
        raise ExportError("the world's Environment Texture uses a mirror-ball projection: tessera reads equirectangular maps")
    if node.image is None:
        raise ExportError("the world's Environment Texture has no image")
    if strength <= 0.0:
        return None, []
    name = write_world_image(node.image, folder)
    degrees = 90.0 - mapping_turn(node)
    table = (
        "[environment]\n"
        'type = "map"\n'
        f"file = {json.dumps(name)}\n"
        f"intensity = {strength!r}\n"
        f"rotate = {degrees!r}\n"
    )
    return table, [name]


def background_node(world):
    """The Background node the World Output's surface draws from, if any."""
    outputs = [n for n in world.node_tree.nodes if n.bl_idname == "ShaderNodeOutputWorld"]
    active = [n for n in outputs if n.is_active_output] or outputs
    if not active or not active[0].inputs["Surface"].is_linked:
        return None
    node = active[0].inputs["Surface"].links[0].from_node
    if node.bl_idname != "ShaderNodeBackground":
        raise ExportError(
            f"the world's surface is a {node.name!r} node: tessera reads a Background node"
        )
    return node


def mapping_turn(texture):
    """Degrees a Mapping node before the Environment Texture turns it about Blender's up (Z)
    axis; other turns, scales and non-point mappings are refused."""
    vector = texture.inputs["Vector"]
    if not vector.is_linked:
        return 0.0
    node = vector.links[0].from_node
    if node.bl_idname != "ShaderNodeMapping" or node.vector_type not in ("POINT", "TEXTURE"):
        raise ExportError(
            "the world's Environment Texture is placed by nodes other than one Mapping node: "
            "tessera turns a world map about the up axis only"
        )
    rot = node.inputs["Rotation"].default_value
    scale = node.inputs["Scale"].default_value
    if abs(rot[0]) > 1e-6 or abs(rot[1]) > 1e-6 or any(abs(s - 1.0) > 1e-6 for s in scale):
        raise ExportError(
            "the world's Mapping node tilts or scales the map: tessera turns a world map about "
            "the up (Z) axis only"
        )
    turn = math.degrees(rot[2])
    # A Texture mapping is the inverse of a Point one.
    return turn if node.vector_type == "POINT" else -turn


def write_world_image(image, folder):
    """The world's image file copied into `folder` (a packed one written out); its file name
    there. An image that lives only in Blender (generated, or edited and not saved) is refused:
    tessera renders files, and Blender writes such images with its view transform applied."""
    source = bpy.path.abspath(image.filepath) if image.filepath else ""
    ext = os.path.splitext(source)[1].lower()
    if image.source != "FILE" or image.is_dirty:
        raise ExportError(
            f"the world's image {image.name!r} has changes that are not in a file: save it "
            "(Image > Save As) as OpenEXR or Radiance HDR"
        )
    if ext not in MAP_EXTENSIONS:
        raise ExportError(
            f"the world's image {image.name!r} is a {ext or 'nameless'} file: tessera reads "
            "environment maps from .exr, .hdr, .png and .jpg files"
        )
    name = "world" + (".jpg" if ext == ".jpeg" else ext)
    target = os.path.join(folder, name)
    if image.packed_file is not None:
        with open(target, "wb") as f:
            f.write(image.packed_file.data)
    elif os.path.isfile(source):
        shutil.copyfile(source, target)
    else:
        raise ExportError(f"the world's image {image.name!r} cannot be read from {source}")
    return name


def constant(rgb, strength):
    """A constant environment of `rgb` × `strength`, or none when that is black."""
    radiance = [float(c) * strength for c in rgb[:3]]
    if max(radiance) <= 0.0:
        return None
    return f'[environment]\ntype = "constant"\nradiance = [{", ".join(repr(c) for c in radiance)}]\n'


def scene_toml(glb, camera, film, denoise, environment, lights):
    """The TOML scene that renders `glb` as Blender frames it."""
    parts = [
        "# Written by the tessera Blender add-on: one frame of a Blender scene.\n",
        "version = 1\n",
        f'\n[camera]\nmodel = "gltf"\nindex = {camera}\n',
        f"\n[film]\nwidth = {film[0]}\nheight = {film[1]}\n",
    ]
    if denoise:
        parts.append(f'\n[render]\ndenoise = {{ quality = "{denoise}" }}\n')
    if environment:
        parts.append("\n" + environment)
    parts.append(f'\n[[objects]]\nshape = "gltf"\nfile = {json.dumps(glb)}\n')
    parts.append(lights)
    return "".join(parts)


# Blender's axes to glTF's (and tessera's): Z up becomes Y up, as the glTF exporter turns them.
Y_UP = ((1.0, 0.0, 0.0), (0.0, 0.0, 1.0), (0.0, -1.0, 0.0))
# Segments of the polygon that stands for a disk or ellipse light.
DISK_SEGMENTS = 64


def area_lights(scene, folder):
    """Blender's area lights, which glTF cannot carry, as emitting shapes of the TOML scene:
    the TOML text (materials and objects), and the files it names.

    A light of power P W and colour c over area A (its shape's, scaled by the object) emits
    radiance c·P/(π·A) from its front (the light's −Z), as Cycles' area lights do; its back is
    black and, unlike a Cycles light, the shape blocks what lies behind it."""
    text, files = [], []
    for obj in sorted(scene.objects, key=lambda o: o.name):
        if obj.type != "LIGHT" or obj.data.type != "AREA" or obj.hide_render:
            continue
        light = obj.data
        if getattr(light, "spread", math.pi) < math.pi - 1e-4:
            raise ExportError(
                f"the area light {obj.name!r} has a spread under 180°: tessera's area lights "
                "emit over the whole hemisphere"
            )
        w = light.size
        h = light.size_y if light.shape in ("RECTANGLE", "ELLIPSE") else light.size
        m = to_y_up(obj.matrix_world)
        u = [m[r][0] * w for r in range(3)]
        v = [m[r][1] * h for r in range(3)]
        area = norm(cross(u, v))
        disk = light.shape in ("DISK", "ELLIPSE")
        if disk:
            area *= DISK_SEGMENTS / 2 * math.sin(2 * math.pi / DISK_SEGMENTS) / 4
        if area <= 0.0 or light.energy <= 0.0:
            continue
        radiance = [float(c) * light.energy / (math.pi * area) for c in light.color]
        name = "blender_light_" + str(len(text))
        # The light's front is its −Z: turned half a turn about X, tessera's +Z-facing shape; a
        # disk's unit mesh is also scaled to the light's half-sizes.
        sx, sy = (w / 2, h / 2) if disk else (1.0, 1.0)
        rows = [[m[r][0] * sx, -m[r][1] * sy, -m[r][2], m[r][3]] for r in range(3)]
        if disk:
            shape = 'shape = "mesh"\nfile = "disk.obj"\n'
            if "disk.obj" not in files:
                write_disk(os.path.join(folder, "disk.obj"))
                files.append("disk.obj")
        else:
            shape = f'shape = "rect"\nsize = [{w!r}, {h!r}]\n'
        matrix = ", ".join("[" + ", ".join(repr(float(x)) for x in row) + "]" for row in rows)
        text.append(
            f'\n[materials.{name}]\ntype = "diffuse"\nalbedo = [0, 0, 0]\n'
            f"emission = [{', '.join(repr(c) for c in radiance)}]\n"
            f"\n[[objects]]\n{shape}material = \"{name}\"\n"
            f"transform.matrix = [{matrix}, [0, 0, 0, 1]]\n"
        )
    return "".join(text), files


def to_y_up(matrix):
    """A Blender world matrix (rows) in glTF's axes."""
    rows = [list(matrix[r]) for r in range(4)]
    return [[sum(Y_UP[i][k] * rows[k][j] for k in range(3)) for j in range(4)] for i in range(3)]


def write_disk(path):
    """A unit disk in the z = 0 plane facing +z, as a fan of triangles (an OBJ file)."""
    n = DISK_SEGMENTS
    lines = ["v 0 0 0"]
    lines += [f"v {math.cos(2 * math.pi * i / n)!r} {math.sin(2 * math.pi * i / n)!r} 0" for i in range(n)]
    lines += [f"f 1 {2 + i} {2 + (i + 1) % n}" for i in range(n)]
    with open(path, "w", encoding="utf-8") as f:
        f.write("\n".join(lines) + "\n")


def cross(a, b):
    return [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]


def norm(a):
    return math.sqrt(sum(x * x for x in a))
