# Renders one frame of a Slurry output directory through the add-on, headless:
#
#   blender -b --factory-startup -P blender/render_frame.py -- DIR FRAME OUT.png [WIDTH HEIGHT SAMPLES]
#
# Uses the installed add-on if Blender has it enabled, else the one beside this script. Imports
# DIR (Blender frame f shows frame f), hides the particles, puts the surface and colliders on a
# floor under a sun and sky, frames the camera on the surface, and renders with Cycles on the CPU
# with motion blur from the velocity attributes (shutter half a frame).
import os
import sys

import bpy
from mathutils import Vector

argv = sys.argv[sys.argv.index("--") + 1:]
directory, frame, out = os.path.abspath(argv[0]), int(argv[1]), os.path.abspath(argv[2])
width, height, samples = (int(a) for a in argv[3:6]) if len(argv) >= 6 else (400, 250, 16)

try:
    import slurry_blender
except ImportError:
    sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
    import slurry_blender
if not hasattr(bpy.types.Scene, "slurry"):
    slurry_blender.register()

scene = bpy.context.scene
for obj in list(scene.objects):
    bpy.data.objects.remove(obj)
bpy.ops.slurry.import_directory(directory=directory, start_frame=0)
scene.frame_set(frame)
objects = {o.name: o for o in scene.objects}
objects["particles"].hide_render = True
surface = objects["surface"]
lo = Vector([min(v.co[k] for v in surface.data.vertices) for k in range(3)])
hi = Vector([max(v.co[k] for v in surface.data.vertices) for k in range(3)])
centre, size = (lo + hi) / 2, max(hi - lo)
bpy.ops.mesh.primitive_plane_add(size=20 * size, location=(centre.x, centre.y, lo.z))
floor = bpy.data.materials.new("floor")
floor.diffuse_color = (0.8, 0.8, 0.75, 1.0)
floor.use_nodes = True
floor.node_tree.nodes["Principled BSDF"].inputs["Base Color"].default_value = (0.8, 0.8, 0.75, 1.0)
bpy.context.object.data.materials.append(floor)
cam = bpy.data.objects.new("camera", bpy.data.cameras.new("camera"))
scene.collection.objects.link(cam)
cam.location = centre + Vector((0.6 * size, -1.6 * size, 0.9 * size))
cam.rotation_euler = (centre - cam.location).to_track_quat("-Z", "Y").to_euler()
scene.camera = cam
sun = bpy.data.objects.new("sun", bpy.data.lights.new("sun", "SUN"))
sun.data.energy = 4.0
sun.rotation_euler = (0.7, 0.2, 0.6)
scene.collection.objects.link(sun)
world = bpy.data.worlds.new("world")
world.color = (0.6, 0.7, 0.85)
scene.world = world
scene.render.engine = "CYCLES"
scene.cycles.device = "CPU"
scene.cycles.samples = samples
scene.cycles.use_denoising = False
scene.render.use_motion_blur = True
scene.render.resolution_x, scene.render.resolution_y, scene.render.resolution_percentage = width, height, 100
scene.render.image_settings.file_format = "PNG"
scene.render.filepath = out
bpy.ops.render.render(write_still=True)
