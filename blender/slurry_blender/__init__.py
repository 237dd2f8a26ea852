"""Slurry for Blender: imports a Slurry output directory as animated objects (particles with
velocity and id, the surface mesh and VDB sequences, one pair per material when the scene
surfaces its materials separately, the colliders), and runs a scene through the `slurry` Python
module from a panel (View3D sidebar, "Slurry" tab), with progress in the status bar, Esc to
cancel, and resume from the run's checkpoints; the run itself is job.RunJob, which the modal
operator's timer ticks. docs/pipeline-outputs.md ("Using the frames in Blender and Houdini")
describes it."""

bl_info = {
    "name": "Slurry",
    "author": "Slurry",
    "version": (0, 1, 0),
    "blender": (3, 4, 0),
    "location": "File > Import > Slurry output directory; View3D > Sidebar > Slurry",
    "description": "Import Slurry simulation output (particles, surfaces, VDB, colliders) and run scenes",
    "category": "Import-Export",
}

import json
import os

import bpy
from bpy.props import BoolProperty, EnumProperty, FloatProperty, IntProperty, PointerProperty, StringProperty

from . import importer, job, module

UP_AXES = [("AUTO", "Auto", "The scene the frames name decides (output.up_axis); Y-up if it cannot be read"),
           ("Y", "Y-up", "Files in the simulation's axes (Slurry's default): turned to Z-up"),
           ("Z", "Z-up", "Files written with output.up_axis \"z\": kept as they are")]


class SlurryPreferences(bpy.types.AddonPreferences):
    bl_idname = __name__

    module_folder: StringProperty(
        name="Slurry Python module folder",
        description="Folder holding slurry.cpython-*.so (e.g. build/release/python); empty: the installed "
                    "module (/usr/local/lib/python3.11/dist-packages), then a search",
        subtype="DIR_PATH", default="")

    def draw(self, context):
        self.layout.prop(self, "module_folder")
        try:
            found = module.import_slurry(self.module_folder)
            self.layout.label(text=f"Module: {found.__file__}")
        except ImportError as e:
            self.layout.label(text=str(e)[:200], icon="ERROR")


def preferences(context):
    addon = context.preferences.addons.get(__name__)
    return addon.preferences if addon else None


def load_slurry(context):
    prefs = preferences(context)
    return module.import_slurry(prefs.module_folder if prefs else "")


class SLURRY_OT_import_directory(bpy.types.Operator):
    """Import a Slurry output directory: particles, surface meshes, surface VDB and colliders, swapped per frame"""
    bl_idname = "slurry.import_directory"
    bl_label = "Import Slurry output directory"
    bl_options = {"REGISTER", "UNDO"}

    directory: StringProperty(name="Directory", subtype="DIR_PATH")
    start_frame: IntProperty(name="Start frame", default=1, description="The Blender frame that shows frame 0")
    up_axis: EnumProperty(name="Up axis of the files", items=UP_AXES, default="AUTO")
    particles: BoolProperty(name="Particles", default=True)
    particle_radius: FloatProperty(name="Particle radius", default=0.01, min=0.0, unit="LENGTH")
    surface: BoolProperty(name="Surface meshes", default=True)
    volume: BoolProperty(name="Surface VDB", default=True)
    colliders: BoolProperty(name="Colliders", default=True)
    set_scene: BoolProperty(name="Set frame range and rate", default=True)

    def execute(self, context):
        try:
            collection, made, notes = importer.import_directory(
                context, self.directory, start=self.start_frame, up_axis=self.up_axis, particles=self.particles,
                surface=self.surface, volume=self.volume, colliders=self.colliders,
                particle_radius=self.particle_radius, set_scene=self.set_scene)
        except (OSError, ValueError) as e:
            self.report({"ERROR"}, str(e))
            return {"CANCELLED"}
        self.report({"INFO"}, f"Slurry: {', '.join(made)} from {collection['slurry_directory']}")
        for note in notes:
            self.report({"INFO"}, f"Slurry: {note}")
        return {"FINISHED"}

    def invoke(self, context, event):
        context.window_manager.fileselect_add(self)
        return {"RUNNING_MODAL"}


class SlurrySettings(bpy.types.PropertyGroup):
    scene_file: StringProperty(name="Scene", subtype="FILE_PATH", description="The scene file (JSON)")
    cache_dir: StringProperty(name="Cache", subtype="DIR_PATH", default="//slurry_cache",
                              description="Where the run writes its frames and checkpoints")
    frames: IntProperty(name="Frames", default=0, min=0, description="Frames after frame 0; 0: the scene's")
    threads: IntProperty(name="Threads", default=0, min=0, description="Worker threads; 0: all cores")
    quality: EnumProperty(name="Quality", default="SCENE", items=[
        ("SCENE", "Scene's", "As the scene file says"),
        ("preview", "Preview", "solver.quality \"preview\""),
        ("production", "Production", "solver.quality \"production\""),
        ("reference", "Reference", "solver.quality \"reference\"")])
    resume: BoolProperty(name="Resume", default=False,
                         description="Continue from the newest checkpoint in the cache instead of frame 0")
    start_frame: IntProperty(name="Start frame", default=1, description="The Blender frame that shows frame 0")


