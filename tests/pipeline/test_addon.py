# The Blender add-on (blender/slurry_blender), headless in Debian's Blender 3.4:
#
#   BLENDER_USER_SCRIPTS=TMP blender -b --factory-startup --python-exit-code 1 -P test_addon.py -- \
#       ADDON.zip DIR FRAMES MATERIALS_DIR OUT [MODULE_DIR RUN_SCENE]
#
# Installs the zipped add-on into the user scripts folder BLENDER_USER_SCRIPTS names (a temporary
# one: nothing global changes) and enables it; imports DIR (a run of a shipped scene by the CLI,
# frames 0..FRAMES); steps the frames and checks, for each, that the particles, surface and
# colliders objects hold the vertex and face counts the PLY headers declare, that the particles'
# `velocity` (FLOAT_VECTOR) and `id` (INT) attributes are the file's columns in Blender's axes, row
# by row, that the surface and colliders carry `velocity`, and that the VDB volume reads that
# frame's file with its `velocity` grid. Imports MATERIALS_DIR (a run of two_liquids.json, one
# surface per material) and checks one mesh and one volume object per material, with every
# frame's counts as the headers declare, and, from a copy missing one material's mesh of a
# frame, that the surface shows an empty mesh there. Then renders one frame at 64 x 48 with
# Cycles on the CPU three times: motion blur off, on, and on with the surface's velocities
# zeroed, and asserts that the velocities make the blurred picture differ from the sharp one, and
# that without them it does not (so the difference is the blur the attribute drives). With
# MODULE_DIR and RUN_SCENE, also runs RUN_SCENE through the add-on's Run operator (blocking) with
# the module from MODULE_DIR and checks what it imported, then drives the modal Run's ticks by
# hand (RunJob.tick, no event loop): every frame reported once and in order, a cancel that stops
# the run between frames and leaves the frames written so far and a checkpoint, and a second run
# with Resume that continues from that checkpoint to the last frame. Any failed assertion raises;
# --python-exit-code 1 makes Blender exit 1.
import os
import sys
import time

import bpy
import numpy as np


def expect(cond, message):
    if not cond:
        raise AssertionError(message)
    print("ok:", message)


def header_counts(path):
    counts = {}
    with open(path, "rb") as f:
        assert f.readline().strip() == b"ply", path
        for raw in f:
            words = raw.decode("ascii").split()
            if words[:1] == ["element"]:
                counts[words[1]] = int(words[2])
            if words[:1] == ["end_header"]:
                return counts
    raise AssertionError(f"{path}: no end_header")


def read_vertex_columns(path):
    """The vertex element of a binary little-endian PLY, as {name: array} (read here, not by the add-on)."""
    types = {"float": "<f4", "double": "<f8", "uint": "<u4", "int": "<i4", "uchar": "u1", "ushort": "<u2"}
    props, count = [], 0
    with open(path, "rb") as f:
        f.readline()
        element = None
        for raw in f:
            words = raw.decode("ascii").split()
            if words[0] == "element":
                element = words[1]
                if element == "vertex":
                    count = int(words[2])
            elif words[0] == "property" and element == "vertex":
                props.append((words[2], types[words[1]]))
            elif words[0] == "end_header":
                break
        rows = np.frombuffer(f.read(np.dtype(props).itemsize * count), np.dtype(props), count)
    return {n: rows[n] for n, _ in props}


def pixels(path):
    img = bpy.data.images.load(path)
    a = np.empty(len(img.pixels), np.float32)
    img.pixels.foreach_get(a)
    bpy.data.images.remove(img)
    return a.reshape(-1, 4)[:, :3]



def new_collection(before):
    """The one collection made since `before` (a set of names), and its objects by name without
    Blender's ".001" suffixes."""
    (name,) = set(bpy.data.collections.keys()) - before
    coll = bpy.data.collections[name]
    return coll, {o.name.split(".")[0]: o for o in coll.objects}


