"""The Blender add-on against a real farm, headless: Blender as a Python module (PyPI's bpy).

Run by tests/blender/addon.sh, which starts a coordinator (with a token and --http) and a
worker, then:

    python addon.py -- ADDON.zip URL TOKEN OUT_DIR

It installs the add-on's zip as Blender installs an extension, builds a scene by script (a
floor, a cube that moves over frames 1-3, a rough gold sphere, an area light, and a world
that is an equirectangular EXR turned by a Mapping node), saves it as OUT_DIR/shot.blend,
and presses "Render on tessera" for the current frame and for the frame range 1-3. Blender's
timer does not run without an event loop, so the script calls the add-on's timer function
(`tick`) itself, as Blender would. It checks that every frame's EXR was saved and loaded as a
Blender image, that a denoised frame's
passes are what Blender's compositor lists (the add-on shows its denoised one), that the
frames of the range differ, and that the failures an artist meets (a wrong token, an address where no
coordinator listens, a world tessera cannot read) say so in words. OUT_DIR/frames.txt lists
"EXPORTED_TOML SAVED_EXR" per frame for the shell to render each export with `tessera render`
and compare the bytes.
"""

import importlib
import math
import os
import sys
import time

import bpy

ADDON = "bl_ext.user_default.tessera"
SAMPLES = 8


def main():
    zip_path, url, token, out = sys.argv[sys.argv.index("--") + 1 :]
    os.makedirs(out, exist_ok=True)
    bpy.ops.wm.read_factory_settings(use_empty=True)
    result = bpy.ops.extensions.package_install_files(
        filepath=zip_path, repo="user_default", enable_on_install=True
    )
    assert result == {"FINISHED"}, result
    addon = importlib.import_module(ADDON)
    prefs = bpy.context.preferences.addons[ADDON].preferences
    prefs.address, prefs.token = url, token

    build_scene(out)
    bpy.ops.wm.save_as_mainfile(filepath=os.path.join(out, "shot.blend"))
    scene = bpy.context.scene
    scene.tessera.samples = SAMPLES

    lines = []
    scene.frame_set(2)
    scene.tessera.frames = "CURRENT"
    scene.tessera.denoise = "fast"
    lines += render(addon, expect=[2], denoised=True)
    scene.tessera.frames = "RANGE"
    scene.tessera.denoise = "OFF"
    lines += render(addon, expect=[1, 2, 3], denoised=False)
    with open(os.path.join(out, "frames.txt"), "w") as f:
        f.write("".join(f"{toml} {exr}\n" for toml, exr in lines))

    check_failures(addon, prefs, url, token)
    check_reconnect(addon, out)
    print("addon: ok")


def render(addon, expect, denoised):
    """Presses the button, runs the timer until the submission ends, checks each frame."""
    before = len(addon.SUBMISSIONS)
    assert bpy.ops.tessera.render() == {"FINISHED"}
    assert len(addon.SUBMISSIONS) == before + 1
    s = addon.SUBMISSIONS[-1]
    run_timer(addon, s)
    assert not s.error, s.error
    assert [f.number for f in s.frames] == expect, [f.number for f in s.frames]
    out = []
    for f in s.frames:
        assert f.state == "done" and os.path.isfile(f.path), (f.number, f.state, f.error)
        name = os.path.basename(f.path)
        assert name == f"shot.{f.number:04d}.exr", name
        image = bpy.data.images.get(name)
        assert image is not None, name
        if denoised:
            check_layers(addon, image, f.path)
        else:
            assert image.size[0] == 40 and image.size[1] == 30, (name, image.size[:])
        export = os.path.join(s.folder, f"shot.{f.number:04d}.toml")
        out.append((export, f.path))
    print(f"addon: frames {expect} rendered: {s.summary()}")
    return out


def check_layers(addon, image, path):
    """A denoised frame is a multilayer image to Blender; the passes the add-on computes from
    the file's header (to show the denoised one) are those Blender's compositor offers."""
    len(image.pixels)  # loads it
    assert image.type == "MULTILAYER", image.type
    bpy.context.scene.use_nodes = True
    node = bpy.context.scene.node_tree.nodes.new("CompositorNodeImage")
    node.image = image
    blender = [o.name for o in node.outputs if o.enabled and o.name != "Alpha"]
    ours = addon.exr.blender_passes(path)
    assert ours == blender and "denoised" in ours, (ours, blender)
    print(f"addon: a denoised frame's passes in Blender: {blender}")


