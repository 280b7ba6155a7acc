# SPDX-License-Identifier: GPL-3.0-or-later
# Run: blender -b --factory-startup --python-exit-code 1 --python tests/blender/run_tests.py -- tests/blender/test_catchup.py
"""The live path with the preview and the catch-up (issue 11), headless: the fallback writes the
mesh as before; the catch-up (timer, save/render/bake handlers, leaving Live or the preview,
larap.solve, undo, reload) leaves the pose key equal to the final solve of the current targets,
computed here by a fresh engine; cancel is bit-exact with Live on; a drag step solves once; the
same targets give the same pose whatever the history. The preview path (lattice only, the object
hidden and shown again) runs headless with the GPU part switched on by a monkeypatch; drawing
itself is checked in a window (tests/blender_window/)."""
import math

import bpy
import larap
import numpy as np
import pytest
from mathutils import Quaternion

from conftest import activate, bar_with_handles, coords

# ------------------------------------------------------------------------------------------------
# Helpers


def key_bytes(obj):
    return coords(obj, "LARAP").astype(np.float32).tobytes()


def fresh_engine(core, obj):
    """A new engine for ``obj``'s rest shape and settings, with its handle groups: (deformer, the
    groups' transforms)."""
    s = obj.larap
    rt = core.ensure_runtime(obj, "full")
    pose = core.gather(obj, rt)
    ids, offsets = core.polygons(obj.data)
    d = larap.Deformer(rt.rest, ids, face_offsets=offsets, cells=int(s.cells), gamma=float(s.gamma),
                       weights=s.weights_final)
    d.set_handle_groups(pose.groups, weights=list(pose.weights), vertex_weights=pose.vertex_weights)
    return d, pose.transforms


def final_pose(core, obj):
    """The final pose of the current targets, solved by a fresh engine (no history at all)."""
    d, tgt = fresh_engine(core, obj)
    s = obj.larap
    return d.solve(transforms=tgt, iterations=max(30, 10 * int(s.iterations)),
                   out=np.empty((len(obj.data.vertices), 3), np.float32), tol=core.FINAL_TOLERANCE)


def assert_caught_up(core, obj):
    assert np.array_equal(coords(obj, "LARAP").astype(np.float32), final_pose(core, obj))
    rt = core.runtime(obj)
    assert not rt.needs_catchup
    from larap_blender import solving
    assert solving.key_up_to_date(obj)


def live_move(targets, dz=0.3):
    targets[1].location.z += dz
    bpy.context.view_layer.update()  # depsgraph_update_post -> live


def count_engine_calls(monkeypatch):
    calls = {"n": 0}
    for name in ("solve", "pose_lattice"):
        orig = getattr(larap.Deformer, name)

        def wrapped(self, *a, _orig=orig, **k):
            calls["n"] += 1
            return _orig(self, *a, **k)
        monkeypatch.setattr(larap.Deformer, name, wrapped)
    return calls




# ------------------------------------------------------------------------------------------------
# The fallback (no preview): the pose key is written at each move, exactly as before


def test_fallback_writes_the_mesh_as_before(core):
    obj, rest, left, right, targets = bar_with_handles(core)
    from larap_blender import preview
    assert preview.blocker(obj) == "background mode"
    # Before issue 11, a live move was: the engine warm-started from the bind's final solve,
    # switched to the interactive weights, solved `iterations` steps, wrote the key.
    d, tgt0 = fresh_engine(core, obj)
    d.solve(transforms=tgt0, iterations=max(30, 10 * obj.larap.iterations), tol=core.FINAL_TOLERANCE)
    obj.larap.live = True
    live_move(targets)
    rt = core.runtime(obj)
    _, tgt1 = fresh_engine(core, obj)
    d.weights = obj.larap.weights_interactive
    expect = d.solve(transforms=tgt1, iterations=obj.larap.iterations, out=np.empty((len(rest), 3), np.float32))
    assert np.array_equal(coords(obj, "LARAP").astype(np.float32), expect)
    assert rt.weights == "trilinear" and rt.needs_catchup and not preview.showing(obj)
    assert not obj.hide_get()
    from larap_blender import catchup
    assert bpy.app.timers.is_registered(catchup._timer)


