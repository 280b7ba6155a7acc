# SPDX-License-Identifier: GPL-3.0-or-later
"""What a live move costs in a Blender window, with the GPU preview on and off (issue 11).

Run (a real window; Xvfb and software OpenGL are enough):
  xvfb-run -a -s "-screen 0 1280x800x24" blender --factory-startup --python scripts/bench_preview.py -- \\
      [--sizes 100000 1000000 4000000] [--repeats 5] [--picture docs/preview-1m.png] [--out docs/results-blender.md]

For each size, a closed quad tube (4 x 0.5 units, so the same lattice at every size) with two
handle groups (its ends, about 5% of the vertices each) is bound with the default lattice, Live
on. The cost a live move adds = the median time of (move the right handle's Empty, depsgraph
update with the live solve, one redraw of the 3D View region) minus the median time of one redraw with
nothing moved; with the preview on (the lattice posed, the mesh drawn from it) and off (the pose
key written and re-evaluated, as before). Also: the catch-up (final solve + write) once the
moves pause. Prints a table and appends it (markdown + a JSON line) to the results file; with
--picture, saves the 3D View showing the preview at the size nearest 1M vertices.
"""
import argparse
import datetime
import json
import os
import statistics
import sys
import time
import traceback

import bpy
import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
for _p in (HERE, os.path.join(ROOT, "addon"), os.environ.get("LARAP_ENGINE_PATH") or os.path.join(ROOT, "python")):
    if _p not in sys.path:
        sys.path.insert(0, _p)

import blender_mesh  # noqa: E402
from blender_window import view3d  # noqa: E402
import machine_info  # noqa: E402


def parse_args():
    argv = sys.argv[sys.argv.index("--") + 1:] if "--" in sys.argv else []
    p = argparse.ArgumentParser(prog="bench_preview.py")
    p.add_argument("--sizes", type=int, nargs="+", default=[100000, 1000000, 4000000])
    p.add_argument("--repeats", type=int, default=5)
    p.add_argument("--picture", default="")
    p.add_argument("--out", default=os.path.join(ROOT, "docs", "results-blender.md"))
    return p.parse_args(argv)


ARGS = parse_args()


def tube(name, n_target):
    """The closed quad tube (4 x 0.5 units) of about n_target vertices, rings of
    sqrt(n_target / 4) vertices (at least 64)."""
    segments = int(max(64, round((n_target / 4.0) ** 0.5)))
    return blender_mesh.quad_tube(name, n_target, segments, smooth=True)


def redraw():
    win, area, region = view3d()
    with bpy.context.temp_override(window=win, area=area, region=region):
        t0 = time.perf_counter()
        bpy.ops.wm.redraw_timer(type="DRAW", iterations=1)  # the 3D View region only
        return (time.perf_counter() - t0) * 1e3


def picture(path):
    win, area, region = view3d()
    shot = path + ".full.png"
    with bpy.context.temp_override(window=win, area=area, region=region):
        bpy.ops.screen.screenshot(filepath=shot, check_existing=False)
    img = bpy.data.images.load(shot, check_existing=False)
    w, h = img.size
    px = np.empty(w * h * 4, dtype=np.float32)
    img.pixels.foreach_get(px)
    bpy.data.images.remove(img)
    os.remove(shot)
    crop = px.reshape(h, w, 4)[region.y:region.y + region.height, region.x:region.x + region.width].copy()
    out = bpy.data.images.new("larap_preview", region.width, region.height)
    out.pixels.foreach_set(crop.ravel())
    out.filepath_raw = path
    out.file_format = "PNG"
    out.save()
    bpy.data.images.remove(out)


