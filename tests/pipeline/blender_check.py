# A real client of Slurry's effects-pipeline files: Blender (Debian's blender 3.4), headless.
#
#   blender -b --factory-startup --python-exit-code 1 -P blender_check.py -- DIR FRAME OUT.png [WIDTH HEIGHT SAMPLES]
#
# Imports DIR/frame_FRAME.ply (particles, as vertices), DIR/surface_FRAME.ply and .obj (the
# surface mesh) and DIR/surface_FRAME.vdb (the level set, as a volume object); asserts that
# Blender sees the vertex and face counts the PLY headers Slurry wrote declare, that the OBJ
# holds the same mesh, that the volume holds one float grid named "surface", and that Blender's
# own meshing of that grid (Volume to Mesh modifier at threshold 0, adaptivity 0, the grid's own
# voxels) has exactly the vertices of Slurry's mesh and one face per triangle or quad, i.e. that
# it read the same voxels. Then renders a small Cycles CPU picture to OUT.png. Any failed
# assertion raises, and --python-exit-code 1 makes Blender exit with 1.
import os
import sys

import bpy


def ply_header_counts(path):
    """Element counts from a PLY header (what Slurry wrote)."""
    counts = {}
    with open(path, "rb") as f:
        if f.readline().strip() != b"ply":
            raise AssertionError(f"{path}: not a PLY file")
        for raw in f:
            line = raw.decode("ascii").strip()
            if line.startswith("element "):
                _, name, n = line.split()
                counts[name] = int(n)
            if line == "end_header":
                return counts
    raise AssertionError(f"{path}: no end_header")


def expect(cond, message):
    if not cond:
        raise AssertionError(message)
    print("ok:", message)


def new_objects(before):
    return [o for o in bpy.context.scene.objects if o.name not in before]


def material(name, colour, roughness):
    """A material of one Principled BSDF (nodes made here: the empty factory startup has no defaults)."""
    m = bpy.data.materials.new(name)
    m.use_nodes = True
    nodes = m.node_tree.nodes
    nodes.clear()
    bsdf = nodes.new("ShaderNodeBsdfPrincipled")
    bsdf.inputs["Base Color"].default_value = colour
    bsdf.inputs["Roughness"].default_value = roughness
    out = nodes.new("ShaderNodeOutputMaterial")
    m.node_tree.links.new(bsdf.outputs["BSDF"], out.inputs["Surface"])
    return m