def check_materials(scene, directory, out):
    """The per-material surfaces of DIRECTORY (surface_<material>_NNNN.ply/.vdb): one mesh and one
    volume object per material, every frame's counts as the PLY headers declare."""
    import shutil
    from slurry_blender import importer
    materials = sorted({n[len("surface_"):-len("_0000.ply")] for n in os.listdir(directory)
                        if n.startswith("surface_") and n.endswith(".ply")})
    expect(materials == ["dyed", "water"], f"two_liquids wrote one surface per material: {materials}")
    numbers = sorted(int(n[6:10]) for n in os.listdir(directory) if n.startswith("frame_") and n.endswith(".ply"))
    last = numbers[-1]
    before = set(bpy.data.collections.keys())
    # set_scene=False: the scene keeps the first import's frame rate, which the render below blurs with.
    result = bpy.ops.slurry.import_directory(directory=directory, start_frame=0, up_axis="AUTO", set_scene=False)
    expect(result == {"FINISHED"}, "per-material import finished")
    coll, objects = new_collection(before)
    expected_names = {"particles"} | {f"surface_{m}" for m in materials} | {f"surface_{m}_vdb" for m in materials}
    expect(set(objects) == expected_names, f"objects {sorted(objects)}")
    expect(objects["surface_water"].data.materials[0] != objects["surface_dyed"].data.materials[0],
           f"materials {objects['surface_water'].data.materials[0].name}, {objects['surface_dyed'].data.materials[0].name}")
    checked = 0
    for f in range(last + 1):
        scene.frame_set(f)
        tag = f"{f:04d}"
        for m in materials:
            expected = header_counts(os.path.join(directory, f"surface_{m}_{tag}.ply"))
            mesh = objects[f"surface_{m}"].data
            expect(len(mesh.vertices) == expected["vertex"] and len(mesh.polygons) == expected["face"] > 0,
                   f"frame {f}: surface_{m} {len(mesh.vertices)} vertices, {len(mesh.polygons)} faces; "
                   f"{expected['vertex']}, {expected['face']} written")
            a = mesh.attributes.get("velocity")
            expect(a is not None and a.data_type == "FLOAT_VECTOR", f"frame {f}: surface_{m} velocity")
            grids = objects[f"surface_{m}_vdb"].data.grids
            grids.load()
            names = sorted(g.name for g in grids)
            expect(os.path.basename(grids.frame_filepath) == f"surface_{m}_{tag}.vdb" and "velocity" in names,
                   f"frame {f}: surface_{m}_vdb reads {os.path.basename(grids.frame_filepath)}, grids {names}")
            checked += 1
        expected = header_counts(os.path.join(directory, f"frame_{tag}.ply"))
        expect(len(objects["particles"].data.vertices) == expected["vertex"],
               f"frame {f}: particles {expected['vertex']}")
    expect(checked == 2 * (last + 1), f"{checked} per-material surfaces checked")
    coll.hide_viewport = True

    # A material without particles in a frame has no file there: that frame shows an empty mesh,
    # the others their own files.
    gap = os.path.join(out, "two_liquids_gap")
    shutil.rmtree(gap, ignore_errors=True)
    os.makedirs(gap)
    for n in os.listdir(directory):
        if n.endswith(".ply") and n != "surface_dyed_0001.ply":
            os.symlink(os.path.join(directory, n), os.path.join(gap, n))
    before = set(bpy.data.collections.keys())
    expect(bpy.ops.slurry.import_directory(directory=gap, start_frame=0, set_scene=False) == {"FINISHED"}, "import with a gap")
    coll, objects = new_collection(before)
    shown = []
    for f in range(-1, last + 2):
        scene.frame_set(f)
        shown.append(len(objects["surface_dyed"].data.vertices))
    declared = [header_counts(os.path.join(directory, f"surface_dyed_{n:04d}.ply"))["vertex"] for n in (0, 2)]
    want = [declared[0], declared[0], 0, declared[1], declared[1]]
    expect(shown == want, f"surface_dyed vertices at Blender frames -1..{last + 1}: {shown} (want {want})")
    seq = {"frames": [1, 2], "files": {"1": "a", "2": "b"}, "start": 0, "last": 3}
    expect([importer.sequence_frame(seq, f) for f in range(-1, 5)] == [None, None, 1, 2, None, None],
           "a surface sequence is empty where it has no file, held at frames 0 and last outside them")
    coll.hide_viewport = True


