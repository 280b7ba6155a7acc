# Windowed check of what an artist sees (issue 12): the LARAP panel with a handle's Empty active,
# Pose waiting for a click (handle vertices shown, the one under the cursor highlighted, the
# status-bar text after a miss), and the overlay after an undo (the rest lattice, labelled).
# Needs a display and simulated events, e.g.
#   blender -b --factory-startup --python-expr "import bpy; bpy.ops.wm.save_as_mainfile(filepath='/tmp/start.blend')"
#   xvfb-run -a -s "-screen 0 1600x1000x24" blender /tmp/start.blend --enable-event-simulate \
#       --python scripts/screenshot_artist_checks.py -- OUTDIR
# Writes OUTDIR/panel-empty.png, pose-waiting.png, pose-miss.png, overlay-after-undo.png.
import os
import sys

import bpy
import numpy as np
from mathutils import Vector

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
for p in (HERE, os.path.join(ROOT, "addon"), os.path.join(ROOT, "python")):
    sys.path.insert(0, p)

from blender_window import frame_view, override, posed_suzanne, run_steps, screenshot, show_larap_tab, view3d  # noqa: E402

OUT = os.path.abspath(sys.argv[sys.argv.index("--") + 1]) if "--" in sys.argv else "/tmp/larap-checks"
os.makedirs(OUT, exist_ok=True)
STATE = {}


def shot(name):
    screenshot(OUT, name)


def window_xy(world):
    from bpy_extras.view3d_utils import location_3d_to_region_2d
    win, area, region = view3d()
    p = location_3d_to_region_2d(region, area.spaces.active.region_3d, world)
    return int(region.x + p.x), int(region.y + p.y)


def activate(ob):
    for o in bpy.context.view_layer.objects:
        o.select_set(False)
    bpy.context.view_layer.objects.active = ob
    ob.select_set(True)


# -- the steps, one per timer tick (the window redraws between them)

def step_panel_empty():
    obj = STATE["obj"]
    activate(obj.larap.handles[0].target)
    return 1.5


def step_shoot_panel():
    shot("panel-empty.png")
    activate(STATE["obj"])
    return 0.5


def step_pose_invoke():
    obj = STATE["obj"]
    obj.larap.show_overlay = False  # Pose shows the handle vertices by itself
    with override():
        print("pose:", bpy.ops.larap.pose("INVOKE_DEFAULT"))
    return 0.5


def step_pose_hover():
    obj = STATE["obj"]
    from larap_blender import core
    pts, owner = core.handle_points(obj)
    chin = Vector(pts[owner == 1].mean(axis=0))
    win = view3d()[0]
    x, y = window_xy(chin)
    win.event_simulate(type="MOUSEMOVE", value="NOTHING", x=x, y=y)
    return 1.0


def step_shoot_pose():
    shot("pose-waiting.png")
    win, area, region = view3d()
    x, y = region.x + 60, region.y + region.height - 120  # far from any handle
    win.event_simulate(type="MOUSEMOVE", value="NOTHING", x=x, y=y)
    win.event_simulate(type="LEFTMOUSE", value="PRESS", x=x, y=y)
    win.event_simulate(type="LEFTMOUSE", value="RELEASE", x=x, y=y)
    return 1.0


def step_shoot_miss():
    shot("pose-miss.png")
    win, area, region = view3d()
    win.event_simulate(type="ESC", value="PRESS", x=region.x + 60, y=region.y + 60)
    win.event_simulate(type="ESC", value="RELEASE", x=region.x + 60, y=region.y + 60)
    return 0.5


def step_undo():
    obj = STATE["obj"]
    obj.larap.show_overlay = True
    top = obj.larap.handles[0].target
    print("Top Empty before:", tuple(top.location), tuple(top.rotation_euler))
    with override():
        bpy.ops.larap.solve("EXEC_DEFAULT", True)  # the posed state, as an undo step
        top.location.z += 0.4
        bpy.ops.ed.undo_push(message="move the Empty")
        bpy.ops.larap.solve("EXEC_DEFAULT", True)
        bpy.context.window_manager.print_undo_steps()
        bpy.ops.ed.undo()  # back to "move the Empty": the key of the earlier pose, the engine's lattice gone
    return 1.5


def step_redraw():
    bpy.context.view_layer.update()
    view3d()[1].tag_redraw()
    return 1.5


def step_shoot_undo():
    obj = bpy.data.objects[STATE["name"]]
    dg = bpy.context.evaluated_depsgraph_get()
    ev = obj.evaluated_get(dg).data
    a = np.empty(len(ev.vertices) * 3)
    ev.vertices.foreach_get("co", a)
    k = np.empty(len(obj.data.vertices) * 3)
    obj.data.shape_keys.key_blocks["LARAP"].data.foreach_get("co", k)
    b = np.empty(len(obj.data.vertices) * 3)
    obj.data.shape_keys.key_blocks["Basis"].data.foreach_get("co", b)
    print("evaluated vs pose key: %.3g, pose key vs rest: %.3g" % (np.abs(a - k).max(), np.abs(k - b).max()))
    from larap_blender import core, overlay
    print("overlay after undo:", overlay.lattice_state(obj, core.runtime(obj)))
    bpy.context.window_manager.print_undo_steps()
    top = obj.larap.handles[0].target
    print("Top Empty after undo:", tuple(top.location), tuple(top.rotation_euler))
    view3d()[1].tag_redraw()
    return 1.5


def step_shoot_undone():
    shot("overlay-after-undo.png")
    return 0.5


STEPS = [step_panel_empty, step_shoot_panel, step_pose_invoke, step_pose_hover, step_shoot_pose, step_shoot_miss,
         step_undo, step_redraw, step_shoot_undo, step_shoot_undone]


def start():
    obj = posed_suzanne(subdivisions=1, cells=2000)
    STATE["obj"], STATE["name"] = obj, obj.name
    show_larap_tab()
    frame_view(obj)
    run_steps(STEPS, first_interval=2.0)
    return None


bpy.app.timers.register(start, first_interval=1.0)
