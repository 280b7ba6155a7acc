# SPDX-License-Identifier: GPL-3.0-or-later
"""LARAP inside Blender vs Blender's Laplacian Deform modifier, on the same meshes and handles.

Run (headless):
  blender -b --factory-startup --python-exit-code 1 --python scripts/bench_blender.py -- \
      --sizes 100000 500000 1000000 [--laplacian-max 500000] [--repeats 5] [--device cpu]

For each size, a closed tube (quads, ~N vertices, 4 x 0.5 units) with two handle groups (its end
rings, x < -1.8 and x > 1.8) is timed for:
  * bind: larap.bind as the add-on does it (lattice + binding + shape keys + first solve);
  * live update: move a target, solve (interactive weights) + write the shape key + depsgraph
    evaluation, as the user sees it (depsgraph.update(); obj.evaluated_get(depsgraph));
  * Blender's share: writing the shape key + re-evaluating, with no solve;
  * Laplacian Deform (same mesh, anchors = both groups, a Hook moves the right group): bind
    (laplaciandeform_bind + evaluation) and one re-evaluation after moving the hook.
Prints a table and appends it (markdown + a JSON line) to docs/results-blender.md.
"""
import argparse
import datetime
import json
import os
import statistics
import sys
import time

import bpy
import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
sys.path.insert(0, HERE)
import blender_mesh  # noqa: E402
import machine_info  # noqa: E402


def parse_args():
    argv = sys.argv[sys.argv.index("--") + 1:] if "--" in sys.argv else []
    p = argparse.ArgumentParser(prog="bench_blender.py")
    p.add_argument("--sizes", type=int, nargs="+", default=[100000, 500000, 1000000])
    p.add_argument("--laplacian-max", type=int, default=500000,
                   help="skip Laplacian Deform above this many vertices (recorded as skipped)")
    p.add_argument("--repeats", type=int, default=5)
    p.add_argument("--iterations", type=int, default=5)
    p.add_argument("--device", default="cpu")
    p.add_argument("--cells", type=int, default=0, help="lattice cells (0: engine default)")
    p.add_argument("--out", default=os.path.join(ROOT, "docs", "results-blender.md"))
    p.add_argument("--no-write", action="store_true")
    return p.parse_args(argv)


def setup_paths():
    for path in (os.path.join(ROOT, "addon"), os.environ.get("LARAP_ENGINE_PATH") or os.path.join(ROOT, "python")):
        if path not in sys.path:
            sys.path.insert(0, path)
    try:
        import larap  # noqa: F401  (prefer the repo's fresh build over a vendored copy)
    except Exception as exc:
        print("engine from python/ not importable (%s); trying the add-on's own copy" % exc)


def enable_addon():
    import addon_utils
    bpy.ops.wm.read_factory_settings(use_empty=True)
    mod = addon_utils.enable("larap_blender", default_set=True)
    if mod is None or not hasattr(bpy.types.Object, "larap"):
        raise SystemExit("could not enable the larap_blender add-on")
    from larap_blender import core, engine
    if engine.get() is None:
        raise SystemExit(engine.error())
    return core, engine


def activate(obj):
    for o in bpy.context.selected_objects:
        o.select_set(False)
    bpy.context.view_layer.objects.active = obj
    obj.select_set(True)


def groups(obj, rest):
    left = np.flatnonzero(rest[:, 0] < -1.8)
    right = np.flatnonzero(rest[:, 0] > 1.8)
    for name, idx in (("Left", left), ("Right", right), ("Anchors", np.concatenate([left, right]))):
        vg = obj.vertex_groups.new(name=name)
        vg.add(idx.tolist(), 1.0, "REPLACE")
    return left, right


def ms(t0):
    return (time.perf_counter() - t0) * 1e3


def evaluate(obj):
    dg = bpy.context.evaluated_depsgraph_get()
    dg.update()
    ev = obj.evaluated_get(dg)
    return ev.data


def bench_larap(core, n, args):
    obj, rest = blender_mesh.quad_tube("LarapTube", n, 256)
    activate(obj)
    left, right = groups(obj, rest)
    s = obj.larap
    s.iterations = args.iterations
    s.device = args.device
    if args.cells:
        s.resolution_mode, s.cells = "CELLS", args.cells
    t0 = time.perf_counter()
    core.add_handle(obj, vertex_group="Left")
    core.add_handle(obj, vertex_group="Right")
    t_handles = ms(t0)
    t0 = time.perf_counter()
    core.bind(obj)
    t_bind = ms(t0)
    rt = core.runtime(obj)
    d = rt.deformer
    bind_stats = dict(d.stats)
    evaluate(obj)
    target = s.handles[1].target
    live, solve_only, engine_ms = [], [], []
    for i in range(args.repeats):
        target.location.z += 0.05
        t0 = time.perf_counter()
        r = core.solve(obj, weights="interactive", validate="fast")
        t_solve = ms(t0)
        evaluate(obj)
        live.append(ms(t0))
        solve_only.append(t_solve)
        engine_ms.append(r.engine_ms)
    # Blender's own share: write the key + re-evaluate, no solve.
    share = []
    pose = rt.out.copy()
    for i in range(args.repeats):
        t0 = time.perf_counter()
        core.write_pose(obj, pose)
        evaluate(obj)
        share.append(ms(t0))
    t0 = time.perf_counter()
    core.solve(obj, weights="final", validate="full")
    t_final = ms(t0)
    res = dict(vertices=len(rest), nodes=int(d.num_nodes), cells=int(d.num_cells), device=str(d.device),
               handles=int(len(left) + len(right)), handle_groups_ms=t_handles, bind_ms=t_bind,
               engine_lattice_ms=float(bind_stats.get("ms_lattice", float("nan"))),
               engine_binding_ms=float(bind_stats.get("ms_binding", float("nan"))),
               engine_factorize_ms=float(bind_stats.get("ms_factorize", float("nan"))),
               live_ms=statistics.median(live), solve_write_ms=statistics.median(solve_only),
               engine_solve_ms=statistics.median(engine_ms), blender_share_ms=statistics.median(share),
               final_solve_full_validate_ms=t_final)
    bpy.data.objects.remove(obj)
    return res