# ------------------------------------------------------------------------------------------------
# The catch-up


def test_timer_catches_up_after_the_last_move(core):
    from larap_blender import catchup
    obj, rest, left, right, targets = bar_with_handles(core)
    obj.larap.live = True
    live_move(targets)
    rt = core.runtime(obj)
    assert bpy.app.timers.is_registered(catchup._timer)
    wait = catchup._timer()  # too early: the move is not DELAY old yet
    assert wait is not None and 0 < wait <= catchup.DELAY and rt.needs_catchup
    rt.last_move -= catchup.DELAY
    assert catchup._timer() is None  # done, nothing left to wait for
    assert_caught_up(core, obj)
    catchup.cancel_timer()


@pytest.mark.parametrize("event", ["save_pre", "render_init", "render_pre", "object_bake_pre"])
def test_handlers_catch_up_first(core, event):
    obj, rest, left, right, targets = bar_with_handles(core)
    obj.larap.live = True
    live_move(targets)
    assert core.runtime(obj).needs_catchup
    ours = [h for h in getattr(bpy.app.handlers, event) if h.__module__.startswith("larap_blender")]
    assert len(ours) == 1
    ours[0](bpy.context.scene)
    assert_caught_up(core, obj)


def test_real_save_and_render_catch_up(core, tmp_path):
    obj, rest, left, right, targets = bar_with_handles(core)
    obj.larap.live = True
    live_move(targets)
    bpy.ops.wm.save_as_mainfile(filepath=str(tmp_path / "a.blend"))
    obj = bpy.data.objects["Bar"]
    assert_caught_up(core, obj)
    targets = [h.target for h in obj.larap.handles]
    live_move(targets)
    assert core.runtime(obj).needs_catchup
    scene = bpy.context.scene
    scene.render.engine = "CYCLES"
    scene.cycles.samples = 1
    scene.cycles.use_denoising = False
    scene.render.resolution_x = scene.render.resolution_y = 8
    cam = bpy.data.objects.new("Cam", bpy.data.cameras.new("Cam"))
    scene.collection.objects.link(cam)
    scene.camera = cam
    bpy.ops.render.render()
    assert_caught_up(core, obj)


@pytest.mark.parametrize("setting", ["live", "preview"])
def test_turning_live_or_preview_off_catches_up(core, setting):
    obj, rest, left, right, targets = bar_with_handles(core)
    obj.larap.live = True
    live_move(targets)
    assert core.runtime(obj).needs_catchup
    setattr(obj.larap, setting, False)
    assert_caught_up(core, obj)


def test_solve_operator_catches_up(core):
    obj, rest, left, right, targets = bar_with_handles(core)
    obj.larap.live = True
    live_move(targets)
    assert bpy.ops.larap.solve() == {"FINISHED"}
    assert_caught_up(core, obj)


def test_frame_change_while_rendering_writes_the_final_pose(core, monkeypatch):
    from larap_blender import handlers
    obj, rest, left, right, targets = bar_with_handles(core)
    obj.larap.live = True
    e = targets[1]
    e.keyframe_insert("location", frame=1)
    e.location.z += 0.6
    e.keyframe_insert("location", frame=5)
    monkeypatch.setattr(handlers, "rendering", lambda: True)
    bpy.context.scene.frame_set(5)
    assert_caught_up(core, obj)


def test_bake_and_apply_change_nothing_after_the_catch_up(core):
    obj, rest, left, right, targets = bar_with_handles(core)
    obj.larap.live = True
    live_move(targets, 0.5)
    targets[0].rotation_euler.x += 0.4
    bpy.context.view_layer.update()
    from larap_blender import catchup
    catchup.catch_up_all()
    shown = coords(obj, "LARAP")
    assert bpy.ops.larap.bake_shape_key(name="Baked") == {"FINISHED"}
    assert np.array_equal(coords(obj, "Baked"), shown)
    assert np.array_equal(coords(obj, "LARAP"), shown)
    # Bake before the catch-up: it catches up first, and bakes that.
    live_move(targets, 0.2)
    assert bpy.ops.larap.bake_shape_key(name="Baked2") == {"FINISHED"}
    assert_caught_up(core, obj)
    assert np.array_equal(coords(obj, "Baked2"), coords(obj, "LARAP"))
    shown = coords(obj, "LARAP")
    assert bpy.ops.larap.apply() == {"FINISHED"}
    keys = obj.data.shape_keys  # Basis + (pose - Basis): equal up to float32 rounding
    assert np.abs(coords(obj, keys.reference_key.name) - shown).max() < 1e-6 * np.abs(shown).max()


