"""Slurry output directories as animated Blender objects.

What a directory holds (docs/pipeline-outputs.md) and what it becomes, in one collection:
  frame_NNNN.ply      "particles": a mesh of vertices only, with the point attributes `velocity`
                      (FLOAT_VECTOR) and `id` (INT) and every other column (J, plastic: FLOAT;
                      material: INT); a Geometry Nodes modifier turns the vertices into points
                      of a radius so that Cycles renders them.
  surface_NNNN.ply    "surface": the liquid's triangle mesh with its vertex `velocity`
  (or .obj)           (the OBJ has none), shaded smooth.
  surface_NNNN.vdb    "surface_vdb": a volume object reading the sequence (is_sequence), its
                      `velocity` grid set as the volume's motion-blur grid (unit: seconds).
  surface_<material>_NNNN.ply (or .obj), .vdb
                      "surface_<material>", "surface_<material>_vdb": the same, one pair of
                      objects per liquid material (output.surface_per_material).
  colliders_NNNN.ply  "colliders": the colliders' mesh with vertex `velocity` and the face
  (or .obj)           attribute `collider` (the index in the scene's `colliders`).
  points_NNNN.vdb     not imported: Blender 3.4 loads voxel grids only and refuses OpenVDB
                      points; the particles come from frame_NNNN.ply, with the same columns.
The mesh objects change data on every frame change (a persistent frame_change_pre handler):
each frame's mesh is read once, when first shown, and kept as its own datablock. A surface has no
file for a frame without its liquid (the CLI writes none for an empty group): that frame shows an
empty mesh, where the particles and colliders hold their nearest earlier file.

Units and axes: Slurry writes metres and m/s; one Blender unit is one metre, and Cycles reads a
mesh's or point cloud's `velocity` attribute in units per second (it scales it by the shutter
time over the scene's frame rate), so velocities are stored as written. Files are Y-up (the
simulation's axes) unless the scene sets output.up_axis "z"; Y-up data is turned to Blender's
Z-up once, as it is read, by (x, y, z) -> (x, -z, y) for positions and velocities alike (a
rotation by +90 degrees about x, the one output.up_axis "z" applies), and the VDB volume,
whose voxels are not rewritten, gets that rotation as its object transform.
"""
import hashlib
import json
import os
import re

import bpy
import numpy as np
from bpy.app.handlers import persistent

from . import ply

SEQUENCE_KEY = "slurry_sequence"
# frame_0001.ply, surface_0001.vdb, surface_water_0001.ply (a material's surface: the name is
# everything between "surface_" and the last "_NNNN"), colliders_0001.obj, points_0001.vdb.
_PATTERN = re.compile(r"^(frame|surface|colliders|points)(?:_(.+))?_(\d{4,})\.(ply|obj|vdb)$")


def scan(directory):
    """{kind: {frame number: path}} for kinds frame, surface (.ply preferred to .obj), surface_vdb,
    colliders (.ply preferred) and points_vdb, and under "materials" {material: {"surface": ...,
    "surface_vdb": ...}} for the per-material surfaces."""
    found = {"frame": {}, "surface": {}, "surface_vdb": {}, "colliders": {}, "points_vdb": {}, "materials": {}}
    for name in sorted(os.listdir(directory)):
        m = _PATTERN.match(name)
        if not m:
            continue
        stem, label, number, ext = m.group(1), m.group(2), int(m.group(3)), m.group(4)
        if label is not None and stem != "surface":
            continue
        path = os.path.join(directory, name)
        if label is not None:
            into = found["materials"].setdefault(label, {"surface": {}, "surface_vdb": {}})
        else:
            into = found
        if ext == "vdb":
            if stem in ("surface", "points"):
                into[stem + "_vdb"][number] = path
            continue
        if stem == "frame" and ext == "ply":
            into["frame"][number] = path
        elif stem in ("surface", "colliders") and (ext == "ply" or number not in into[stem]):
            into[stem][number] = path
    return found


def has_files(found):
    return any(found[k] for k in ("frame", "surface", "surface_vdb", "colliders")) or any(
        any(m.values()) for m in found["materials"].values())


