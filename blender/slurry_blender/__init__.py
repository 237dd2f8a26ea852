"""Slurry for Blender: imports a Slurry output directory as animated objects (particles with
velocity and id, the surface mesh and VDB sequences, one pair per material when the scene
surfaces its materials separately, the colliders), and runs a scene through the `slurry` Python module from a panel (View3D sidebar, "Slurry" tab), with
progress in the status bar, Esc to cancel, and resume from the run's checkpoints.
docs/pipeline-outputs.md ("Using the frames in Blender and Houdini") describes it."""

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
import queue
import threading

import bpy
from bpy.props import BoolProperty, EnumProperty, FloatProperty, IntProperty, PointerProperty, StringProperty

from . import importer, module

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


class SLURRY_OT_run(bpy.types.Operator):
    """Run the scene into the cache directory through the slurry module, then import it (Esc cancels)"""
    bl_idname = "slurry.run"
    bl_label = "Run"

    blocking: BoolProperty(name="Blocking", default=False, options={"SKIP_SAVE"},
                           description="Run in this call (scripts, blender -b), without the modal timer")

    def start(self, context):
        settings = context.scene.slurry
        slurry = load_slurry(context)
        self.scene = load_scene(slurry, settings)
        self.directory = cache_directory(settings, self.scene.source)
        self.total = settings.frames or self.scene.frames
        self.token = slurry.StopToken()
        self.events = queue.Queue()
        self.result = None
        kwargs = dict(directory=self.directory, frames=settings.frames or None, threads=settings.threads,
                      resume=settings.resume, stop=self.token,
                      on_frame=lambda f: self.events.put((f["frame"], f["frames"], f["seconds"])))

        def work():
            try:
                self.result = ("done", slurry.run_scene(self.scene, **kwargs))
            except BaseException as e:  # handed to the main thread, which reports it
                self.result = ("error", e)

        self.thread = threading.Thread(target=work, name="slurry run", daemon=True)
        self.thread.start()

    def finish(self, context):
        kind, value = self.result
        settings = context.scene.slurry
        if kind == "error":
            self.report({"ERROR"}, f"Slurry: {value}")
        elif value["stopped"]:
            self.report({"WARNING"}, f"Slurry: cancelled after frame {value['frames_written'] - 1} "
                                     f"(tick Resume to continue from the last checkpoint)")
        if os.path.isdir(self.directory) and importer.scan(self.directory)["frame"]:
            _, _, notes = importer.import_directory(context, self.directory, start=settings.start_frame,
                                                    up_axis=self.scene.up_axis.upper())
            for note in notes:
                self.report({"INFO"}, f"Slurry: {note}")
        if kind == "done":
            self.report({"INFO"}, f"Slurry: {value['frames_written']} frames in {self.directory} "
                                  f"({value['wall_seconds']:.1f} s)")
        return {"FINISHED"} if kind == "done" else {"CANCELLED"}

    def execute(self, context):
        try:
            self.start(context)
        except (ImportError, OSError, ValueError) as e:
            self.report({"ERROR"}, f"Slurry: {e}")
            return {"CANCELLED"}
        if self.blocking:
            self.thread.join()
            return self.finish(context)
        wm = context.window_manager
        self.timer = wm.event_timer_add(0.25, window=context.window)
        wm.progress_begin(0, max(1, self.total))
        wm.modal_handler_add(self)
        context.workspace.status_text_set(f"Slurry: running {os.path.basename(self.scene.source)} (Esc cancels)")
        return {"RUNNING_MODAL"}

    def modal(self, context, event):
        if event.type == "ESC" and not self.token.requested:
            self.token.request()
            context.workspace.status_text_set("Slurry: stopping after the current frame")
        if event.type != "TIMER":
            return {"PASS_THROUGH"}
        while not self.events.empty():
            frame, frames, seconds = self.events.get()
            context.window_manager.progress_update(frame)
            if not self.token.requested:
                context.workspace.status_text_set(
                    f"Slurry: frame {frame}/{frames} ({seconds:.1f} s a frame), Esc cancels")
        if self.thread.is_alive():
            return {"PASS_THROUGH"}
        wm = context.window_manager
        wm.event_timer_remove(self.timer)
        wm.progress_end()
        context.workspace.status_text_set(None)
        return self.finish(context)

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