def stepped_job():
    """The RunJob class with a worker that waits, after each frame it reports, until a tick has
    taken it (drive() lets it go on): the ticks see every frame as it is written, and a cancel
    lands between the same two frames on a fast machine and a slow one."""
    import threading
    from slurry_blender import job

    class SteppedJob(job.RunJob):
        def __init__(self, *args, **kwargs):
            self.gate = threading.Semaphore(0)
            super().__init__(*args, **kwargs)

        def frame_written(self, report):
            super().frame_written(report)
            self.gate.acquire()

    return SteppedJob


def drive(run, cancel_at=None):
    """Ticks a RunJob by hand until it ends, as the modal operator's timer does; cancels it at the
    first tick that reports frame `cancel_at` or a later one. Returns the last tick and every
    frame reported, in the order the ticks reported them."""
    seen, frames_seen = [], []
    tick = run.tick()
    while True:
        seen += tick.new_frames
        frames_seen.append(tick.frame)
        if tick.state != "running":
            break
        if cancel_at is not None and tick.frame >= cancel_at and not run.cancelled:
            run.cancel()
            if hasattr(run, "gate"):  # the worker waits at the gate: the run cannot have ended
                t = run.tick()
                expect(t.state == "running" and not t.new_frames and "stopping" in t.text,
                       f"a cancelled run says so until it ends: {t.text}")
        for _ in tick.new_frames:
            if hasattr(run, "gate"):
                run.gate.release()
        run.wait(0.05)
        tick = run.tick()
    expect(frames_seen == sorted(frames_seen), f"progress never goes back: {frames_seen[0]} .. {frames_seen[-1]} "
                                               f"over {len(frames_seen)} ticks")
    return tick, seen


def check_run_ticks(scene, cache, run_scene):
    """The modal Run without an event loop: progress, cancel between frames, resume."""
    import shutil
    import slurry_blender
    settings = scene.slurry
    settings.scene_file = os.path.abspath(run_scene)
    settings.cache_dir = cache
    settings.frames = 3
    settings.threads = 2
    settings.resume = False
    directory = os.path.join(cache, os.path.splitext(os.path.basename(run_scene))[0])
    ctx = bpy.context

    # The panel's settings make the job start_run() starts.
    run = slurry_blender.start_run(ctx)
    expect(run.directory == directory and run.frames == 3, f"RunJob into {run.directory}, frames 0..{run.frames}")
    run.cancel()
    run.wait()
    shutil.rmtree(directory)

    # Cancelled when the ticks report frame 1: the run stops before frame 2, with frame 1's
    # checkpoint.
    slurry = slurry_blender.load_slurry(ctx)
    run = stepped_job()(slurry, slurry_blender.load_scene(slurry, settings), directory, frames=3, threads=2)
    tick, seen = drive(run, cancel_at=1)
    last = tick.summary["frames_written"] - 1
    expect(tick.state == "stopped" and tick.summary["stopped"], f"cancelled run ended {tick.state}: {tick.text}")
    expect(seen == [0, 1] and tick.frame == last == 1, f"frames reported: {seen}; the run stopped after frame {last}")
    written = sorted(n for n in os.listdir(directory) if n.startswith("frame_"))
    expect(written == [f"frame_{n:04d}.ply" for n in range(last + 1)], f"the frames so far are kept: {written}")
    expect(os.path.isfile(os.path.join(directory, f"checkpoint_{last:04d}.slc")), f"checkpoint_{last:04d}.slc written")
    before = set(bpy.data.collections.keys())
    reports, coll = slurry_blender.finish_run(ctx, run, tick)
    expect(reports[0][0] == {"WARNING"} and "cancelled" in reports[0][1], f"report: {reports[0]}")
    expect(any("points_NNNN.vdb not imported" in m for _, m in reports), "the VDB points left out are reported")
    expect(coll is not None and coll.name not in before, f"the cancelled run's frames imported into {coll.name}")
    coll.hide_viewport = coll.hide_render = True

    # Resume: continues from that checkpoint to frame 3.
    settings.resume = True
    run = slurry_blender.start_run(ctx)
    tick, seen = drive(run)
    expect(tick.state == "done" and not tick.summary["stopped"], f"resumed run ended {tick.state}: {tick.text}")
    expect(tick.summary["resumed_from"] == last, f"resumed from frame {tick.summary['resumed_from']}")
    expect(seen == list(range(last + 1, 4)), f"the resumed run reports frames {seen}")
    expect(os.path.isfile(os.path.join(directory, "frame_0003.ply")), "frame_0003.ply written")
    reports, coll = slurry_blender.finish_run(ctx, run, tick)
    expect(reports[0][0] == {"INFO"} and "frames 0-3" in reports[0][1], f"report: {reports[0]}")
    objects = {o.name.split(".")[0]: o for o in coll.objects}
    scene.frame_set(settings.start_frame + 3)
    expected = header_counts(os.path.join(directory, "frame_0003.ply"))["vertex"]
    expect(len(objects["particles"].data.vertices) == expected, f"frame 3 imported: {expected} particles")
    settings.resume = False