def last_frame(found):
    """The largest frame number of any file the importer reads."""
    numbers = [n for k in ("frame", "surface", "surface_vdb", "colliders") for n in found[k]]
    numbers += [n for m in found["materials"].values() for files in m.values() for n in files]
    return max(numbers) if numbers else 0


def frame_comment(path):
    """The Slurry comment of a particle frame ("slurry flip frame t=... source=..."), or ""."""
    for c in ply.read_header(path)[1]:
        if c.startswith("slurry "):
            return c
    return ""


def detect_up_axis(directory, frames):
    """"y" or "z": the output.up_axis of the scene a frame names (its comment's source=), read from
    that file if it can be found (as named, or from the directory and its parents); "y" otherwise."""
    if not frames:
        return "y"
    m = re.search(r"source=(\S+)", frame_comment(frames[min(frames)]))
    if not m:
        return "y"
    source = m.group(1)
    candidates = [source] if os.path.isabs(source) else []
    d = os.path.abspath(directory)
    while not os.path.isabs(source):
        candidates.append(os.path.join(d, source))
        parent = os.path.dirname(d)
        if parent == d:
            break
        d = parent
    for c in candidates:
        if os.path.isfile(c):
            try:
                with open(c) as f:
                    return str(json.load(f).get("output", {}).get("up_axis", "y"))
            except (OSError, ValueError, AttributeError):
                return "y"
    return "y"


def frame_rate(frames):
    """Frames per second from frame 1's time (t=...), or None."""
    if 1 not in frames:
        return None
    m = re.search(r"\bt=([0-9.eE+-]+)", frame_comment(frames[1]))
    if not m or float(m.group(1)) <= 0:
        return None
    return 1.0 / float(m.group(1))


def _to_z_up(xyz):
    return np.column_stack([xyz[:, 0], -xyz[:, 2], xyz[:, 1]])


def _vectors(columns, names, z_up):
    if not all(n in columns for n in names[:2]):
        return None
    cols = [np.asarray(columns[n], np.float32) if n in columns else np.zeros(len(columns[names[0]]), np.float32)
            for n in names]
    xyz = np.column_stack(cols)
    return _to_z_up(xyz) if z_up else xyz


def read_obj(path):
    """(vertices (n, 3), face counts, flat indices) of an OBJ file Slurry wrote (v and f lines)."""
    verts, counts, flat = [], [], []
    with open(path) as f:
        for line in f:
            if line.startswith("v "):
                verts.append([float(x) for x in line.split()[1:4]])
            elif line.startswith("f "):
                idx = [int(w.split("/")[0]) - 1 for w in line.split()[1:]]
                counts.append(len(idx))
                flat.extend(idx)
    return np.array(verts, np.float32).reshape(-1, 3), np.array(counts, np.int64), np.array(flat, np.int64)


