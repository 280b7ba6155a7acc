# Renders meshes to a PNG with Blender's Workbench engine (headless):
#   blender -b --factory-startup --python-exit-code 1 --python scripts/render_pose.py -- OUT.png A.obj [B.obj ...]
# Each mesh is placed side by side along x; the camera frames them all.
import os
import sys

import bpy
import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "python"))
import larap  # noqa: E402

args = sys.argv[sys.argv.index("--") + 1:]
out, paths = os.path.abspath(args[0]), args[1:]
bpy.ops.wm.read_factory_settings(use_empty=True)
scene = bpy.context.scene
offset = 0.0
lo, hi = np.full(3, np.inf), np.full(3, -np.inf)
for k, path in enumerate(paths):
    V, F = larap.load_mesh(path)
    V = V - [V[:, 0].min() - offset, 0, 0]
    faces = F.tolist() if isinstance(F, np.ndarray) else [f.tolist() for f in F]
    me = bpy.data.meshes.new(os.path.basename(path))
    me.from_pydata(V.tolist(), [], faces)
    me.update()
    for p in me.polygons:
        p.use_smooth = True
    ob = bpy.data.objects.new(me.name, me)
    scene.collection.objects.link(ob)
    offset = V[:, 0].max() + 0.3 * (V[:, 0].max() - V[:, 0].min())
    lo, hi = np.minimum(lo, V.min(0)), np.maximum(hi, V.max(0))
centre, size = (lo + hi) / 2, float(np.linalg.norm(hi - lo))
cam = bpy.data.objects.new("cam", bpy.data.cameras.new("cam"))
scene.collection.objects.link(cam)
cam.location = (centre[0], centre[1] - 1.5 * size, centre[2] + 0.7 * size)
direction = centre - np.array(cam.location)
cam.rotation_euler = __import__("mathutils").Vector(direction.tolist()).to_track_quat("-Z", "Y").to_euler()
scene.camera = cam
scene.render.engine = "BLENDER_WORKBENCH"
scene.display.shading.light = "STUDIO"
scene.display.shading.color_type = "SINGLE"
scene.render.resolution_x, scene.render.resolution_y = 960, 540
scene.render.filepath = out
bpy.ops.render.render(write_still=True)
print("wrote", out)