def main():
    argv = sys.argv[sys.argv.index("--") + 1:]
    addon_zip, directory, frames = argv[0], os.path.abspath(argv[1]), int(argv[2])
    materials_dir, out = os.path.abspath(argv[3]), os.path.abspath(argv[4])
    module_dir, run_scene = (argv[5], argv[6]) if len(argv) >= 7 else (None, None)
    os.makedirs(out, exist_ok=True)
    user_scripts = os.environ.get("BLENDER_USER_SCRIPTS", "")
    expect(user_scripts and os.path.isdir(user_scripts), f"BLENDER_USER_SCRIPTS is a folder ({user_scripts})")

    # 1. Install and enable the zipped add-on, into the temporary user scripts folder.
    bpy.ops.preferences.addon_install(filepath=os.path.abspath(addon_zip), overwrite=True)
    bpy.ops.preferences.addon_enable(module="slurry_blender")
    import slurry_blender
    expect(os.path.realpath(slurry_blender.__file__).startswith(os.path.realpath(user_scripts)),
           f"add-on installed under the temporary scripts folder: {slurry_blender.__file__}")
    expect(hasattr(bpy.ops.slurry, "import_directory") and hasattr(bpy.ops.slurry, "run"), "operators registered")

    # 2. Import the CLI's output into an empty scene (no startup cube): Blender frame f shows frame f.
    scene = bpy.context.scene
    for obj in list(scene.objects):
        bpy.data.objects.remove(obj)
    t0 = time.time()
    result = bpy.ops.slurry.import_directory(directory=directory, start_frame=0, up_axis="AUTO")
    expect(result == {"FINISHED"}, f"import finished ({time.time() - t0:.2f} s)")
    objects = {o.name: o for o in scene.objects}
    for name in ("particles", "surface", "colliders", "surface_vdb"):
        expect(name in objects, f"object {name} imported")
    particles, surface, colliders, volume = (objects[n] for n in ("particles", "surface", "colliders", "surface_vdb"))
    expect(scene.frame_start == 0 and scene.frame_end == frames, f"frame range {scene.frame_start}..{scene.frame_end}")

    # 3. Every frame: counts as declared, attributes as written (in Z-up), the VDB of that frame.
    for f in range(frames + 1):
        scene.frame_set(f)
        tag = f"{f:04d}"
        expected = header_counts(os.path.join(directory, f"frame_{tag}.ply"))
        mesh = particles.data
        expect(len(mesh.vertices) == expected["vertex"] and len(mesh.polygons) == 0,
               f"frame {f}: particles {len(mesh.vertices)} vertices, {expected['vertex']} written")
        cols = read_vertex_columns(os.path.join(directory, f"frame_{tag}.ply"))
        n = len(mesh.vertices)
        co = np.empty(3 * n, np.float32)
        mesh.vertices.foreach_get("co", co)
        vel = mesh.attributes.get("velocity")
        ids = mesh.attributes.get("id")
        expect(vel is not None and vel.data_type == "FLOAT_VECTOR" and vel.domain == "POINT",
               f"frame {f}: particles have a point FLOAT_VECTOR velocity")
        expect(ids is not None and ids.data_type == "INT" and ids.domain == "POINT", f"frame {f}: particles have INT id")
        v = np.empty(3 * n, np.float32)
        vel.data.foreach_get("vector", v)
        i = np.empty(n, np.int32)
        ids.data.foreach_get("value", i)
        # The scene is Y-up: Blender's (x, y, z) is the file's (x, -z, y).
        expect(np.array_equal(co.reshape(-1, 3), np.column_stack([cols["x"], -cols["z"], cols["y"]])),
               f"frame {f}: positions are the file's, turned Z-up")
        expect(np.array_equal(v.reshape(-1, 3), np.column_stack([cols["vx"], -cols["vz"], cols["vy"]])),
               f"frame {f}: velocities are the file's m/s, turned Z-up (max |v| {np.abs(v).max():.3f})")
        expect(np.array_equal(i, cols["id"].astype(np.int32)), f"frame {f}: ids are the file's, row by row")
        for obj, stem in ((surface, "surface"), (colliders, "colliders")):
            expected = header_counts(os.path.join(directory, f"{stem}_{tag}.ply"))
            m = obj.data
            expect(len(m.vertices) == expected["vertex"] and len(m.polygons) == expected["face"],
                   f"frame {f}: {stem} {len(m.vertices)} vertices, {len(m.polygons)} faces; "
                   f"{expected['vertex']}, {expected['face']} written")
            a = m.attributes.get("velocity")
            expect(a is not None and a.data_type == "FLOAT_VECTOR" and a.domain == "POINT", f"frame {f}: {stem} velocity")
        expect(colliders.data.attributes.get("collider") is not None, f"frame {f}: colliders have the face attribute collider")
        grids = volume.data.grids
        grids.load()
        expect(os.path.basename(grids.frame_filepath) == f"surface_{tag}.vdb",
               f"frame {f}: the volume reads {os.path.basename(grids.frame_filepath)}")
        names = {g.name for g in grids}
        expect({"surface", "velocity"} <= names and volume.data.velocity_grid == "velocity",
               f"frame {f}: volume grids {sorted(names)}, velocity grid {volume.data.velocity_grid}")

    # 3b. One surface per material: a mesh and a volume object per liquid, counts per frame.
    check_materials(scene, materials_dir, out)

    # 4. Motion blur from the velocity attribute: one frame, 64 x 48, Cycles CPU.
    for coll in bpy.data.collections:
        if coll.get("slurry_directory") != directory:
            coll.hide_render = True
    f = frames
    scene.frame_set(f)
    particles.hide_render = True
    colliders.hide_render = True
    lo = np.array([min(v.co[k] for v in surface.data.vertices) for k in range(3)])
    hi = np.array([max(v.co[k] for v in surface.data.vertices) for k in range(3)])
    centre, size = (lo + hi) / 2, float(max(hi - lo))
    cam = bpy.data.objects.new("camera", bpy.data.cameras.new("camera"))
    scene.collection.objects.link(cam)
    cam.location = centre + np.array([0.0, -1.6 * size, 0.5 * size])
    from mathutils import Vector
    cam.rotation_euler = (Vector(centre) - cam.location).to_track_quat("-Z", "Y").to_euler()
    scene.camera = cam
    sun = bpy.data.objects.new("sun", bpy.data.lights.new("sun", "SUN"))
    sun.data.energy = 4.0
    sun.rotation_euler = (0.6, 0.2, 0.4)
    scene.collection.objects.link(sun)
    world = bpy.data.worlds.new("world")
    world.color = (0.8, 0.8, 0.8)
    scene.world = world
    scene.render.engine = "CYCLES"
    scene.cycles.device = "CPU"
    scene.cycles.samples = 8
    scene.cycles.use_denoising = False
    scene.cycles.seed = 1
    scene.render.resolution_x, scene.render.resolution_y, scene.render.resolution_percentage = 64, 48, 100
    scene.render.image_settings.file_format = "PNG"
    scene.render.image_settings.color_depth = "16"
    # A shutter of 4 frames: the liquid moves a few pixels while it is open.
    scene.render.motion_blur_shutter = 4.0

    def render(name, blur):
        scene.render.use_motion_blur = blur
        scene.render.filepath = os.path.join(out, name)
        t = time.time()
        bpy.ops.render.render(write_still=True)
        print(f"rendered {name} in {time.time() - t:.2f} s")
        return pixels(scene.render.filepath)

    sharp = render("sharp.png", False)
    blurred = render("blurred.png", True)
    velocity = surface.data.attributes["velocity"]
    saved = np.empty(3 * len(velocity.data), np.float32)
    velocity.data.foreach_get("vector", saved)
    velocity.data.foreach_set("vector", np.zeros_like(saved))
    still = render("blur_without_velocity.png", True)
    velocity.data.foreach_set("vector", saved)
    moved = float(np.abs(blurred - sharp).mean())
    unmoved = float(np.abs(still - sharp).mean())
    changed = float((np.abs(blurred - sharp).max(axis=1) > 0.02).mean())
    print(f"pixel difference: blur on {moved:.5f} (mean |diff|, {100 * changed:.1f} % of pixels > 0.02), "
          f"blur on without velocities {unmoved:.5f}")
    expect(moved > 0.002 and changed > 0.01, f"motion blur changes the picture: mean {moved:.5f}, {100 * changed:.1f} % of pixels")
    expect(unmoved < 0.25 * moved, f"without the velocity attribute the blur is gone: {unmoved:.5f} < 0.25 x {moved:.5f}")

    # 5. The panel's Run, blocking, through the slurry module.
    if module_dir:
        prefs = bpy.context.preferences.addons["slurry_blender"].preferences
        prefs.module_folder = module_dir
        settings = scene.slurry
        settings.scene_file = os.path.abspath(run_scene)
        settings.cache_dir = os.path.join(out, "cache")
        settings.frames = 2
        settings.threads = 2
        settings.start_frame = 1
        before = set(bpy.data.collections.keys())
        t = time.time()
        result = bpy.ops.slurry.run(blocking=True)
        expect(result == {"FINISHED"}, f"Run finished ({time.time() - t:.1f} s)")
        run_dir = os.path.join(out, "cache", os.path.splitext(os.path.basename(run_scene))[0])
        expect(os.path.isfile(os.path.join(run_dir, "frame_0002.ply")), f"Run wrote {run_dir}/frame_0002.ply")
        (new,) = set(bpy.data.collections.keys()) - before
        names = {o.name.split(".")[0] for o in bpy.data.collections[new].objects}
        expect({"particles", "surface"} <= names, f"Run imported {sorted(names)}")
        scene.frame_set(3)
        (parts,) = [o for o in bpy.data.collections[new].objects if o.name.startswith("particles")]
        expected = header_counts(os.path.join(run_dir, "frame_0002.ply"))
        expect(len(parts.data.vertices) == expected["vertex"], f"Blender frame 3 shows frame 2: {len(parts.data.vertices)} particles")

        check_run_ticks(scene, os.path.join(out, "cache_ticks"), run_scene)


main()