def build_mesh(name, path, kind, z_up):
    """A new mesh datablock from one file: positions in Blender's axes, attributes as in the
    module's docstring."""
    mesh = bpy.data.meshes.new(name)
    point_attrs, face_attrs = {}, {}
    counts = flat = None
    if path.endswith(".obj"):
        co, counts, flat = read_obj(path)
        if z_up:  # the OBJ files have the axes of the frames, as the PLY files
            co = _to_z_up(co)
    else:
        _, elements = ply.read_ply(path)
        v = elements["vertex"]
        co = _vectors(v.columns, ("x", "y", "z"), z_up)
        vel = _vectors(v.columns, ("vx", "vy", "vz"), z_up)
        if vel is not None:
            point_attrs["velocity"] = ("FLOAT_VECTOR", vel)
        for n, col in v.columns.items():
            if n in ("x", "y", "z", "vx", "vy", "vz"):
                continue
            point_attrs[n] = ("INT" if col.dtype.kind in "iu" else "FLOAT", col)
        face = elements.get("face")
        if face is not None and "vertex_indices" in face.lists:
            counts, flat = face.lists["vertex_indices"]
            for n, col in face.columns.items():
                face_attrs[n] = ("INT" if col.dtype.kind in "iu" else "FLOAT", col)
    n = len(co)
    mesh.vertices.add(n)
    mesh.vertices.foreach_set("co", np.ascontiguousarray(co, np.float32).ravel())
    if counts is not None and len(counts):
        mesh.loops.add(len(flat))
        mesh.loops.foreach_set("vertex_index", flat.astype(np.int32))
        mesh.polygons.add(len(counts))
        starts = np.zeros(len(counts), np.int32)
        starts[1:] = np.cumsum(counts[:-1])
        mesh.polygons.foreach_set("loop_start", starts)
        mesh.polygons.foreach_set("loop_total", counts.astype(np.int32))
        if kind == "surface":
            mesh.polygons.foreach_set("use_smooth", np.ones(len(counts), bool))
    for attr_name, (dtype, values) in point_attrs.items():
        _set_attribute(mesh, attr_name, dtype, "POINT", values)
    for attr_name, (dtype, values) in face_attrs.items():
        _set_attribute(mesh, attr_name, dtype, "FACE", values)
    mesh.update(calc_edges=True)
    mesh["slurry_file"] = path
    mesh["slurry_mtime"] = str(os.stat(path).st_mtime_ns)
    return mesh


def _set_attribute(mesh, name, dtype, domain, values):
    attr = mesh.attributes.new(name, dtype, domain)
    if dtype == "FLOAT_VECTOR":
        attr.data.foreach_set("vector", np.ascontiguousarray(values, np.float32).ravel())
    elif dtype == "INT":
        # ids are uint32 in the file; Blender's INT is int32 (ids stay below 2^31).
        attr.data.foreach_set("value", np.asarray(values).astype(np.int32))
    else:
        attr.data.foreach_set("value", np.asarray(values, np.float32))


def _sequence(obj):
    raw = obj.get(SEQUENCE_KEY)
    return json.loads(raw) if raw else None


def sequence_frame(seq, scene_frame):
    """The file frame shown at a Blender frame: frame - start, held at the first and last files
    (and at the last file before it where one is missing). A sequence with "last" (the surfaces)
    instead shows None, an empty mesh, at a frame in 0..last that has no file of its own, and
    frame 0 and `last` before and after the run."""
    numbers = seq["frames"]
    target = scene_frame - seq["start"]
    if "last" in seq:
        target = min(max(target, 0), seq["last"])
        return target if str(target) in seq["files"] else None
    best = numbers[0]
    for n in numbers:
        if n <= target:
            best = n
    return best


def mesh_for(seq, number):
    """The mesh of one file of a sequence, read once and kept (re-read if the file changed); an
    empty mesh for number None."""
    if number is None:
        name = f"{seq['key']}_empty"
        mesh = bpy.data.meshes.get(name) or bpy.data.meshes.new(name)
        if len(mesh.materials) == 0:
            for m in seq.get("materials", []):
                mat = bpy.data.materials.get(m)
                if mat is not None:
                    mesh.materials.append(mat)
        return mesh
    path = os.path.join(seq["dir"], seq["files"][str(number)])
    name = f"{seq['key']}_{number:04d}"
    mesh = bpy.data.meshes.get(name)
    if mesh is not None:
        try:
            if mesh.get("slurry_mtime") == str(os.stat(path).st_mtime_ns):
                return mesh
        except OSError:
            return mesh
        mesh.name = name + "_old"
        if mesh.users == 0:
            bpy.data.meshes.remove(mesh)
    mesh = build_mesh(name, path, seq["kind"], seq["z_up"])
    for m in seq.get("materials", []):
        mat = bpy.data.materials.get(m)
        if mat is not None:
            mesh.materials.append(mat)
    return mesh


def update_object(obj, scene_frame):
    seq = _sequence(obj)
    if not seq or obj.type != "MESH":
        return
    mesh = mesh_for(seq, sequence_frame(seq, scene_frame))
    if obj.data != mesh:
        # Materials the user gave the object's previous mesh follow it to the new one.
        if obj.data is not None and len(mesh.materials) == 0:
            for m in obj.data.materials:
                mesh.materials.append(m)
        obj.data = mesh