def bench_laplacian(n, args):
    obj, rest = blender_mesh.quad_tube("LapTube", n, 256)
    activate(obj)
    left, right = groups(obj, rest)
    hook_target = bpy.data.objects.new("HookTarget", None)
    bpy.context.scene.collection.objects.link(hook_target)
    hook = obj.modifiers.new("Hook", "HOOK")
    hook.object = hook_target
    hook.vertex_group = "Right"
    lap = obj.modifiers.new("LaplacianDeform", "LAPLACIANDEFORM")
    lap.vertex_group = "Anchors"
    lap.iterations = 1
    evaluate(obj)
    t0 = time.perf_counter()
    with bpy.context.temp_override(object=obj, active_object=obj):
        bpy.ops.object.laplaciandeform_bind(modifier=lap.name)
    evaluate(obj)
    t_bind = ms(t0)
    res = dict(vertices=len(rest), bind_ms=t_bind, is_bind=bool(lap.is_bind))
    times = []
    moved = None
    for i in range(args.repeats):
        hook_target.location.z += 0.05
        t0 = time.perf_counter()
        me = evaluate(obj)
        times.append(ms(t0))
    co = np.empty(len(me.vertices) * 3, np.float32)
    me.vertices.foreach_get("co", co)
    co = co.reshape(-1, 3)
    middle = np.flatnonzero(np.abs(rest[:, 0]) < 0.05)
    moved = float(np.abs(co[middle, 2] - rest[middle, 2]).mean())
    res.update(update_ms=statistics.median(times), middle_dz=moved)
    # Failure modes: not bound, or the interior did not follow (the modifier passes the input through).
    res["ok"] = bool(lap.is_bind and moved > 1e-4)
    bpy.data.objects.remove(obj)
    bpy.data.objects.remove(hook_target)
    return res


def main():
    args = parse_args()
    setup_paths()
    core, engine = enable_addon()
    rows = []
    for n in args.sizes:
        print("== %d vertices" % n, flush=True)
        row = dict(size=n, larap=bench_larap(core, n, args))
        print("   larap:", json.dumps(row["larap"]), flush=True)
        if n <= args.laplacian_max:
            try:
                row["laplacian"] = bench_laplacian(n, args)
            except Exception as exc:
                row["laplacian"] = dict(ok=False, error="%s: %s" % (type(exc).__name__, exc))
        else:
            row["laplacian"] = dict(ok=False, skipped="above --laplacian-max %d" % args.laplacian_max)
        print("   laplacian:", json.dumps(row["laplacian"]), flush=True)
        rows.append(row)

    head = ("| vertices | lattice nodes | bind ms | live update ms | engine solve ms | Blender share ms "
            "| Laplacian bind ms | Laplacian update ms |")
    lines = [head, "|" + "---|" * 8]
    for row in rows:
        L, P = row["larap"], row["laplacian"]
        if P.get("ok"):
            lap_bind, lap_upd = "%.0f" % P["bind_ms"], "%.0f" % P["update_ms"]
        elif "skipped" in P:
            lap_bind = lap_upd = "skipped"
        elif "error" in P:
            lap_bind, lap_upd = "error", P["error"][:60]
        else:
            lap_bind = "%.0f (failed)" % P.get("bind_ms", float("nan"))
            lap_upd = "failed: no deformation" if P.get("is_bind") else "failed: not bound"
        lines.append("| %d | %d | %.0f | %.1f | %.1f | %.1f | %s | %s |" % (
            L["vertices"], L["nodes"], L["bind_ms"], L["live_ms"], L["engine_solve_ms"], L["blender_share_ms"],
            lap_bind, lap_upd))
    table = "\n".join(lines)
    print(table)
    stamp = datetime.datetime.now().strftime("%Y-%m-%d %H:%M")
    info = dict(date=stamp, machine=machine_info.describe(), blender=bpy.app.version_string, device=args.device,
                iterations=args.iterations, repeats=args.repeats, engine=engine.location(), rows=rows)
    if not args.no_write:
        new = not os.path.exists(args.out)
        with open(args.out, "a") as f:
            if new:
                f.write("<!-- SPDX-License-Identifier: GPL-3.0-or-later -->\n# LARAP in Blender: benchmark results\n\nAppended by `scripts/bench_blender.py` "
                        "(one section per run; medians over --repeats). \"live update\" = solve with the "
                        "interactive weights + write the shape key + depsgraph evaluation; \"Blender share\" = "
                        "the same without the solve. Mesh: closed quad tube, handles = its two end caps.\n")
            f.write("\n## %s: %s, Blender %s, device %s, %d iterations\n\n%s\n\n"
                    % (stamp, info["machine"], info["blender"], args.device, args.iterations, table))
            f.write("<!-- json: %s -->\n" % json.dumps(info))
        print("appended to", args.out)


if __name__ == "__main__":  # Blender runs a --python script as __main__; importing it runs nothing
    main()
