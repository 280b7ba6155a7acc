# SPDX-License-Identifier: GPL-3.0-or-later
"""Blender's own deformers beside LARAP's add-on, inside Blender, on the report's bar and its 90°
bend (the same steps and transforms as every other method). One method and size per Blender
process, so a peer that hangs or crashes is recorded as a failure by the caller (its timeout):

  blender -b --factory-startup --python-exit-code 1 --python scripts/report/blender_peers.py -- \
      METHOD VERTICES RESULT.jsonl [MESH_OUT.npz]

METHOD: laplacian (Laplacian Deform, anchors = both groups, a Hook on the tip group follows an
Empty), meshdeform (Mesh Deform bound to a box cage of 8 x 2 x 2 segments whose tip-end vertices
follow the tip transform through a Hook; the rest of the cage stays: what an artist has before
posing the cage by hand), larap (the add-on: two handles from vertex groups, Empties moved).
Per method: bind ms, ms per handle move (the mesh re-evaluated, as the viewport would), and
for larap the engine's share and Blender's share (shape key write + re-evaluation). The final
pose goes to MESH_OUT for the quality measures. Appends one JSON line to RESULT.jsonl."""
import json
import os
import sys
import time

import bpy
import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(os.path.dirname(HERE))
for p in (os.path.join(ROOT, "scripts"), os.path.join(ROOT, "addon"), os.path.join(ROOT, "python")):
    if p not in sys.path:
        sys.path.insert(0, p)

from blender_mesh import mesh_object  # noqa: E402
from report.blender_peers_geometry import bar  # noqa: E402


def ms(t0):
    return (time.perf_counter() - t0) * 1e3


def evaluate(obj):
    dg = bpy.context.evaluated_depsgraph_get()
    dg.update()
    return obj.evaluated_get(dg).data


def positions(me):
    co = np.empty(len(me.vertices) * 3, np.float32)
    me.vertices.foreach_get("co", co)
    return co.reshape(-1, 3).astype(np.float64)


def make_mesh(name, V, F):
    import larap
    offsets, indices = larap.faces_to_csr(F, len(V))
    return mesh_object(name, V, offsets, indices)


def add_groups(obj, groups, names=("Base", "Tip")):
    for name, ids in zip(names, groups):
        obj.vertex_groups.new(name=name).add(ids.tolist(), 1.0, "REPLACE")
    obj.vertex_groups.new(name="Anchors").add(np.concatenate(groups).tolist(), 1.0, "REPLACE")


def empty(name):
    e = bpy.data.objects.new(name, None)
    bpy.context.scene.collection.objects.link(e)
    return e


def matrix(T):
    from mathutils import Matrix
    return Matrix(np.asarray(T).tolist())


def bind_and_move(obj, bind_op, modifier, target, steps):
    """A Blender deformer's bind and moves, timed as the viewport sees them: ``bind_op`` (the
    modifier's bind operator) on ``obj``'s ``modifier`` with the mesh re-evaluated, then the tip
    transform of each step given to ``target`` (the Empty a Hook follows) and the mesh re-evaluated.
    Returns (bind ms, median ms per move, the last pose's #V by 3 positions)."""
    evaluate(obj)
    t0 = time.perf_counter()
    with bpy.context.temp_override(object=obj, active_object=obj, selected_objects=[obj]):
        bind_op(modifier=modifier.name)
    evaluate(obj)
    bind_ms = ms(t0)
    moves = []
    for T in steps:
        target.matrix_world = matrix(T[1])
        t0 = time.perf_counter()
        me = evaluate(obj)
        moves.append(ms(t0))
    return bind_ms, float(np.median(moves)), positions(me)


def laplacian(V, F, groups, steps):
    obj = make_mesh("Bar", V, F)
    add_groups(obj, groups)
    target = empty("TipTarget")
    hook = obj.modifiers.new("Hook", "HOOK")
    hook.object, hook.vertex_group = target, "Tip"
    lap = obj.modifiers.new("Laplacian", "LAPLACIANDEFORM")
    lap.vertex_group, lap.iterations = "Anchors", 1
    bind_ms, move_ms, X = bind_and_move(obj, bpy.ops.object.laplaciandeform_bind, lap, target, steps)
    res = dict(bind_ms=bind_ms, is_bind=bool(lap.is_bind))
    mid = np.flatnonzero(np.abs(V[:, 0] - 2.0) < 0.1)
    moved = float(np.abs(X[mid] - V[mid]).max())
    res.update(move_ms=move_ms, ok=bool(lap.is_bind and moved > 1e-3))
    if not res["ok"]:
        res["error"] = "not bound" if not lap.is_bind else "no deformation (the modifier passed the mesh through)"
    return res, X


