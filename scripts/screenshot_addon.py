# Screenshot of the add-on at work (for the README): a subdivided Suzanne bound by LARAP, its top
# handle moved, the lattice overlay on, the LARAP sidebar tab open. Needs a display, e.g.
#   blender -b --factory-startup --python-expr "import bpy; bpy.ops.wm.save_as_mainfile(filepath='/tmp/start.blend')"
#   xvfb-run -s "-screen 0 1600x900x24" blender /tmp/start.blend --python scripts/screenshot_addon.py -- OUT.png
# (opening a file skips the splash screen).
import os
import sys

import bpy

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
for p in (HERE, os.path.join(ROOT, "addon"), os.path.join(ROOT, "python")):
    sys.path.insert(0, p)

from blender_window import frame_view, posed_suzanne, show_larap_tab  # noqa: E402

OUT = os.path.abspath(sys.argv[sys.argv.index("--") + 1]) if "--" in sys.argv else "/tmp/larap-addon.png"


def shoot():
    bpy.ops.screen.screenshot(filepath=OUT)
    print("wrote", OUT)
    bpy.ops.wm.quit_blender()


obj = posed_suzanne(subdivisions=2)
show_larap_tab()
frame_view(obj)
bpy.app.timers.register(shoot, first_interval=3.0)
