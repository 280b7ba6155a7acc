# SPDX-License-Identifier: GPL-3.0-or-later
# A small animated shot for the farm bake tests and scripts/bench_farm.py, saved to a .blend:
#   blender -b --factory-startup --python-exit-code 1 --python tests/blender/farm_scene.py -- OUT.blend \
#       [--rings 41] [--frames 12] [--cells 1000] [--bind]
# Two bars ("Bar", "Bar.R" with --two) along X; vertex groups at both ends follow two Empties; the
# right Empty rises and turns over the frames (linear keys), so every frame is a different pose.
# Without --bind the handles are set up but not bound (the farm's bind task binds them).
import argparse
import math
import os
import sys

import bpy
import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
sys.path.insert(0, os.path.join(ROOT, "python"))
from larap.farm._blender import enable_addon  # noqa: E402


def bar(name, rings, segments=16, length=4.0, radius=0.25, offset=(0.0, 0.0, 0.0)):
    xs = np.linspace(-length / 2, length / 2, rings)
    ang = np.linspace(0, 2 * math.pi, segments, endpoint=False)
    verts = [(x + offset[0], radius * math.cos(a) + offset[1], radius * math.sin(a) + offset[2])
             for x in xs for a in ang]
    faces = [(r * segments + s, r * segments + (s + 1) % segments, (r + 1) * segments + (s + 1) % segments,
              (r + 1) * segments + s) for r in range(rings - 1) for s in range(segments)]
    faces.append(tuple(reversed(range(segments))))
    faces.append(tuple((rings - 1) * segments + s for s in range(segments)))
    me = bpy.data.meshes.new(name)
    me.from_pydata(verts, [], faces)
    me.update()
    obj = bpy.data.objects.new(name, me)
    bpy.context.scene.collection.objects.link(obj)
    return obj, np.array(verts)


def rig(core, obj, rest, frames, cells, phase=0.0):
    x = rest[:, 0]
    for side, sel in (("Left", x < x.min() + 0.2), ("Right", x > x.max() - 0.2)):
        vg = obj.vertex_groups.new(name=side)
        vg.add([int(i) for i in np.flatnonzero(sel)], 1.0, "REPLACE")
        core.add_handle(obj, vertex_group=side)
    obj.larap.resolution_mode = "CELLS"
    obj.larap.cells = cells
    obj.larap.iterations = 10
    empty = obj.larap.handles[1].target
    z0 = empty.location.z
    for f in range(1, frames + 1):
        t = (f - 1) / max(1, frames - 1)
        empty.location.z = z0 + 1.2 * t
        empty.rotation_euler.x = phase + 1.0 * t
        empty.keyframe_insert("location", frame=f)
        empty.keyframe_insert("rotation_euler", frame=f)
    for fc in empty.animation_data.action.fcurves:
        for kp in fc.keyframe_points:
            kp.interpolation = "LINEAR"


def main():
    argv = sys.argv[sys.argv.index("--") + 1:] if "--" in sys.argv else []
    p = argparse.ArgumentParser()
    p.add_argument("out")
    p.add_argument("--rings", type=int, default=41)
    p.add_argument("--frames", type=int, default=12)
    p.add_argument("--cells", type=int, default=1000)
    p.add_argument("--two", action="store_true")
    p.add_argument("--bind", action="store_true")
    a = p.parse_args(argv)
    bpy.ops.wm.read_factory_settings(use_empty=True)
    core = enable_addon(os.path.join(ROOT, "addon"))
    scene = bpy.context.scene
    scene.frame_start, scene.frame_end = 1, a.frames
    objs = [bar("Bar", a.rings)]
    if a.two:
        objs.append(bar("Bar.R", a.rings, offset=(0.0, 1.5, 0.0)))
    for i, (obj, rest) in enumerate(objs):
        bpy.context.view_layer.objects.active = obj
        rig(core, obj, rest, a.frames, a.cells, phase=0.3 * i)
    scene.frame_set(1)
    if a.bind:
        for obj, _ in objs:
            core.bind(obj)
    bpy.ops.wm.save_as_mainfile(filepath=os.path.abspath(a.out), compress=False)
    print("farm_scene: saved", a.out)


main()