# ------------------------------------------------------------------------------------------------
# One pose per set of targets; cancel; one solve per drag step


def test_same_targets_same_pose_whatever_the_history(core):
    from larap_blender import catchup
    obj, rest, left, right, targets = bar_with_handles(core)
    obj.larap.live = True
    goal = targets[1].location.copy()
    goal.z += 0.6
    goal.y += 0.2
    # History 1: straight there, caught up.
    targets[1].location = goal
    bpy.context.view_layer.update()
    catchup.catch_up_all()
    first = key_bytes(obj)
    # History 2: wander (live moves, a confirmed drag, a cancelled one), then come back.
    for dz in (0.9, -0.4, 0.3):
        live_move(targets, dz)
    session = core.PoseSession(obj, 1).begin()
    session.update(translation=(0.3, 0.0, -0.5))
    session.confirm()
    session = core.PoseSession(obj, 1).begin()
    session.update(rotation=Quaternion((1, 0, 0), math.radians(50)))
    session.cancel()
    targets[1].location = goal
    bpy.context.view_layer.update()
    catchup.catch_up_all()
    assert key_bytes(obj) == first
    assert_caught_up(core, obj)


def test_cancel_is_bit_exact_with_live_on(core):
    obj, rest, left, right, targets = bar_with_handles(core)
    obj.larap.live = True
    live_move(targets, 0.5)
    from larap_blender import catchup
    catchup.catch_up_all()
    before = key_bytes(obj)
    t_before = tuple(targets[1].matrix_world.col[3]), tuple(targets[1].location)
    rt = core.runtime(obj)
    session = core.PoseSession(obj, 1).begin()
    for step in range(1, 4):
        session.update(translation=(0.0, 0.1 * step, 0.2 * step))
        bpy.context.view_layer.update()  # what the window does between steps (Live fires)
    assert key_bytes(obj) != before
    calls = rt.engine_calls
    session.cancel()
    for _ in range(3):
        bpy.context.view_layer.update()
    bpy.context.scene.frame_set(bpy.context.scene.frame_current)
    assert key_bytes(obj) == before
    assert (tuple(targets[1].matrix_world.col[3]), tuple(targets[1].location)) == t_before
    assert core.runtime(obj).engine_calls == calls  # nothing solved after the cancel
    assert not rt.needs_catchup


def test_one_solve_per_drag_step(core, monkeypatch):
    obj, rest, left, right, targets = bar_with_handles(core)
    obj.larap.live = True
    calls = count_engine_calls(monkeypatch)
    session = core.PoseSession(obj, 1).begin()
    bpy.context.view_layer.update()
    assert calls["n"] == 0
    for step in range(1, 6):
        session.update(translation=(0.0, 0.05 * step, 0.1 * step))
        bpy.context.view_layer.update()  # Live sees the moved target: must not solve again
        assert calls["n"] == step
    session.confirm()
    assert calls["n"] == 6  # the final solve
    for _ in range(3):
        bpy.context.view_layer.update()
    assert calls["n"] == 6
    assert_caught_up(core, obj)


def test_modal_drag_with_live_solves_once_per_step(core, monkeypatch):
    from test_pose_modal import event, fake_context, make_operator
    obj, rest, left, right, targets = bar_with_handles(core)
    obj.larap.live = True
    calls = count_engine_calls(monkeypatch)
    ctx, _ = fake_context(obj)
    op = make_operator(handle=1)
    assert op.invoke(ctx, event("MOUSEMOVE", pos=(600, 400))) == {"RUNNING_MODAL"}
    n0 = calls["n"]
    for i, y in enumerate((420, 450, 500)):
        assert op.modal(ctx, event("MOUSEMOVE", "NOTHING", pos=(600, y))) == {"RUNNING_MODAL"}
        bpy.context.view_layer.update()
        assert calls["n"] == n0 + i + 1
    before = key_bytes(obj)
    assert op.modal(ctx, event("ESC")) == {"CANCELLED"}
    bpy.context.view_layer.update()
    assert calls["n"] == n0 + 3