@persistent
def on_frame_change(scene, depsgraph=None):
    """Shows each sequence's mesh of the scene's current frame. Cycles' motion-blur steps set
    subframes (frame_set(f, 0.25) ...): the nearest whole frame's mesh is kept for those."""
    frame = int(np.floor(scene.frame_current + scene.frame_subframe + 0.5))
    for obj in scene.objects:
        if SEQUENCE_KEY in obj:
            update_object(obj, frame)


def register_handler():
    handlers = bpy.app.handlers.frame_change_pre
    for h in list(handlers):
        if getattr(h, "__name__", "") == on_frame_change.__name__ and getattr(h, "__module__", "") == __name__:
            handlers.remove(h)
    handlers.append(on_frame_change)


def unregister_handler():
    handlers = bpy.app.handlers.frame_change_pre
    for h in list(handlers):
        if getattr(h, "__name__", "") == on_frame_change.__name__ and getattr(h, "__module__", "") == __name__:
            handlers.remove(h)


def _material(name, colour, roughness, transmission=0.0):
    mat = bpy.data.materials.get(name)
    if mat is not None:
        return mat
    mat = bpy.data.materials.new(name)
    mat.use_nodes = True
    bsdf = mat.node_tree.nodes.get("Principled BSDF")
    if bsdf is not None:
        bsdf.inputs["Base Color"].default_value = colour
        bsdf.inputs["Roughness"].default_value = roughness
        bsdf.inputs["Transmission"].default_value = transmission
    mat.diffuse_color = colour
    return mat


def _points_node_group(radius):
    """Geometry Nodes: Mesh to Points of a radius, so that Cycles renders the particles as a point
    cloud (its attributes, velocity among them, are kept)."""
    ng = bpy.data.node_groups.new("Slurry particles to points", "GeometryNodeTree")
    ng.inputs.new("NodeSocketGeometry", "Geometry")
    ng.outputs.new("NodeSocketGeometry", "Geometry")
    group_in = ng.nodes.new("NodeGroupInput")
    group_out = ng.nodes.new("NodeGroupOutput")
    to_points = ng.nodes.new("GeometryNodeMeshToPoints")
    to_points.inputs["Radius"].default_value = radius
    ng.links.new(group_in.outputs[0], to_points.inputs["Mesh"])
    ng.links.new(to_points.outputs["Points"], group_out.inputs[0])
    return ng


# Surface colours of the per-material surfaces, in the order of their names: water's blue first.
_PALETTE = [(0.15, 0.45, 0.85, 1.0), (0.85, 0.35, 0.12, 1.0), (0.2, 0.7, 0.3, 1.0), (0.75, 0.2, 0.6, 1.0),
            (0.85, 0.75, 0.15, 1.0), (0.3, 0.3, 0.3, 1.0)]


def _velocity_grid(vol):
    """Names the volume's `velocity` grid as its motion-blur grid if the first file has one.
    Blender checks the name against the loaded grids and reports an error for one it cannot
    find (also for any name before the grids are loaded), so the grids are loaded first; a
    scene written without velocities has no such grid and keeps Blender's default."""
    if not vol.grids.load():
        return False
    if vol.grids.get("velocity") is None:
        return False
    vol.velocity_grid = "velocity"
    vol.velocity_unit = "SECOND"
    vol.velocity_scale = 1.0
    return True


