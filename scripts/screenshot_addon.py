# Screenshot of the add-on at work (for the README): a subdivided Suzanne bound by LARAP, its top
# handle moved, the lattice overlay on, the LARAP sidebar tab open. Needs a display, e.g.
#   blender -b --factory-startup --python-expr "import bpy; bpy.ops.wm.save_as_mainfile(filepath='/tmp/start.blend')"
#   xvfb-run -s "-screen 0 1600x900x24" blender /tmp/start.blend --python scripts/screenshot_addon.py -- OUT.png
# (opening a file skips the splash screen).
import math
import os
import sys

import addon_utils
import bpy
import numpy as np
from mathutils import Matrix, Vector

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
for p in (os.path.join(ROOT, "addon"), os.path.join(ROOT, "python")):
    sys.path.insert(0, p)
OUT = os.path.abspath(sys.argv[sys.argv.index("--") + 1]) if "--" in sys.argv else "/tmp/larap-addon.png"


def setup():
    for ob in list(bpy.data.objects):
        bpy.data.objects.remove(ob)
    assert addon_utils.enable("larap_blender", default_set=True) is not None
    bpy.ops.mesh.primitive_monkey_add()
    obj = bpy.context.object
    mod = obj.modifiers.new("sub", "SUBSURF")
    mod.levels = 2
    bpy.ops.object.modifier_apply(modifier="sub")
    bpy.ops.object.shade_smooth()
    co = np.empty(len(obj.data.vertices) * 3)
    obj.data.vertices.foreach_get("co", co)
    co = co.reshape(-1, 3)
    z = co[:, 2]
    for name, ids in (("Top", np.flatnonzero(z > z.max() - 0.25)), ("Chin", np.flatnonzero(z < z.min() + 0.25))):
        g = obj.vertex_groups.new(name=name)
        g.add(ids.tolist(), 1.0, "REPLACE")
        bpy.ops.larap.handle_add(vertex_group=name)
    bpy.context.view_layer.objects.active = obj
    obj.select_set(True)
    bpy.ops.larap.bind()
    top = obj.larap.handles[0].target
    top.matrix_world = (Matrix.Translation(Vector((0.35, 0.0, 0.1))) @ Matrix.Rotation(math.radians(25), 4, "Y")
                        @ top.matrix_world)
    bpy.ops.larap.solve()
    if hasattr(obj.larap, "show_overlay"):
        obj.larap.show_overlay = True
    return obj


def show_larap_tab():
    # Blender 3.4 cannot switch sidebar tabs from Python: show the LARAP panels in the "Item" tab
    # (this throwaway session only) instead of the Transform panel.
    from larap_blender import ui

    transform = getattr(bpy.types, "VIEW3D_PT_transform", None)
    if transform is not None:
        bpy.utils.unregister_class(transform)
    for cls in (ui.VIEW3D_PT_larap, ui.VIEW3D_PT_larap_settings):
        bpy.utils.unregister_class(cls)
        cls.bl_category = "Item"
        bpy.utils.register_class(cls)


def frame_view(obj):
    from mathutils import Euler

    for area in bpy.context.screen.areas:
        if area.type == "VIEW_3D":
            space = area.spaces.active
            space.show_region_ui = True
            space.shading.type = "SOLID"
            r3d = space.region_3d
            r3d.view_rotation = Euler((math.radians(72), 0.0, math.radians(-35))).to_quaternion()
            r3d.view_location = obj.matrix_world.translation + Vector((0.15, 0.0, 0.0))
            r3d.view_distance = 6.5


def shoot():
    bpy.ops.screen.screenshot(filepath=OUT)
    print("wrote", OUT)
    bpy.ops.wm.quit_blender()


obj = setup()
show_larap_tab()
frame_view(obj)
bpy.app.timers.register(shoot, first_interval=3.0)