def main():
    argv = sys.argv[sys.argv.index("--") + 1:]
    directory, frame, out_png = argv[0], int(argv[1]), argv[2]
    width, height, samples = (int(a) for a in argv[3:6]) if len(argv) >= 6 else (160, 120, 8)
    tag = f"{frame:04d}"
    points_ply = os.path.join(directory, f"frame_{tag}.ply")
    mesh_ply = os.path.join(directory, f"surface_{tag}.ply")
    mesh_obj = os.path.join(directory, f"surface_{tag}.obj")
    vdb = os.path.join(directory, f"surface_{tag}.vdb")

    bpy.ops.wm.read_factory_settings(use_empty=True)

    # 1. The particle frame: Blender's PLY importer makes one vertex per particle (no faces).
    expected = ply_header_counts(points_ply)
    before = {o.name for o in bpy.context.scene.objects}
    bpy.ops.import_mesh.ply(filepath=points_ply)
    (points,) = new_objects(before)
    expect(len(points.data.vertices) == expected["vertex"],
           f"particle frame: {len(points.data.vertices)} vertices in Blender, {expected['vertex']} written")

    # 2. The surface mesh, PLY: vertices and triangles as declared.
    expected = ply_header_counts(mesh_ply)
    before = {o.name for o in bpy.context.scene.objects}
    bpy.ops.import_mesh.ply(filepath=mesh_ply)
    (surface,) = new_objects(before)
    mesh = surface.data
    expect(len(mesh.vertices) == expected["vertex"], f"surface PLY: {len(mesh.vertices)} vertices, {expected['vertex']} written")
    expect(len(mesh.polygons) == expected["face"], f"surface PLY: {len(mesh.polygons)} faces, {expected['face']} written")
    expect(all(len(p.vertices) == 3 for p in mesh.polygons), "surface PLY: every face a triangle")

    # 3. The same mesh as OBJ (Blender's importer may merge nothing: keep the vertex order).
    before = {o.name for o in bpy.context.scene.objects}
    bpy.ops.import_scene.obj(filepath=mesh_obj, split_mode="OFF", axis_forward="Y", axis_up="Z")
    (obj_surface,) = new_objects(before)
    expect(len(obj_surface.data.vertices) == expected["vertex"], f"surface OBJ: {len(obj_surface.data.vertices)} vertices")
    expect(len(obj_surface.data.polygons) == expected["face"], f"surface OBJ: {len(obj_surface.data.polygons)} faces")
    obj_surface.hide_render = True

    # 4. The level set: a volume object with the float grid "surface".
    before = {o.name for o in bpy.context.scene.objects}
    bpy.ops.object.volume_import(filepath=vdb, files=[{"name": os.path.basename(vdb)}], directory=directory)
    (volume,) = new_objects(before)
    volume.data.grids.load()
    names = [g.name for g in volume.data.grids]
    expect("surface" in names and set(names) <= {"surface", "velocity"}, f"VDB: grids {names}")
    by_name = {g.name: g for g in volume.data.grids}
    expect(by_name["surface"].data_type == "FLOAT", f"VDB: grid type {by_name['surface'].data_type}")
    if "velocity" in by_name:
        expect(by_name["velocity"].data_type == "VECTOR_FLOAT", f"VDB: velocity grid type {by_name['velocity'].data_type}")
        # The documented motion-blur path (docs/pipeline-outputs.md): the volume's velocity grid.
        volume.data.velocity_grid = "velocity"
        volume.data.velocity_unit = "SECOND"
        expect(volume.data.velocity_grid == "velocity", "VDB: velocity_grid not set")
    # Blender meshes the grid itself: the level set is the distance to Slurry's mesh, so the
    # zero level Blender finds encloses the same volume, within 10 % (droplets smaller than a
    # voxel are in the mesh only).
    holder = bpy.data.objects.new("vdb_mesh", bpy.data.meshes.new("vdb_mesh"))
    bpy.context.scene.collection.objects.link(holder)
    mod = holder.modifiers.new("to_mesh", "VOLUME_TO_MESH")
    mod.object = volume
    mod.grid_name = "surface"
    mod.resolution_mode = "GRID"
    mod.threshold = 0.0
    mod.adaptivity = 0.0
    evaluated = holder.evaluated_get(bpy.context.evaluated_depsgraph_get())
    vdb_mesh = evaluated.to_mesh()
    def enclosed(m):
        total = 0.0
        for p in m.polygons:
            v = [m.vertices[i].co for i in p.vertices]
            for k in range(1, len(v) - 1):
                total += v[0].dot(v[k].cross(v[k + 1])) / 6.0
        return abs(total)
    vdb_volume, mesh_volume = enclosed(vdb_mesh), enclosed(mesh)
    expect(len(vdb_mesh.polygons) > 0, "VDB meshed by Blender: no faces")
    expect(0.9 * mesh_volume <= vdb_volume <= 1.1 * mesh_volume,
           f"VDB meshed by Blender encloses {vdb_volume:.6g} m^3, Slurry's mesh {mesh_volume:.6g} m^3")
    evaluated.to_mesh_clear()
    holder.hide_render = True
    volume.hide_render = True

    # 5. A small Cycles CPU render of the surface (water-like) over the particles (small dots).
    scene = bpy.context.scene
    scene.render.engine = "CYCLES"
    scene.cycles.device = "CPU"
    scene.cycles.samples = samples
    scene.cycles.use_denoising = False
    scene.render.resolution_x, scene.render.resolution_y = width, height
    scene.render.resolution_percentage = 100
    scene.render.filepath = out_png
    scene.render.image_settings.file_format = "PNG"
    mesh.materials.append(material("water", (0.15, 0.45, 0.85, 1.0), 0.15))
    for p in mesh.polygons:
        p.use_smooth = True
    points.hide_render = True
    # Axes: the engine's y is up; Blender's z is. Rotate the imported surface to stand upright.
    surface.rotation_euler = (1.5707963, 0.0, 0.0)
    lo = [min(v.co[i] for v in mesh.vertices) for i in range(3)]
    hi = [max(v.co[i] for v in mesh.vertices) for i in range(3)]
    centre = [(a + b) / 2 for a, b in zip(lo, hi)]
    size = max(b - a for a, b in zip(lo, hi))
    target = (centre[0], -centre[2], centre[1])  # (x, y, z) -> (x, -z, y) by the rotation above
    bpy.ops.mesh.primitive_plane_add(size=20 * size, location=(target[0], target[1], lo[1]))
    bpy.context.object.data.materials.append(material("floor", (0.8, 0.8, 0.75, 1.0), 0.6))
    cam_data = bpy.data.cameras.new("camera")
    cam = bpy.data.objects.new("camera", cam_data)
    scene.collection.objects.link(cam)
    cam.location = (target[0] + 1.6 * size, target[1] - 2.2 * size, target[2] + 1.3 * size)
    direction = [t - c for t, c in zip(target, cam.location)]
    from mathutils import Vector
    cam.rotation_euler = Vector(direction).to_track_quat("-Z", "Y").to_euler()
    scene.camera = cam
    sun = bpy.data.objects.new("sun", bpy.data.lights.new("sun", "SUN"))
    sun.data.energy = 4.0
    sun.rotation_euler = (0.7, 0.2, 0.6)
    scene.collection.objects.link(sun)
    world = bpy.data.worlds.new("world")
    world.use_nodes = True
    world.node_tree.nodes.clear()
    background = world.node_tree.nodes.new("ShaderNodeBackground")
    background.inputs["Color"].default_value = (0.6, 0.7, 0.85, 1.0)
    world_out = world.node_tree.nodes.new("ShaderNodeOutputWorld")
    world.node_tree.links.new(background.outputs["Background"], world_out.inputs["Surface"])
    scene.world = world
    bpy.ops.render.render(write_still=True)
    expect(os.path.getsize(out_png) > 1000, f"rendered {out_png} ({os.path.getsize(out_png)} bytes)")


main()