def import_directory(context, directory, start=1, up_axis="AUTO", particles=True, surface=True, volume=True,
                     colliders=True, particle_radius=0.01, set_scene=True):
    """Imports a Slurry output directory into a new collection. Returns (collection, {object name:
    object}, notes), notes being lines for the user about files left out. `start` is the Blender
    frame that shows frame 0. Raises ValueError if the directory holds no Slurry file."""
    directory = os.path.abspath(bpy.path.abspath(directory))
    found = scan(directory)
    if not has_files(found):
        raise ValueError(f"{directory}: no frame_NNNN.ply, surface_NNNN.*, surface_<material>_NNNN.* "
                         f"or colliders_NNNN.* files")
    axis = detect_up_axis(directory, found["frame"]) if up_axis == "AUTO" else up_axis.lower()
    z_up = axis != "z"  # the data is turned to Z-up when the files are Y-up
    last = last_frame(found)
    scene = context.scene
    collection = bpy.data.collections.new(f"Slurry {os.path.basename(directory)}")
    scene.collection.children.link(collection)
    digest = hashlib.sha1(directory.encode()).hexdigest()[:8]
    made = {}
    notes = []

    def sequence_object(kind, files, label, materials=()):
        seq = {"dir": directory, "kind": kind, "start": start, "z_up": z_up, "frames": sorted(files),
               "files": {str(n): os.path.basename(p) for n, p in files.items()},
               "key": f"slurry_{digest}_{label}", "materials": list(materials)}
        if kind == "surface":
            seq["last"] = last
        obj = bpy.data.objects.new(label, mesh_for(seq, sequence_frame(seq, start)))
        obj[SEQUENCE_KEY] = json.dumps(seq)
        collection.objects.link(obj)
        made[label] = obj
        return obj

    def volume_object(files, label, hidden):
        numbers = sorted(files)
        vol = bpy.data.volumes.new(f"slurry_{digest}_{label}")
        vol.filepath = files[numbers[0]]
        vol.is_sequence = True
        # Blender reads file number (frame - frame_start + 1 + frame_offset): frame start + k
        # shows file k.
        vol.frame_start = start
        vol.frame_offset = -1
        vol.frame_duration = numbers[-1] + 1
        vol.sequence_mode = "EXTEND"
        _velocity_grid(vol)
        obj = bpy.data.objects.new(label, vol)
        if z_up:
            obj.rotation_euler = (np.pi / 2, 0.0, 0.0)
        # The level set is for meshing (a Volume to Mesh modifier) or shading; the mesh renders.
        obj.hide_render = hidden
        collection.objects.link(obj)
        made[label] = obj
        return obj

    if particles and found["frame"]:
        obj = sequence_object("points", found["frame"], "particles")
        mod = obj.modifiers.new("Slurry points", "NODES")
        mod.node_group = _points_node_group(particle_radius)
    if surface and found["surface"]:
        water = _material("Slurry water", _PALETTE[0], 0.1)
        sequence_object("surface", found["surface"], "surface", [water.name])
    for k, name in enumerate(sorted(found["materials"])):
        if surface and found["materials"][name]["surface"]:
            mat = _material(f"Slurry {name}", _PALETTE[k % len(_PALETTE)], 0.1)
            sequence_object("surface", found["materials"][name]["surface"], f"surface_{name}", [mat.name])
    if colliders and found["colliders"]:
        solid = _material("Slurry collider", (0.6, 0.55, 0.5, 1.0), 0.5)
        sequence_object("colliders", found["colliders"], "colliders", [solid.name])
    if volume and found["surface_vdb"]:
        volume_object(found["surface_vdb"], "surface_vdb", bool(found["surface"]) and surface)
    for name in sorted(found["materials"]):
        files = found["materials"][name]
        if volume and files["surface_vdb"]:
            volume_object(files["surface_vdb"], f"surface_{name}_vdb", bool(files["surface"]) and surface)
    if found["points_vdb"]:
        notes.append(f"points_NNNN.vdb not imported ({len(found['points_vdb'])} files): Blender 3.4 loads "
                     f"voxel grids only, not OpenVDB points; the particles come from frame_NNNN.ply")
    if set_scene:
        scene.frame_start = start
        scene.frame_end = start + last
        fps = frame_rate(found["frame"])
        if fps:
            scene.render.fps = max(1, int(round(fps)))
            scene.render.fps_base = scene.render.fps / fps
        # The handler replaces meshes while a render evaluates other frames: rendering with a
        # locked interface keeps the viewport from drawing them meanwhile.
        scene.render.use_lock_interface = True
    collection["slurry_directory"] = directory
    collection["slurry_up_axis"] = axis
    register_handler()
    on_frame_change(scene)
    return collection, made, notes
