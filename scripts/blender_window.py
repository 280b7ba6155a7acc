# SPDX-License-Identifier: GPL-3.0-or-later
"""A Blender window's 3D View for the scripts that take pictures of the add-on at work
(screenshot_addon.py, screenshot_artist_checks.py, bench_preview.py): the 3D View and a context
for its operators, the LARAP panels shown in the sidebar, the posed Suzanne the screenshots show
and the view framing it. Runs inside Blender with a window (Xvfb is enough)."""
import math

import bpy
import numpy as np
from mathutils import Euler, Matrix, Vector


def view3d():
    """(window, area, region) of the first window's largest 3D View."""
    win = bpy.context.window_manager.windows[0]
    areas = [a for a in win.screen.areas if a.type == "VIEW_3D"]
    if not areas:
        raise RuntimeError("no 3D View")
    area = max(areas, key=lambda a: a.width * a.height)
    return win, area, next(r for r in area.regions if r.type == "WINDOW")


def override():
    """A context for operators that act on the 3D View (from a timer, where there is none)."""
    win, area, region = view3d()
    return bpy.context.temp_override(window=win, area=area, region=region)


def posed_suzanne(subdivisions, cells=0):
    """A Suzanne subdivided ``subdivisions`` times, with two handles (its top and chin vertex
    groups), bound (``cells``: lattice cells, 0: the add-on's default), its top handle moved and
    turned, solved, the LARAP overlay on. Every other object is removed first."""
    import addon_utils
    for ob in list(bpy.data.objects):
        bpy.data.objects.remove(ob)
    assert addon_utils.enable("larap_blender", default_set=True) is not None
    bpy.ops.mesh.primitive_monkey_add()
    obj = bpy.context.object
    mod = obj.modifiers.new("sub", "SUBSURF")
    mod.levels = subdivisions
    bpy.ops.object.modifier_apply(modifier="sub")
    bpy.ops.object.shade_smooth()
    co = np.empty(len(obj.data.vertices) * 3)
    obj.data.vertices.foreach_get("co", co)
    z = co.reshape(-1, 3)[:, 2]
    for name, ids in (("Top", np.flatnonzero(z > z.max() - 0.25)), ("Chin", np.flatnonzero(z < z.min() + 0.25))):
        obj.vertex_groups.new(name=name).add(ids.tolist(), 1.0, "REPLACE")
        with override():
            bpy.ops.larap.handle_add(vertex_group=name)
    bpy.context.view_layer.objects.active = obj
    obj.select_set(True)
    if cells:
        obj.larap.resolution_mode, obj.larap.cells = "CELLS", cells
    bpy.ops.larap.bind()
    top = obj.larap.handles[0].target
    top.matrix_world = (Matrix.Translation(Vector((0.35, 0.0, 0.1))) @ Matrix.Rotation(math.radians(25), 4, "Y")
                        @ top.matrix_world)
    bpy.ops.larap.solve()
    obj.larap.show_overlay = True
    return obj


def show_larap_tab():
    """The LARAP panels in the sidebar's "Item" tab instead of the Transform panel (Blender 3.4
    cannot switch sidebar tabs from Python; this throwaway session only)."""
    from larap_blender import ui
    transform = getattr(bpy.types, "VIEW3D_PT_transform", None)
    if transform is not None:
        bpy.utils.unregister_class(transform)
    for cls in (ui.VIEW3D_PT_larap, ui.VIEW3D_PT_larap_settings):
        bpy.utils.unregister_class(cls)
        cls.bl_category = "Item"
        bpy.utils.register_class(cls)


def frame_view(obj):
    """The 3D View in solid shading, sidebar open, looking at ``obj`` from the front left."""
    space = view3d()[1].spaces.active
    space.show_region_ui = True
    space.shading.type = "SOLID"
    r3d = space.region_3d
    r3d.view_rotation = Euler((math.radians(72), 0.0, math.radians(-35))).to_quaternion()
    r3d.view_location = obj.matrix_world.translation + Vector((0.15, 0.0, 0.0))
    r3d.view_distance = 6.5


def screenshot(out_dir, name):
    """The whole window into out_dir/name (a PNG); prints where."""
    import os
    path = os.path.join(out_dir, name)
    with override():
        bpy.ops.screen.screenshot(filepath=path)
    print("wrote", path)


def run_steps(steps, first_interval=1.0):
    """Runs `steps` (callables returning the seconds to wait before the next) one per timer tick,
    so that the window redraws between them; quits Blender after the last, or at an exception
    (printed)."""
    steps = list(steps)

    def tick():
        step = steps.pop(0)
        try:
            delay = step()
        except Exception:
            import traceback
            traceback.print_exc()
            bpy.ops.wm.quit_blender()
            return None
        if not steps:
            bpy.ops.wm.quit_blender()
            return None
        return delay

    bpy.app.timers.register(tick, first_interval=first_interval)