def bench(n):
    from larap_blender import catchup, core, preview
    for obj in list(bpy.data.objects):
        bpy.data.objects.remove(obj)
    for me in list(bpy.data.meshes):
        bpy.data.meshes.remove(me)
    obj, rest = tube("Tube", n)
    for name, idx in (("Left", np.flatnonzero(rest[:, 0] < -1.8)), ("Right", np.flatnonzero(rest[:, 0] > 1.8))):
        obj.vertex_groups.new(name=name).add(idx.tolist(), 1.0, "REPLACE")
    bpy.context.view_layer.objects.active = obj
    obj.select_set(True)
    assert bpy.ops.larap.handle_add(vertex_group="Left") == {"FINISHED"}
    assert bpy.ops.larap.handle_add(vertex_group="Right") == {"FINISHED"}
    t0 = time.perf_counter()
    assert bpy.ops.larap.bind() == {"FINISHED"}
    bind_ms = (time.perf_counter() - t0) * 1e3
    s = obj.larap
    s.live = True
    rt = core.runtime(obj)
    row = {"vertices": len(rest), "nodes": rt.deformer.num_nodes, "handles": int(sum(
        len(v) for v in core.membership(obj, rt).values())), "bind_ms": bind_ms}
    win, area, region = view3d()
    space = area.spaces.active
    space.overlay.show_overlays = False
    from mathutils import Euler
    r3d = space.region_3d
    r3d.view_perspective = "PERSP"
    r3d.view_location = (0.0, 0.0, 0.3)
    r3d.view_rotation = Euler((1.3, 0.0, 0.2)).to_quaternion()
    r3d.view_distance = 7.0
    target = s.handles[1].target
    sign = [1.0]

    def move():
        target.location.z += 0.05 * sign[0]
        target.rotation_euler.y -= 0.03 * sign[0]
        sign[0] = -sign[0] if abs(target.location.z) > 0.6 else sign[0]
        t0 = time.perf_counter()
        bpy.context.view_layer.update()  # the depsgraph update: Live solves here
        solve_ms = (time.perf_counter() - t0) * 1e3
        return solve_ms + redraw(), solve_ms

    for mode in ("on", "off"):
        s.preview = mode == "on"
        target.location.z += 0.3
        move()  # warm up (first preview draw uploads the binding)
        redraw()
        if mode == "on":
            row["preview_blocker"] = preview.blocker(obj)
            row["preview_showing"] = preview.showing(obj)
            if ARGS.picture and n == min(ARGS.sizes, key=lambda m: abs(m - 1000000)):
                picture(os.path.abspath(ARGS.picture))
                row["picture"] = ARGS.picture
        idle = [redraw() for _ in range(ARGS.repeats)]
        moves = [move() for _ in range(ARGS.repeats)]
        row["redraw_%s_ms" % mode] = statistics.median(idle)
        row["move_%s_ms" % mode] = statistics.median(m[0] for m in moves)
        row["update_%s_ms" % mode] = statistics.median(m[1] for m in moves)
        row["added_%s_ms" % mode] = row["move_%s_ms" % mode] - row["redraw_%s_ms" % mode]
        t0 = time.perf_counter()
        catchup.catch_up_all()
        row["catchup_%s_ms" % mode] = (time.perf_counter() - t0) * 1e3
        print("LARAP bench_preview %d vertices, preview %s: %s" % (len(rest), mode, json.dumps(row)))
        sys.stdout.flush()
    return row


def report(rows):
    import gpu
    info = {"date": datetime.datetime.now().strftime("%Y-%m-%d %H:%M"), "machine": machine_info.describe(),
            "blender": bpy.app.version_string, "gl": "%s %s" % (gpu.platform.renderer_get(), gpu.platform.version_get()),
            "repeats": ARGS.repeats, "rows": rows}
    lines = ["", "## %s: live move in a window, GPU preview on/off (scripts/bench_preview.py)" % info["date"], "",
             "%s; Blender %s, %s; device cpu, default lattice, 2 handle groups (the tube's ends), median of %d."
             % (info["machine"], info["blender"], info["gl"], ARGS.repeats), "",
             "| vertices | lattice nodes | handle vertices | redraw ms (preview off) | live move adds, preview off ms "
             "| live move adds, preview on ms | of it depsgraph + solve, preview on ms | catch-up ms |",
             "|---|---|---|---|---|---|---|---|"]
    for r in rows:
        lines.append("| %d | %d | %d | %.0f | %.1f | %.1f | %.1f | %.0f |" % (
            r["vertices"], r["nodes"], r["handles"], r["redraw_off_ms"], r["added_off_ms"], r["added_on_ms"],
            r["update_on_ms"], r["catchup_on_ms"]))
    lines += ["", "<!-- json: %s -->" % json.dumps(info), ""]
    text = "\n".join(lines)
    print(text)
    if ARGS.out:
        with open(ARGS.out, "a") as f:
            f.write(text)


STATE = {"k": 0, "rows": []}


def step():
    try:
        if STATE["k"] == 0:
            STATE["k"] = 1
            bpy.ops.wm.read_homefile(use_factory_startup=True)  # closes the splash screen
            return 0.3
        if STATE["k"] == 1:
            import addon_utils
            import larap  # noqa: F401
            addon_utils.enable("larap_blender", default_set=True)
            STATE["k"] = 2
            return 0.2
        i = STATE["k"] - 2
        if i < len(ARGS.sizes):
            STATE["rows"].append(bench(ARGS.sizes[i]))
            STATE["k"] += 1
            return 0.2
        report(STATE["rows"])
        code = 0
    except Exception:
        traceback.print_exc()
        code = 1
    sys.stdout.flush()
    os._exit(code)


bpy.app.timers.register(step, first_interval=0.5, persistent=True)