def load_scene(slurry, settings):
    """The scene file with the panel's quality, validated by the module (errors name the key)."""
    path = os.path.abspath(bpy.path.abspath(settings.scene_file))
    with open(path) as f:
        spec = json.load(f)
    if settings.quality != "SCENE":
        spec.setdefault("solver", {})["quality"] = settings.quality
    return slurry.parse_scene(spec, path)


def cache_directory(settings, scene_file):
    base = settings.cache_dir or "//slurry_cache"
    path = bpy.path.abspath(base)
    if not os.path.isabs(path):  # an unsaved .blend: "//" means nothing
        path = os.path.join(os.getcwd(), base.lstrip("/"))
    return os.path.join(path, os.path.splitext(os.path.basename(scene_file))[0])


def start_run(context):
    """A RunJob for the scene panel's settings (raises ImportError, OSError or ValueError)."""
    settings = context.scene.slurry
    slurry = load_slurry(context)
    scene = load_scene(slurry, settings)
    return job.RunJob(slurry, scene, cache_directory(settings, scene.source), frames=settings.frames or None,
                      threads=settings.threads, resume=settings.resume)


def finish_run(context, run, tick):
    """Imports what an ended run wrote (also a cancelled one's frames); returns the reports, as
    [(level, message)], and the new collection or None."""
    reports = [({"ERROR"} if tick.state == "error" else {"WARNING"} if tick.state == "stopped" else {"INFO"}, tick.text)]
    collection = None
    if os.path.isdir(run.directory) and importer.scan(run.directory)["frame"]:
        collection, _, notes = importer.import_directory(context, run.directory, start=context.scene.slurry.start_frame,
                                                         up_axis=run.scene.up_axis.upper())
        reports += [({"INFO"}, f"Slurry: {n}") for n in notes]
    return reports, collection


def show_tick(context, tick):
    """The status bar's text and the progress indicator (0..frames) for a tick."""
    context.window_manager.progress_update(max(0, tick.frame))
    if context.workspace is not None:
        context.workspace.status_text_set(tick.text)


class SLURRY_OT_run(bpy.types.Operator):
    """Run the scene into the cache directory through the slurry module, then import it (Esc cancels)"""
    bl_idname = "slurry.run"
    bl_label = "Run"

    blocking: BoolProperty(name="Blocking", default=False, options={"SKIP_SAVE"},
                           description="Run in this call (scripts, blender -b), without the modal timer")

    def finish(self, context, tick):
        reports, _ = finish_run(context, self.job, tick)
        for level, message in reports:
            self.report(level, message)
        return {"FINISHED"} if tick.state == "done" else {"CANCELLED"}

    def execute(self, context):
        try:
            self.job = start_run(context)
        except (ImportError, OSError, ValueError) as e:
            self.report({"ERROR"}, f"Slurry: {e}")
            return {"CANCELLED"}
        if self.blocking:
            tick = self.job.tick()
            while tick.state == "running":
                self.job.wait(0.25)
                tick = self.job.tick()
            return self.finish(context, tick)
        wm = context.window_manager
        self.timer = wm.event_timer_add(0.25, window=context.window)
        wm.progress_begin(0, max(1, self.job.frames))
        wm.modal_handler_add(self)
        context.workspace.status_text_set(f"Slurry: running {os.path.basename(self.job.scene.source)} (Esc cancels)")
        return {"RUNNING_MODAL"}

    def modal(self, context, event):
        if event.type == "ESC":
            self.job.cancel()
        elif event.type != "TIMER":
            return {"PASS_THROUGH"}
        tick = self.job.tick()
        show_tick(context, tick)
        if tick.state == "running":
            return {"PASS_THROUGH"}
        wm = context.window_manager
        wm.event_timer_remove(self.timer)
        wm.progress_end()
        context.workspace.status_text_set(None)
        return self.finish(context, tick)

    def invoke(self, context, event):
        return self.execute(context)


class SLURRY_PT_panel(bpy.types.Panel):
    bl_label = "Slurry"
    bl_space_type = "VIEW_3D"
    bl_region_type = "UI"
    bl_category = "Slurry"

    def draw(self, context):
        settings = context.scene.slurry
        col = self.layout.column()
        col.prop(settings, "scene_file")
        col.prop(settings, "cache_dir")
        col.prop(settings, "frames")
        col.prop(settings, "threads")
        col.prop(settings, "quality")
        col.prop(settings, "start_frame")
        col.prop(settings, "resume")
        col.operator(SLURRY_OT_run.bl_idname, icon="PLAY")
        col.separator()
        col.operator(SLURRY_OT_import_directory.bl_idname, icon="IMPORT")


def menu_import(self, context):
    self.layout.operator(SLURRY_OT_import_directory.bl_idname, text="Slurry output directory")


CLASSES = (SlurryPreferences, SLURRY_OT_import_directory, SlurrySettings, SLURRY_OT_run, SLURRY_PT_panel)


def register():
    for c in CLASSES:
        bpy.utils.register_class(c)
    bpy.types.Scene.slurry = PointerProperty(type=SlurrySettings)
    bpy.types.TOPBAR_MT_file_import.append(menu_import)
    importer.register_handler()


def unregister():
    importer.unregister_handler()
    bpy.types.TOPBAR_MT_file_import.remove(menu_import)
    del bpy.types.Scene.slurry
    for c in reversed(CLASSES):
        bpy.utils.unregister_class(c)
