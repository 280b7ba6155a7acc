# SPDX-License-Identifier: GPL-3.0-or-later
"""What the add-on costs per move in a large scene: one live tube among N other objects.

Run (--root: the checkout whose add-on and engine are loaded, default this one):
  blender -b --factory-startup --python-exit-code 1 --python scripts/bench_scene_size.py -- \
      [--sizes 1000 5000 20000] [--root CHECKOUT] [--repeats 15] [--out FILE | --no-write]
or in a window (Xvfb is enough), which also times the GPU preview's draw callback:
  xvfb-run -a -s "-screen 0 1280x800x24" blender --factory-startup --python scripts/bench_scene_size.py -- ...

The scene: a closed tube of about 20,000 vertices bound with two handles as an artist makes them
(vertex groups of its end rings, x < -1.6 and x > 1.6: 10% of its vertices each, following two
Empties), Live on, the default lattice; then N objects more, half Empties and half meshes sharing
one triangle (in a window, hidden with H, so that Blender's own drawing stays small while the
depsgraph still holds them). For each N, the
median and the largest over --repeats moves of:
  * the add-on's depsgraph handler when an Empty that drives nothing moves (Blender reports the
    move; the add-on must find that no live mesh follows it);
  * the same handler when a handle's Empty moves (the solve and, headless, the write of the pose
    key: the GPU preview, which writes nothing per move, needs a window);
  * the meshes a handle's Empty drives, as the sidebar asks at each redraw while it is active;
  * in a window: the preview's draw callback per redraw of the 3D View, the tube's pose shown;
  * Blender's own update for the unrelated move with the add-on disabled, for scale.
Prints a table and appends it (markdown) to docs/results-blender.md unless --no-write.
"""
import argparse
import datetime
import os
import statistics
import sys
import time
import types

import bpy
import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
import blender_mesh  # noqa: E402
import machine_info  # noqa: E402


def parse_args():
    argv = sys.argv[sys.argv.index("--") + 1:] if "--" in sys.argv else []
    p = argparse.ArgumentParser(prog="bench_scene_size.py")
    p.add_argument("--sizes", type=int, nargs="+", default=[1000, 5000, 20000])
    p.add_argument("--root", default=os.path.dirname(HERE), help="checkout whose addon/ and python/ are loaded")
    p.add_argument("--repeats", type=int, default=15)
    p.add_argument("--vertices", type=int, default=20000)
    p.add_argument("--out", default=os.path.join(os.path.dirname(HERE), "docs", "results-blender.md"))
    p.add_argument("--no-write", action="store_true")
    return p.parse_args(argv)


def enable(root):
    import addon_utils
    for path in (os.path.join(root, "addon"), os.path.join(root, "python")):
        sys.path.insert(0, os.path.abspath(path))
    if bpy.app.background:
        bpy.ops.wm.read_factory_settings(use_empty=True)
    else:  # reading the factory settings from a timer in a window makes Blender 3.4 crash at quit
        for obj in list(bpy.data.objects):
            bpy.data.objects.remove(obj)
    mod = addon_utils.enable("larap_blender", default_set=True)
    if mod is None or not hasattr(bpy.types.Object, "larap"):
        raise SystemExit("could not enable the larap_blender add-on from %s" % root)
    if not os.path.realpath(mod.__file__).startswith(os.path.realpath(root)):
        raise SystemExit("the add-on came from %s, not %s" % (mod.__file__, root))
    from larap_blender import core, engine, handlers
    if engine.get() is None:
        raise SystemExit(engine.error())
    return core, handlers


def timed_handler(handlers):
    """Put a timing wrapper in place of the add-on's depsgraph handler; returns its list of times."""
    times = []
    hl = bpy.app.handlers.depsgraph_update_post
    i = hl.index(handlers.larap_depsgraph_update_post)

    def wrapper(scene, depsgraph=None):
        t0 = time.perf_counter()
        handlers.larap_depsgraph_update_post(scene, depsgraph)
        times.append(time.perf_counter() - t0)
    hl[i] = wrapper

    def restore():
        hl[hl.index(wrapper)] = handlers.larap_depsgraph_update_post
    return times, restore


def setup(core, n_vertices):
    obj, rest = blender_mesh.quad_tube("LiveTube", n_vertices, 64)
    for name, idx in (("Left", np.flatnonzero(rest[:, 0] < -1.6)), ("Right", np.flatnonzero(rest[:, 0] > 1.6))):
        obj.vertex_groups.new(name=name).add(idx.tolist(), 1.0, "REPLACE")
    bpy.context.view_layer.objects.active = obj
    obj.select_set(True)
    core.add_handle(obj, vertex_group="Left")
    core.add_handle(obj, vertex_group="Right")
    core.bind(obj)
    obj.larap.live = True
    shares = [100.0 * np.count_nonzero(rest[:, 0] < -1.6) / len(rest),
              100.0 * np.count_nonzero(rest[:, 0] > 1.6) / len(rest)]
    return obj, [h.target for h in obj.larap.handles], len(rest), shares


