# Windowed check of a wire mesh (loose edges only) posed through the add-on: a stick figure with a
# Skin modifier (the way artists block out creatures), bound with its spine, right hand and feet
# held by Empties and its left hand's Empty turned 80 degrees up about the shoulder.
# Needs a display, e.g.
#   blender -b --factory-startup --python-expr "import bpy; bpy.ops.wm.save_as_mainfile(filepath='/tmp/start.blend')"
#   xvfb-run -a -s "-screen 0 1600x1000x24" blender /tmp/start.blend --python scripts/screenshot_skin_wire.py -- OUTDIR
# Writes OUTDIR/skin-wire-rest.png and OUTDIR/skin-wire-raised.png, and prints the edges' stretch.
import math
import os
import sys

import bpy
import numpy as np
from mathutils import Euler, Matrix, Vector

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
for p in (HERE, os.path.join(ROOT, "addon"), os.path.join(ROOT, "python")):
    sys.path.insert(0, p)

from blender_window import override, run_steps, screenshot, show_larap_tab, view3d  # noqa: E402

OUT = os.path.abspath(sys.argv[sys.argv.index("--") + 1]) if "--" in sys.argv else "/tmp/larap-checks"
os.makedirs(OUT, exist_ok=True)
STATE = {}


def shot(name):
    screenshot(OUT, name)


def stretch(obj):
    me = obj.data
    e = np.empty(len(me.edges) * 2, np.int64)
    me.edges.foreach_get("vertices", e)
    e = e.reshape(-1, 2)
    n = len(me.vertices)
    rest, key = np.empty(3 * n), np.empty(3 * n)
    me.shape_keys.reference_key.data.foreach_get("co", rest)
    me.shape_keys.key_blocks["LARAP"].data.foreach_get("co", key)
    rest, key = rest.reshape(n, 3), key.reshape(n, 3)
    return np.linalg.norm(key[e[:, 0]] - key[e[:, 1]], axis=1) / np.linalg.norm(rest[e[:, 0]] - rest[e[:, 1]], axis=1)


def build():
    import addon_utils
    addon_utils.enable("larap_blender", default_set=True)
    from larap import shapes
    for o in list(bpy.data.objects):
        bpy.data.objects.remove(o)
    V, F, limbs = shapes.stick_figure()
    me = bpy.data.meshes.new("Figure")
    me.from_pydata([tuple(map(float, v)) for v in V], [tuple(map(int, e)) for e in F], [])
    obj = bpy.data.objects.new("Figure", me)
    bpy.context.scene.collection.objects.link(obj)
    bpy.context.view_layer.objects.active = obj
    obj.select_set(True)
    skin = obj.modifiers.new("Skin", "SKIN")
    for sv in me.skin_vertices[0].data:
        sv.radius = (0.07, 0.07)
    obj.modifiers.new("Subdivision", "SUBSURF").levels = 1
    groups = {"Spine": limbs["spine"], "LeftHand": limbs["left_arm"][-2:], "RightHand": limbs["right_arm"][-2:],
              "LeftFoot": limbs["left_leg"][-2:], "RightFoot": limbs["right_leg"][-2:]}
    for name, ids in groups.items():
        obj.vertex_groups.new(name=name).add([int(i) for i in ids], 1.0, "REPLACE")
        assert bpy.ops.larap.handle_add(vertex_group=name) == {"FINISHED"}
    assert bpy.ops.larap.bind() == {"FINISHED"}
    spine = V[limbs["spine"]]
    STATE.update(obj=obj, shoulder=Vector(spine[np.argmin(np.linalg.norm(spine - V[limbs["left_arm"][0]], axis=1))]))
    show_larap_tab()
    space = view3d()[1].spaces.active
    space.show_region_ui = True
    space.shading.type = "SOLID"
    r3d = space.region_3d
    r3d.view_rotation = Euler((math.radians(80), 0.0, math.radians(90))).to_quaternion()
    r3d.view_location = Vector((0.0, 0.0, 1.5))
    r3d.view_distance = 6.0
    return 1.5


def raise_arm():
    obj, s = STATE["obj"], STATE["shoulder"]
    hand = obj.larap.handles[1].target
    hand.matrix_world = Matrix.Translation(s) @ Matrix.Rotation(math.radians(80), 4, "X") @ Matrix.Translation(-s) @ hand.matrix_world
    bpy.context.view_layer.objects.active = obj
    with override():
        assert bpy.ops.larap.solve() == {"FINISHED"}
    st = stretch(obj)
    print("edges' stretch: min %.3f max %.3f; lattice components %d" % (st.min(), st.max(),
          __import__("larap_blender").core.runtime(obj).deformer.num_components))
    return 1.5


run_steps([build, lambda: (shot("skin-wire-rest.png"), 0.5)[1], raise_arm,
           lambda: (shot("skin-wire-raised.png"), 0.5)[1]])