# ------------------------------------------------------------------------------------------------
# Reload and undo


def test_reopening_and_moving_nothing_changes_nothing(core, tmp_path):
    obj, rest, left, right, targets = bar_with_handles(core)
    obj.larap.live = True
    live_move(targets, 0.5)
    path = str(tmp_path / "posed.blend")
    bpy.ops.wm.save_as_mainfile(filepath=path)  # catches up first
    saved = key_bytes(bpy.data.objects["Bar"])
    bpy.ops.wm.open_mainfile(filepath=path)
    obj = bpy.data.objects["Bar"]
    assert key_bytes(obj) == saved
    targets = [h.target for h in obj.larap.handles]
    activate(targets[1])  # select a target, re-evaluate, step the frame: no move
    bpy.context.view_layer.update()
    bpy.context.scene.frame_set(bpy.context.scene.frame_current)
    targets[1].location.z += 0.0
    bpy.context.view_layer.update()
    assert key_bytes(obj) == saved
    rt = core.runtime(obj)
    assert rt is None or rt.engine_calls == 0


def test_reopening_a_file_saved_behind_catches_up(core, tmp_path):
    """An autosave or quit.blend may hold a pose key behind its targets: loading catches up."""
    from larap_blender import handlers
    obj, rest, left, right, targets = bar_with_handles(core)
    obj.larap.live = True
    live_move(targets, 0.5)
    from larap_blender import catchup
    catchup.catch_up_all()
    live_move(targets, 0.3)  # not caught up
    path = str(tmp_path / "behind.blend")
    bpy.app.handlers.save_pre.remove(handlers.larap_catch_up)
    try:
        bpy.ops.wm.save_as_mainfile(filepath=path)
    finally:
        bpy.app.handlers.save_pre.append(handlers.larap_catch_up)
    bpy.ops.wm.open_mainfile(filepath=path)
    obj = bpy.data.objects["Bar"]
    assert_caught_up(core, obj)


def test_undo_shows_the_caught_up_pose(core):
    from larap_blender import catchup
    from test_safety import push, undo
    obj, rest, left, right, targets = bar_with_handles(core)
    obj.larap.live = True
    push("bound")
    poses = []
    for dz in (0.4, 0.4):
        live_move(targets, dz)
        push("Move")  # Blender pushes the step when G is confirmed: before the catch-up
        catchup.catch_up_all()
        poses.append(key_bytes(obj))
    undo()  # back to the first move's step: its key was stored before its catch-up
    obj = bpy.data.objects["Bar"]
    assert key_bytes(obj) == poses[0]
    assert_caught_up(core, obj)


# ------------------------------------------------------------------------------------------------
# The preview path (GPU drawing switched on headless)


def test_preview_path_poses_the_lattice_and_hides_the_stale_mesh(core, gpu_preview):
    from larap_blender import catchup
    obj, rest, left, right, targets = bar_with_handles(core)
    obj.larap.live = True
    assert gpu_preview.blocker(obj) == ""
    before = key_bytes(obj)
    live_move(targets, 0.5)
    rt = core.runtime(obj)
    assert key_bytes(obj) == before  # nothing written per move
    assert rt.needs_catchup and gpu_preview.showing(obj)
    assert obj.hide_get() and obj.get(gpu_preview.HIDDEN_PROP) == 2
    d, tgt = fresh_engine(core, obj)
    d.weights = "trilinear"
    # The lattice the preview draws is a pose of the current targets (interactive, warm-started).
    assert rt.lattice_nodes.shape == (rt.deformer.num_nodes, 3)
    cells = rt.deformer.cell_nodes()
    cid, frac = rt.deformer.trilinear_binding()
    # The shader's transfer, in numpy: the trilinear blend of the cell's corner displacements,
    # against the engine's own transfer of a lattice (a 0-iteration solve transfers the lattice it has).
    expect = rt.deformer.solve(transforms=core.gather(obj, rt).transforms, iterations=0)
    disp = rt.deformer.lattice_deformed() - rt.deformer.lattice_rest()
    w = np.ones((len(cid), 8))
    for c in range(8):
        for axis in range(3):
            bit = (c >> axis) & 1
            w[:, c] *= frac[:, axis] if bit else 1.0 - frac[:, axis]
    drawn = rt.rest + np.einsum("vc,vcx->vx", w, disp[cells[cid]])
    assert np.abs(drawn - expect).max() < 1e-5 * rt.deformer.diagonal
    rt.last_move -= catchup.DELAY
    catchup._timer()
    assert not obj.hide_get() and obj.select_get() and gpu_preview.HIDDEN_PROP not in obj
    assert_caught_up(core, obj)