def fill(scene, count, made):
    me = bpy.data.meshes.get("bench_triangle")
    if me is None:
        me = bpy.data.meshes.new("bench_triangle")
        me.from_pydata([(0, 0, 0), (0.1, 0, 0), (0, 0.1, 0)], [], [(0, 1, 2)])
    while made < count:
        o = bpy.data.objects.new("filler_%06d" % made, me if made % 2 else None)
        o.location = (made % 100 * 0.2, made // 100 % 100 * 0.2, 5.0 + made // 10000)
        scene.collection.objects.link(o)
        if not bpy.app.background:
            o.hide_set(True)  # hidden in the view layer, still evaluated (not Disable in Viewports)
        made += 1
    bpy.context.view_layer.update()
    return made


def median_ms(xs):
    return 1e3 * statistics.median(xs)


def spread(xs):
    """(median, largest) in ms."""
    return 1e3 * statistics.median(xs), 1e3 * max(xs)


def draw_times(repeats):
    """The preview's draw callback, timed over ``repeats`` redraws of the 3D View (None: no window
    or no preview showing)."""
    from larap_blender import preview
    if bpy.app.background or not preview._SHOWN:
        return None
    import blender_window
    win, area, region = blender_window.view3d()
    times = []
    bpy.types.SpaceView3D.draw_handler_remove(preview._DRAW_HANDLE, "WINDOW")

    def timed():
        t0 = time.perf_counter()
        preview.draw()
        times.append(time.perf_counter() - t0)
    preview._DRAW_HANDLE = bpy.types.SpaceView3D.draw_handler_add(timed, (), "WINDOW", "POST_VIEW")
    with bpy.context.temp_override(window=win, area=area, region=region):
        for _ in range(repeats):
            bpy.ops.wm.redraw_timer(type="DRAW", iterations=1)
    bpy.types.SpaceView3D.draw_handler_remove(preview._DRAW_HANDLE, "WINDOW")
    preview._DRAW_HANDLE = bpy.types.SpaceView3D.draw_handler_add(preview.draw, (), "WINDOW", "POST_VIEW")
    return spread(times) if times else None


def main():
    args = parse_args()
    core, handlers = enable(args.root)
    scene = bpy.context.scene
    obj, targets, n_vertices, shares = setup(core, args.vertices)
    times, restore = timed_handler(handlers)
    other = bpy.data.objects.new("unrelated", None)
    scene.collection.objects.link(other)
    rows, made = [], 0
    for n in sorted(args.sizes):
        made = fill(scene, n, made)
        for _ in range(3):  # settle: the first updates after the scene changed look everything up
            other.location.x += 0.01
            bpy.context.view_layer.update()
        times.clear()
        for _ in range(args.repeats):
            other.location.x += 0.01
            bpy.context.view_layer.update()
        unrelated = spread(times)
        times.clear()
        for _ in range(args.repeats):
            targets[1].location.z += 0.002
            bpy.context.view_layer.update()
        target = spread(times)
        draw = draw_times(args.repeats)
        ctx = types.SimpleNamespace(object=targets[1])  # the context the sidebar draws in, its target active
        panel = []
        for _ in range(args.repeats):
            t0 = time.perf_counter()
            driven = core.posed_meshes(ctx)
            panel.append(time.perf_counter() - t0)
        assert driven == [obj], driven
        rows.append(dict(objects=len(scene.objects), unrelated=unrelated, target=target, panel=spread(panel),
                         draw=draw))
        print("objects %6d: handler, unrelated move %.3f (max %.3f) ms; handler, target move %.2f (max %.2f) ms; "
              "driven meshes %.3f (max %.3f) ms%s" % (rows[-1]["objects"], *unrelated, *target, *rows[-1]["panel"],
                                                       "; preview draw %.3f (max %.3f) ms" % draw if draw else ""))
    restore()
    import addon_utils
    addon_utils.disable("larap_blender", default_set=True)
    off = []
    for _ in range(args.repeats):
        other.location.x += 0.01
        t0 = time.perf_counter()
        bpy.context.view_layer.update()
        off.append(time.perf_counter() - t0)
    report(args, rows, median_ms(off), n_vertices, shares)


def report(args, rows, off, n_vertices, shares):
    stamp = datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%d %H:%M UTC")
    lines = ["", "### Per move in a large scene (`scripts/bench_scene_size.py`, %s)" % stamp, "",
             "%s; Blender %s, %s; add-on from `%s`; a live tube of %d vertices, 2 handles "
             "(vertex groups of %.0f%% and %.0f%% of its vertices), median / largest of %d moves (ms):"
             % (machine_info.describe(), bpy.app.version_string,
                "headless" if bpy.app.background else "in a window (fillers hidden with H)", os.path.realpath(args.root),
                n_vertices, shares[0], shares[1], args.repeats), "",
             "| objects | add-on's handler, unrelated move | handler, target move: %s "
             "| meshes a target drives | preview's draw callback |"
             % ("solve and write" if bpy.app.background else "solve (the preview writes nothing)"),
             "|---|---|---|---|---|"]
    for r in rows:
        lines.append("| %d | %.3f / %.3f | %.2f / %.2f | %.3f / %.3f | %s |" % (
            r["objects"], *r["unrelated"], *r["target"], *r["panel"],
            "%.3f / %.3f" % r["draw"] if r["draw"] else "(headless)"))
    lines += ["", "Blender's own update for the unrelated move at %d objects, add-on disabled: %.2f ms."
              % (rows[-1]["objects"], off), ""]
    text = "\n".join(lines)
    print(text)
    if not args.no_write:
        with open(args.out, "a") as f:
            f.write(text)


if __name__ == "__main__":
    if bpy.app.background:
        main()
    else:  # in a window: once it is drawn, then quit
        def run():
            try:
                main()
            finally:
                bpy.ops.wm.quit_blender()
        bpy.app.timers.register(run, first_interval=1.0)