def run_timer(addon, s, limit_s=600):
    start = time.monotonic()
    while True:
        again = addon.tick()
        if s.finished:
            return
        assert again is not None, "the timer stopped before the submission ended"
        assert time.monotonic() - start < limit_s, "the submission did not end"
        time.sleep(again)


def check_failures(addon, prefs, url, token):
    scene = bpy.context.scene
    scene.tessera.frames = "CURRENT"
    # The coordinator's own refusal, in its words.
    prefs.token = token + "-wrong"
    bpy.ops.tessera.render()
    s = addon.SUBMISSIONS[-1]
    run_timer(addon, s)
    assert s.error.startswith("unauthenticated: wrong token"), s.error
    print(f"addon: a wrong token: {s.error}")
    # Nobody listening.
    prefs.token, prefs.address = token, "http://127.0.0.1:9"
    bpy.ops.tessera.render()
    s = addon.SUBMISSIONS[-1]
    run_timer(addon, s)
    assert s.error.startswith("cannot reach the coordinator at http://127.0.0.1:9"), s.error
    print(f"addon: no coordinator: {s.error}")
    prefs.address = url
    # The farm's refusal of the scene, in its words (addon.sh starts it with --max-spp 1000).
    scene.tessera.samples = 5000
    bpy.ops.tessera.render()
    s = addon.SUBMISSIONS[-1]
    run_timer(addon, s)
    assert s.error.startswith(f"frame {scene.frame_current}: invalid_argument:") and "5000" in s.error, s.error
    print(f"addon: too many samples: {s.error}")
    scene.tessera.samples = SAMPLES
    # A world tessera does not read is refused before anything is sent.
    tree = scene.world.node_tree
    sky = tree.nodes.new("ShaderNodeTexSky")
    tree.links.new(sky.outputs["Color"], tree.nodes["Background"].inputs["Color"])
    try:
        bpy.ops.tessera.render()
        raise AssertionError("a Sky Texture world was exported")
    except RuntimeError as e:
        assert "Sky Texture" in str(e) and "Environment Texture" in str(e), e
        print(f"addon: a sky texture: {str(e).strip()}")
    # So are a narrowed area light and a scene without a camera, each in words.
    tree.nodes.remove(sky)
    light = next(o for o in scene.objects if o.type == "LIGHT")
    light.data.spread = 1.0
    refused(f"the area light {light.name!r} has a spread under 180°")
    light.data.spread = 3.14159265
    scene.camera = None
    refused("the scene has no active camera")


def refused(words):
    """Pressing the button is refused before anything is sent, saying `words`."""
    try:
        bpy.ops.tessera.render()
    except RuntimeError as e:
        assert words in str(e), e
        print(f"addon: refused: {str(e).strip()}")
        return
    raise AssertionError(f"not refused: {words}")


class Restarting:
    """A coordinator that cannot be reached for its first two status requests (as while it
    restarts), then reports the job done."""

    def __init__(self, client):
        self.client, self.asked = client, 0

    def upload(self, path):
        return "0" * 64

    def submit(self, body):
        return {"job_id": "job-000042"}

    def status(self, job_id):
        self.asked += 1
        if self.asked <= 2:
            raise self.client.FarmError("cannot reach the coordinator at http://x: connection refused")
        return {"state": "done", "units_done": 4, "units_total": 4, "error": ""}

    def output(self, job_id):
        return b"exr"

    def cancel(self, job_id):
        pass


def check_reconnect(addon, out):
    """A coordinator that is unreachable for a while (restarting) is asked again, not given up
    on: the submission ends with its frame saved."""
    folder = os.path.join(out, "reconnect")
    os.makedirs(folder, exist_ok=True)
    with open(os.path.join(folder, "f.toml"), "w") as f:
        f.write("version = 1\n")
    frame = addon.export.Frame(7, "f.toml", [])
    farm = Restarting(addon.client)
    s = addon.jobs.Submission(farm, folder, [frame], 1, folder, "r")
    addon.jobs.POLL_S = 0.01
    s.start()
    assert s.wait(30), "the submission did not end"
    s.apply_events(lambda path: None)
    assert not s.error and s.frames[0].state == "done", (s.error, s.frames[0].state)
    assert farm.asked == 3 and os.path.getsize(os.path.join(folder, "r.0007.exr")) == 3
    print("addon: a coordinator unreachable for two polls is asked again; the frame is saved")