def test_preview_drag_writes_nothing_until_confirm_and_cancel_restores(core, gpu_preview):
    obj, rest, left, right, targets = bar_with_handles(core)
    before = key_bytes(obj)
    session = core.PoseSession(obj, 1).begin()
    session.update(translation=(0.0, 0.0, 0.6))
    assert key_bytes(obj) == before and obj.hide_get()
    session.cancel()
    assert key_bytes(obj) == before and not obj.hide_get()
    session = core.PoseSession(obj, 1).begin()
    session.update(translation=(0.0, 0.0, 0.6))
    session.confirm()
    assert not obj.hide_get()
    assert_caught_up(core, obj)


def test_preview_falls_back_where_it_would_lie(core, gpu_preview):
    obj, rest, left, right, targets = bar_with_handles(core)
    obj.larap.live = True
    mod = obj.modifiers.new("Sub", "SUBSURF")
    assert "modifiers after the pose key (Sub)" in gpu_preview.blocker(obj)
    before = key_bytes(obj)
    live_move(targets, 0.5)
    assert key_bytes(obj) != before and not obj.hide_get()  # written, as before
    mod.show_viewport = False
    assert gpu_preview.blocker(obj) == ""
    obj.larap.weights_interactive = "bspline"
    assert "B-spline" in gpu_preview.blocker(obj)
    obj.larap.weights_interactive = "trilinear"
    obj.data.shape_keys.key_blocks["LARAP"].value = 0.5
    assert "full strength" in gpu_preview.blocker(obj)


def test_undo_of_a_step_stored_during_the_preview_shows_the_object(core, gpu_preview):
    from larap_blender import catchup
    from test_safety import push, undo
    obj, rest, left, right, targets = bar_with_handles(core)
    obj.larap.live = True
    push("bound")
    live_move(targets, 0.5)
    assert obj.hide_get()
    push("Move")  # stored with the object hidden behind the preview
    catchup.catch_up_all()
    live_move(targets, 0.2)
    push("Move 2")
    catchup.catch_up_all()
    undo()
    obj = bpy.data.objects["Bar"]
    assert not obj.hide_get() and gpu_preview.HIDDEN_PROP not in obj
    assert not gpu_preview.showing(obj)
    assert_caught_up(core, obj)


def test_preview_leaves_a_mesh_the_artist_hid_hidden(core, gpu_preview):
    """A live mesh hidden with H is posed by writing it (the preview would draw it) and stays
    hidden after the catch-up; show()/stop() on a hidden mesh leave it hidden."""
    from larap_blender import catchup
    obj, rest, left, right, targets = bar_with_handles(core)
    obj.larap.live = True
    obj.hide_set(True)
    assert gpu_preview.blocker(obj) == "hidden"
    before = key_bytes(obj)
    live_move(targets, 0.5)
    assert key_bytes(obj) != before and not gpu_preview.showing(obj)  # written, not drawn
    catchup.catch_up_all()
    assert obj.hide_get()
    assert_caught_up(core, obj)
    # Defensive: a direct show() of a hidden mesh is undone to hidden (and never drawn); it
    # needs a posed lattice to draw.
    assert not gpu_preview.show(obj) and gpu_preview.HIDDEN_PROP not in obj
    core.solve(obj, weights="interactive", validate="fast", lattice_only=True)
    assert gpu_preview.show(obj) and obj.get(gpu_preview.HIDDEN_PROP) == 3
    gpu_preview.stop(obj)
    assert obj.hide_get() and gpu_preview.HIDDEN_PROP not in obj
    gpu_preview.show(obj)
    gpu_preview.reset_all()
    assert obj.hide_get() and gpu_preview.HIDDEN_PROP not in obj
    obj.hide_set(False)
    assert gpu_preview.blocker(obj) == ""


