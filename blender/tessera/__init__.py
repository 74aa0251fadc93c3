"""tessera for Blender: render the open scene on a tessera farm.

Render Properties > tessera > "Render on tessera" exports the current frame (or the scene's
frame range) with Blender's glTF exporter and the world as tessera's environment, uploads every
file the export names to the coordinator's HTTP API, submits a job per frame, shows their
progress, and loads each finished EXR into the Image Editor. The farm's address and token are
the add-on's preferences. docs/blender.md is the manual; README.md's "Rendering from Blender"
installs it.
"""

import os
import re
import tempfile

import bpy

from . import client, exr, export, jobs

# Every submission of this Blender session, newest last, for the panel.
SUBMISSIONS = []
# How often the timer applies what the submissions' threads posted.
TICK_S = 0.5


class TesseraPreferences(bpy.types.AddonPreferences):
    """Where the farm is: set once per machine."""

    bl_idname = __package__

    address: bpy.props.StringProperty(
        name="Coordinator",
        description="The coordinator's HTTP address (its --http), e.g. http://farm:7880",
        default="http://127.0.0.1:7880",
    )
    token: bpy.props.StringProperty(
        name="Token",
        description="Your token on the farm, if it asks for one (--token or --tokens-file)",
        subtype="PASSWORD",
        default="",
    )

    def draw(self, context):
        self.layout.prop(self, "address")
        self.layout.prop(self, "token")


class TesseraSettings(bpy.types.PropertyGroup):
    """What one scene asks of the farm (saved with the .blend)."""

    samples: bpy.props.IntProperty(
        name="Samples", description="Samples per pixel", default=64, min=1, max=1 << 20
    )
    frames: bpy.props.EnumProperty(
        name="Frames",
        items=[
            ("CURRENT", "Current Frame", "Render the current frame"),
            ("RANGE", "Frame Range", "Render the scene's frame range, a job per frame"),
        ],
        default="CURRENT",
    )
    denoise: bpy.props.EnumProperty(
        name="Denoise",
        description="Add a denoised layer (Open Image Denoise), made by a coordinator or a worker started with --denoise",
        items=[
            ("OFF", "Off", "No denoised layer"),
            ("fast", "Fast", "Open Image Denoise, fast quality"),
            ("balanced", "Balanced", "Open Image Denoise, balanced quality"),
            ("high", "High", "Open Image Denoise, high quality"),
        ],
        default="OFF",
    )
    output: bpy.props.StringProperty(
        name="Output",
        description="Folder for the frames' EXR files and the exported scene",
        default="//tessera/",
        subtype="DIR_PATH",
    )


def preferences(context):
    return context.preferences.addons[__package__].preferences


def stem_of(context):
    """The frames' file stem: the .blend's name, in the letters the farm allows."""
    name = os.path.splitext(os.path.basename(bpy.data.filepath))[0] or "untitled"
    return re.sub(r"[^A-Za-z0-9_-]", "_", name)


def output_folder(settings):
    """The output folder as an absolute path; beside an unsaved file, the temporary folder."""
    path = settings.output
    if path.startswith("//") and not bpy.data.filepath:
        return os.path.join(tempfile.gettempdir(), "tessera", path[2:])
    return bpy.path.abspath(path)


def frame_numbers(scene, which):
    if which == "CURRENT":
        return [scene.frame_current]
    return list(range(scene.frame_start, scene.frame_end + 1, max(1, scene.frame_step)))


class TESSERA_OT_render(bpy.types.Operator):
    """Export the scene, send it to the tessera farm and load the frames it renders"""

    bl_idname = "tessera.render"
    bl_label = "Render on tessera"

    def execute(self, context):
        scene = context.scene
        settings = scene.tessera
        prefs = preferences(context)
        try:
            farm = client.Farm(prefs.address, prefs.token)
            stem = stem_of(context)
            out = output_folder(settings)
            folder = os.path.join(out, stem + "-export")
            numbers = frame_numbers(scene, settings.frames)
            denoise = None if settings.denoise == "OFF" else settings.denoise
            frames = export.export(scene, folder, stem, numbers, denoise)
        except (client.FarmError, export.ExportError) as e:
            self.report({"ERROR"}, str(e))
            return {"CANCELLED"}
        except OSError as e:
            self.report({"ERROR"}, f"cannot write the export: {e}")
            return {"CANCELLED"}
        submission = jobs.Submission(farm, folder, frames, settings.samples, out, stem)
        SUBMISSIONS.append(submission)
        submission.start()
        if not bpy.app.timers.is_registered(tick):
            bpy.app.timers.register(tick, first_interval=TICK_S)
        self.report({"INFO"}, f"sending {len(frames)} frame(s) to {farm.url}")
        return {"FINISHED"}