def build_scene(out):
    scene = bpy.context.scene
    scene.render.resolution_x, scene.render.resolution_y = 80, 60
    scene.render.resolution_percentage = 50
    scene.frame_start, scene.frame_end = 1, 3

    floor = principled("floor", (0.8, 0.8, 0.8), roughness=1.0, specular=0.0)
    blue = principled("blue", (0.1, 0.2, 0.8), roughness=0.5, specular=0.5)
    gold = principled("gold", (1.0, 0.77, 0.34), roughness=0.3, specular=0.5, metallic=1.0)
    bpy.ops.mesh.primitive_plane_add(size=6, location=(0, 0, 0))
    bpy.context.object.data.materials.append(floor)
    bpy.ops.mesh.primitive_cube_add(size=1, location=(-1, 0, 0.5))
    cube = bpy.context.object
    cube.data.materials.append(blue)
    cube.keyframe_insert("location", frame=1)
    cube.location.x = -0.4
    cube.keyframe_insert("location", frame=3)
    bpy.ops.mesh.primitive_uv_sphere_add(radius=0.5, location=(0.8, 0.3, 0.5))
    bpy.ops.object.shade_smooth()
    bpy.context.object.data.materials.append(gold)

    bpy.ops.object.light_add(type="AREA", location=(0, 0, 3))
    bpy.context.object.data.energy = 150
    bpy.context.object.data.size = 1.0
    bpy.ops.object.camera_add(location=(0, -5, 3), rotation=(math.radians(60), 0, 0))
    scene.camera = bpy.context.object
    # A second camera the exporter may list first: the scene's camera must still be used.
    bpy.ops.object.camera_add(location=(5, 0, 1), rotation=(math.radians(90), 0, math.radians(90)))
    bpy.context.object.name = "A-side-camera"

    scene.world = bpy.data.worlds.new("world")
    scene.world.use_nodes = True
    tree = scene.world.node_tree
    env = tree.nodes.new("ShaderNodeTexEnvironment")
    env.image = sky_image(out)
    mapping = tree.nodes.new("ShaderNodeMapping")
    mapping.inputs["Rotation"].default_value = (0, 0, math.radians(30))
    coords = tree.nodes.new("ShaderNodeTexCoord")
    tree.links.new(coords.outputs["Generated"], mapping.inputs["Vector"])
    tree.links.new(mapping.outputs["Vector"], env.inputs["Vector"])
    background = tree.nodes["Background"]
    tree.links.new(env.outputs["Color"], background.inputs["Color"])
    background.inputs["Strength"].default_value = 0.5


def principled(name, color, roughness, specular, metallic=0.0):
    m = bpy.data.materials.new(name)
    m.use_nodes = True
    p = m.node_tree.nodes["Principled BSDF"]
    p.inputs["Base Color"].default_value = (*color, 1)
    p.inputs["Roughness"].default_value = roughness
    p.inputs["Specular IOR Level"].default_value = specular
    p.inputs["Metallic"].default_value = metallic
    return m


def sky_image(out):
    """A 32×16 sky, brighter towards one side so a wrong turn would show, saved as EXR."""
    w, h = 32, 16
    image = bpy.data.images.new("sky", w, h, float_buffer=True)
    pixels = []
    for j in range(h):
        for i in range(w):
            glow = 2.0 if 4 <= i < 8 and j >= 10 else 0.3 + 0.02 * i
            pixels += [glow, 0.8 * glow, 0.6 * glow, 1.0]
    image.pixels = pixels
    image.filepath_raw = os.path.join(out, "sky.exr")
    image.file_format = "OPEN_EXR"
    image.save()
    # Blender writes the file with its view transform applied: render the file, as tessera does.
    return bpy.data.images.load(image.filepath_raw)


if __name__ == "__main__":
    main()