def meshdeform(V, F, groups, steps):
    obj = make_mesh("Bar", V, F)
    add_groups(obj, groups)
    xs = np.linspace(-0.15, 4.15, 9)
    cV, cF = cage_box(xs, (-0.65, 0.65), (-0.65, 0.65))
    cage = make_mesh("Cage", cV, cF)
    tip = np.flatnonzero(cV[:, 0] >= 3.6)
    cage.vertex_groups.new(name="Tip").add(tip.tolist(), 1.0, "REPLACE")
    target = empty("TipTarget")
    hook = cage.modifiers.new("Hook", "HOOK")
    hook.object, hook.vertex_group = target, "Tip"
    md = obj.modifiers.new("MeshDeform", "MESH_DEFORM")
    md.object, md.precision = cage, 4
    bind_ms, move_ms, X = bind_and_move(obj, bpy.ops.object.meshdeform_bind, md, target, steps)
    res = dict(bind_ms=bind_ms, is_bind=bool(md.is_bound), cage_vertices=len(cV), move_ms=move_ms,
               ok=bool(md.is_bound))
    return res, X


def cage_box(xs, ys, zs):
    """Closed quad box whose x direction is split at xs (a cage with segments along the bar)."""
    nx = len(xs)
    V, F = [], []
    ring = [(ys[0], zs[0]), (ys[1], zs[0]), (ys[1], zs[1]), (ys[0], zs[1])]
    for x in xs:
        V += [(x, y, z) for y, z in ring]
    for i in range(nx - 1):
        for j in range(4):
            a, b = 4 * i + j, 4 * i + (j + 1) % 4
            F.append([a, b, b + 4, a + 4])
    F.append([3, 2, 1, 0])
    last = 4 * (nx - 1)
    F.append([last, last + 1, last + 2, last + 3])
    return np.array(V, float), F


def larap_addon(V, F, groups, steps):
    import addon_utils
    mod = addon_utils.enable("larap_blender", default_set=True)
    if mod is None or not hasattr(bpy.types.Object, "larap"):
        raise RuntimeError("could not enable the larap_blender add-on")
    from larap_blender import core, solving
    obj = make_mesh("Bar", V, F)
    add_groups(obj, groups)
    bpy.context.view_layer.objects.active = obj
    obj.select_set(True)
    core.add_handle(obj, vertex_group="Base")
    core.add_handle(obj, vertex_group="Tip")
    t0 = time.perf_counter()
    core.bind(obj)
    evaluate(obj)
    res = dict(bind_ms=ms(t0))
    tip = obj.larap.handles[1].target
    rest = tip.matrix_world.copy()
    live, engine, share = [], [], []
    for T in steps:
        tip.matrix_world = matrix(T[1]) @ rest
        t0 = time.perf_counter()
        r = solving.solve(obj, weights="interactive", validate="fast")
        evaluate(obj)
        live.append(ms(t0))
        engine.append(r.engine_ms)
    rt = core.runtime(obj)
    pose = rt.out.copy()
    for _ in range(3):
        t0 = time.perf_counter()
        core.write_pose(obj, pose)
        evaluate(obj)
        share.append(ms(t0))
    solving.solve(obj, weights="final", validate="full")
    X = rt.out.astype(np.float64).copy()
    res.update(move_ms=float(np.median(live)), engine_ms=float(np.median(engine)),
               blender_share_ms=float(np.median(share)), nodes=int(rt.deformer.num_nodes), ok=True)
    return res, X


def main():
    argv = sys.argv[sys.argv.index("--") + 1:]
    method, n, result = argv[0], int(argv[1]), argv[2]
    mesh_out = argv[3] if len(argv) > 3 else None
    bpy.ops.wm.read_factory_settings(use_empty=True)
    V, F, groups, steps = bar(n)
    row = dict(method=method, size=n, vertices=len(V), handles=int(sum(len(g) for g in groups)))
    try:
        res, X = {"laplacian": laplacian, "meshdeform": meshdeform, "larap": larap_addon}[method](V, F, groups, steps)
        row.update(res)
        if mesh_out:
            np.savez(mesh_out, X=X.astype(np.float32))
    except Exception as exc:  # recorded, not raised: a peer's failure is a result
        row.update(ok=False, error="%s: %s" % (type(exc).__name__, exc))
    with open(result, "a") as f:
        f.write(json.dumps(row) + "\n")
    print(json.dumps(row))


main()