class TESSERA_OT_cancel(bpy.types.Operator):
    """Cancel the latest submission's jobs on the farm"""

    bl_idname = "tessera.cancel"
    bl_label = "Cancel"

    def execute(self, context):
        for s in SUBMISSIONS:
            if not s.finished:
                s.cancel()
        return {"FINISHED"}


class TESSERA_PT_panel(bpy.types.Panel):
    bl_label = "tessera"
    bl_space_type = "PROPERTIES"
    bl_region_type = "WINDOW"
    bl_context = "render"

    def draw(self, context):
        layout = self.layout
        settings = context.scene.tessera
        layout.label(text=f"Farm: {preferences(context).address}")
        layout.prop(settings, "samples")
        layout.prop(settings, "frames")
        layout.prop(settings, "denoise")
        layout.prop(settings, "output")
        row = layout.row()
        row.operator(TESSERA_OT_render.bl_idname, icon="RENDER_STILL")
        if SUBMISSIONS and not SUBMISSIONS[-1].finished:
            row.operator(TESSERA_OT_cancel.bl_idname, icon="CANCEL")
        if SUBMISSIONS:
            draw_submission(layout, SUBMISSIONS[-1])


def draw_submission(layout, s):
    box = layout.box()
    if s.error:
        for i, line in enumerate(wrap(s.error)):
            box.label(text=line, icon="ERROR" if i == 0 else "BLANK1")
    elif hasattr(box, "progress"):
        box.progress(factor=s.progress(), text=s.summary())
    else:
        box.label(text=s.summary())
    for f in s.frames[-8:]:
        text = f"frame {f.number}: {f.job_id or '…'} {f.state}"
        if f.units_total and f.state != "done":
            text += f" {f.units_done}/{f.units_total}"
        box.label(text=text)
        for line in wrap(f.error):
            box.label(text=line, icon="ERROR")


def wrap(text, width=70):
    """The error in lines a panel shows whole."""
    words, lines, line = text.split(), [], ""
    for w in words:
        if line and len(line) + 1 + len(w) > width:
            lines.append(line)
            line = w
        else:
            line = f"{line} {w}" if line else w
    return lines + [line] if line else lines


def load_exr(path):
    """Loads (or reloads) a finished frame and shows it in every Image Editor: its denoised
    layer where the frame has one (Blender reads tessera's EXR as a multilayer image whose
    passes are `Combined`, the beauty, then each layer by name)."""
    image = bpy.data.images.load(path, check_existing=True)
    image.reload()
    passes = exr.blender_passes(path)
    shown = passes.index("denoised") if "denoised" in passes else 0
    wm = bpy.context.window_manager
    for window in wm.windows if wm else []:
        for area in window.screen.areas:
            if area.type == "IMAGE_EDITOR":
                space = area.spaces.active
                space.image = image
                space.image_user.multilayer_pass = shown
    return image


def tick():
    """The timer: applies every submission's news on the main thread; stops when all ended."""
    changed = False
    for s in SUBMISSIONS:
        changed |= s.apply_events(load_exr)
    if changed:
        wm = bpy.context.window_manager
        for window in wm.windows if wm else []:
            for area in window.screen.areas:
                if area.type in ("PROPERTIES", "IMAGE_EDITOR"):
                    area.tag_redraw()
    return None if all(s.finished for s in SUBMISSIONS) else TICK_S


CLASSES = (TesseraPreferences, TesseraSettings, TESSERA_OT_render, TESSERA_OT_cancel, TESSERA_PT_panel)


def register():
    for cls in CLASSES:
        bpy.utils.register_class(cls)
    bpy.types.Scene.tessera = bpy.props.PointerProperty(type=TesseraSettings)


def unregister():
    for s in SUBMISSIONS:
        s.cancel()
    if bpy.app.timers.is_registered(tick):
        bpy.app.timers.unregister(tick)
    del bpy.types.Scene.tessera
    for cls in reversed(CLASSES):
        bpy.utils.unregister_class(cls)