def test_handle_points_follow_the_preview_not_the_stale_key(core, gpu_preview):
    """While the preview shows a drag, the handle vertices (picking, overlay) are where the
    preview draws them (the engine's transfer of the preview's lattice), not in the pose key."""
    obj, rest, left, right, targets = bar_with_handles(core)
    obj.location = (0.3, -0.2, 0.1)  # world points: the object's matrix applies
    bpy.context.view_layer.update()
    session = core.PoseSession(obj, 1).begin()
    session.update(translation=(0.0, 0.4, 0.6))
    assert gpu_preview.showing(obj)
    rt = core.runtime(obj)
    pts, owner = core.handle_points(obj, refresh=False)
    mw = np.array(obj.matrix_world)
    local = (pts - mw[:3, 3]) @ np.linalg.inv(mw[:3, :3]).T
    # The engine's own transfer of the lattice it holds (a 0-iteration solve transfers it).
    expect = rt.deformer.solve(transforms=core.gather(obj, rt).transforms, iterations=0)
    tol = 1e-5 * rt.deformer.diagonal
    assert np.abs(local[owner == 1] - expect[right]).max() < tol
    assert np.abs(local[owner == 0] - expect[left]).max() < tol
    assert np.abs(local[owner == 1] - coords(obj, "LARAP")[right]).max() > 0.3  # the key is behind
    session.cancel()
    pts, owner = core.handle_points(obj, refresh=False)
    assert np.abs(pts[owner == 1] - (coords(obj, "LARAP")[right] @ mw[:3, :3].T + mw[:3, 3])).max() < 1e-6


def test_preview_data_is_built_before_it_shows_not_in_the_draw(core, gpu_preview, monkeypatch):
    """show() builds the per-binding data (triangles, normals) on the live/drag path; the draw
    callback finds it built for the current engine (and never builds it)."""
    obj, rest, left, right, targets = bar_with_handles(core)
    obj.larap.live = True
    built = []
    init = gpu_preview._GpuMesh.__init__

    def counted(self, *a, **k):
        built.append(1)
        init(self, *a, **k)
    monkeypatch.setattr(gpu_preview._GpuMesh, "__init__", counted)
    live_move(targets, 0.5)
    assert gpu_preview.showing(obj)
    g = gpu_preview._GPU.get(obj.larap.runtime_id)
    rt = core.runtime(obj)
    assert g is not None and g.deformer is rt.deformer and g.counts == rt.counts
    assert len(g.arrays["rest"]) == len(rest) and len(g.tris) == len(obj.data.loop_triangles)
    live_move(targets, 0.2)
    assert len(built) == 1  # once per binding, not per move


def test_preview_falls_back_for_shading_it_does_not_draw(core, gpu_preview):
    """The preview shades all smooth or all flat: mixed flat and smooth faces, custom normals and
    auto smooth make posing write the mesh instead. (The faces' flags are read again once Blender
    evaluates the changed mesh, as it does before any handler or redraw: view_layer.update().)"""
    obj, rest, left, right, targets = bar_with_handles(core)
    obj.larap.live = True
    me = obj.data
    assert gpu_preview.blocker(obj) == ""
    me.polygons[0].use_smooth = True
    bpy.context.view_layer.update()
    assert gpu_preview.blocker(obj) == "mixed flat and smooth faces"
    before = key_bytes(obj)
    live_move(targets, 0.5)
    assert key_bytes(obj) != before and not gpu_preview.showing(obj) and not obj.hide_get()
    for p in me.polygons:
        p.use_smooth = True
    bpy.context.view_layer.update()
    assert gpu_preview.blocker(obj) == ""
    if hasattr(me, "use_auto_smooth"):  # Blender < 4.1
        me.use_auto_smooth = True
        assert gpu_preview.blocker(obj) == "auto smooth"
    me.normals_split_custom_set_from_vertices([(0.0, 0.0, 1.0)] * len(me.vertices))
    assert me.has_custom_normals and gpu_preview.blocker(obj) == "custom normals"
