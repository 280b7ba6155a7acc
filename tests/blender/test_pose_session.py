# SPDX-License-Identifier: GPL-3.0-or-later
# Run: blender -b --factory-startup --python-exit-code 1 --python tests/blender/run_tests.py -- tests/blender/test_pose_session.py
import math

import bpy
import numpy as np
import pytest
from mathutils import Quaternion, Vector

from conftest import bar_with_handles, coords, diagonal


def _snapshot_target(t):
    return (tuple(t.location), tuple(t.rotation_euler), tuple(t.rotation_quaternion), tuple(t.scale),
            t.rotation_mode, tuple(tuple(r) for r in t.matrix_world))


def test_cancel_restores_bit_exactly(core):
    obj, rest, left, right, targets = bar_with_handles(core)
    # Start from a non-trivial pose so a sloppy restore would show.
    targets[1].location.z += 0.7
    bpy.ops.larap.solve()
    before = coords(obj, "LARAP").astype(np.float32).tobytes()
    t_before = _snapshot_target(targets[1])
    session = core.PoseSession(obj, 1).begin()
    rt = core.runtime(obj)
    for step in range(1, 4):
        r = session.update(translation=(0.0, 0.1 * step, 0.2 * step))
        assert rt.weights == obj.larap.weights_interactive == "trilinear"
        assert r.ms > 0
    session.update(rotation=Quaternion((0, 0, 1), math.radians(40)), scale=(1.1, 1.1, 1.1))
    assert coords(obj, "LARAP").astype(np.float32).tobytes() != before
    session.cancel()
    assert coords(obj, "LARAP").astype(np.float32).tobytes() == before
    assert _snapshot_target(targets[1]) == t_before
    assert not session.active


def test_cancel_puts_the_lattice_of_the_shown_pose_back(core):
    """After a cancel the engine holds the pre-drag lattice again: the overlay draws the pose's
    lattice (not the rest lattice), and the next drag starts from the shown pose, not from rest."""
    from larap_blender import overlay
    obj, rest, left, right, targets = bar_with_handles(core)
    targets[1].location.z += 0.7
    bpy.ops.larap.solve()
    rt = core.runtime(obj)
    assert overlay.lattice_state(obj, rt) == "pose"
    shown = rt.deformer.lattice_deformed()
    session = core.PoseSession(obj, 1).begin()
    session.update(translation=(0.0, 0.3, -0.5))
    assert np.abs(rt.deformer.lattice_deformed() - shown).max() > 0.05
    session.cancel()
    assert overlay.lattice_state(obj, rt) == "pose"
    assert np.array_equal(rt.deformer.lattice_deformed(), shown)
    # The first step of the next drag starts from the shown pose: a zero move keeps it.
    session = core.PoseSession(obj, 1).begin()
    session.update(translation=(0.0, 0.0, 0.0))
    assert np.abs(rt.deformer.lattice_deformed() - shown).max() < 1e-3 * diagonal(rest)
    session.cancel()


def test_a_solve_without_usable_handles_leaves_the_engine_at_rest(core):
    """No usable handles: the rest pose is written and the engine's lattice is the rest lattice, so
    a later drag's cancel puts back that rest lattice, not the pose before the handles went."""
    from larap_blender import overlay
    obj, rest, left, right, targets = bar_with_handles(core)
    targets[1].location.z += 0.7
    bpy.ops.larap.solve()
    rt = core.runtime(obj)
    for h in obj.larap.handles:
        h.enabled = False
    core.solve(obj, weights="final")
    at_rest = lambda: np.abs(rt.deformer.lattice_deformed() - rt.deformer.lattice_rest()).max() <= 1e-12
    assert at_rest()
    for h in obj.larap.handles:
        h.enabled = True
    session = core.PoseSession(obj, 1).begin()
    session.update(translation=(0.0, 0.3, 0.0))
    session.cancel()
    assert overlay.lattice_state(obj, rt) == "pose"
    assert at_rest()
    assert np.abs(coords(obj, "LARAP") - rest).max() == 0.0


def posed_bar_live_preview(core):
    """The bar with Live and Preview on, its far end raised and solved: (object, targets, runtime)."""
    obj, rest, left, right, targets = bar_with_handles(core)
    obj.larap.live = True
    obj.larap.preview = True
    targets[1].location.z += 0.7
    bpy.ops.larap.solve()
    return obj, targets, core.runtime(obj)


def test_the_catch_up_waits_for_a_drag(core, gpu_preview):
    """A catch-up due during a preview drag writes nothing: the drag's cancel leaves the pose key
    as it was (and its record true)."""
    from larap_blender import catchup
    obj, targets, rt = posed_bar_live_preview(core)
    before = coords(obj, "LARAP").copy()
    session = core.PoseSession(obj, 1).begin()
    session.update(translation=(0.0, 0.0, 1.0))
    assert gpu_preview.showing(obj) and not session.wrote and rt.needs_catchup
    rt.last_move = 0.0  # as if a live move happened more than DELAY ago (a registered timer)
    catchup._timer()
    assert np.array_equal(coords(obj, "LARAP"), before)
    session.cancel()
    assert np.array_equal(coords(obj, "LARAP"), before)


def test_a_failed_catch_up_at_the_drag_start_cancels_to_the_rest_lattice(core, gpu_preview, monkeypatch):
    """The catch-up at the drag's start fails (the engine left at rest, the mesh showing the old
    pose key): a cancel does not claim the engine's lattice is the shown pose's."""
    import larap
    from larap_blender import handlers, overlay
    obj, targets, rt = posed_bar_live_preview(core)
    targets[1].location.y += 0.4
    bpy.context.view_layer.update()
    handlers.live_update(bpy.context.scene)  # a live move: a lattice-only solve, the preview shows
    assert gpu_preview.showing(obj) and rt.needs_catchup

    def failing(self, *args, **kwargs):
        raise RuntimeError("device lost")
    real = larap.Deformer.solve
    monkeypatch.setattr(larap.Deformer, "solve", failing)
    session = core.PoseSession(obj, 1).begin()
    monkeypatch.setattr(larap.Deformer, "solve", real)
    assert "catching up failed" in rt.last_error and not rt.lattice_current
    session.update(translation=(0.0, 0.0, 0.2))
    session.cancel()
    assert overlay.lattice_state(obj, rt) == "rest"


def test_confirm_uses_final_weights(core):
    obj, rest, left, right, targets = bar_with_handles(core)
    session = core.PoseSession(obj, 1).begin()
    session.update(translation=(0.0, 0.0, 0.8))
    r = session.confirm()
    assert r.weights == "bspline" and core.runtime(obj).weights == "bspline"
    pose = coords(obj, "LARAP")
    assert np.abs(pose[right, 2] - rest[right, 2] - 0.8).max() < 0.02 * diagonal(rest)
    # The target moved with the drag (handles follow targets).
    assert targets[1].matrix_world.translation.z == pytest.approx(0.8, abs=1e-6)
    # A later solve from the targets reproduces the confirmed pose (up to the further iterations
    # of the warm-started solver).
    bpy.ops.larap.solve()
    assert np.abs(coords(obj, "LARAP") - pose).max() < 5e-3 * diagonal(rest)


def test_rotate_about_handle_centre(core):
    obj, rest, left, right, targets = bar_with_handles(core)
    session = core.PoseSession(obj, 1).begin()
    centre = Vector(rest[right].mean(axis=0))
    assert (session.pivot - centre).length < 1e-5
    session.update(rotation=Quaternion((0, 1, 0), math.radians(-20)))
    session.confirm()
    assert (targets[1].matrix_world.translation - centre).length < 1e-5  # pivot = target origin here
    assert targets[1].matrix_world.to_euler().y == pytest.approx(math.radians(-20), abs=1e-5)


def test_session_errors_are_reported(core):
    obj, rest, left, right, targets = bar_with_handles(core)
    with pytest.raises(core.LarapError):
        core.PoseSession(obj, 7).begin()
    bpy.data.objects.remove(targets[0])
    with pytest.raises(core.LarapError, match="no target"):
        core.PoseSession(obj, 0).begin()


def test_pose_operator_needs_3d_view(core):
    obj, *_ = bar_with_handles(core)
    with pytest.raises(RuntimeError, match="3D View|interactive"):
        bpy.ops.larap.pose("INVOKE_DEFAULT")


def test_failed_confirm_restores_like_cancel(core, monkeypatch, gpu_preview):
    """The final solve of confirm fails: the pose key, the target and its record are restored,
    the preview ends (the mesh is shown again) and nothing is left to catch up."""
    import larap
    from larap_blender import session as session_module, solving
    from test_pose_modal import event, fake_context, make_operator
    obj, rest, left, right, targets = bar_with_handles(core)
    obj.larap.live = True
    before = coords(obj, "LARAP").astype(np.float32).tobytes()
    t_before = _snapshot_target(targets[1])
    sig_before = solving.stored_signature(obj)
    engine_solve = larap.Deformer.solve
    for via_operator in (False, True):
        if via_operator:
            ctx, _ = fake_context(obj)
            op = make_operator(handle=1)
            assert op.invoke(ctx, event("MOUSEMOVE", pos=(600, 400))) == {"RUNNING_MODAL"}
            op.modal(ctx, event("MOUSEMOVE", "NOTHING", pos=(600, 480)))
        else:
            session = core.PoseSession(obj, 1).begin()
            session.update(translation=(0.0, 0.2, 0.5))
        assert gpu_preview.showing(obj) and obj.hide_get()
        assert targets[1].matrix_world.translation.z != 0.0 or targets[1].matrix_world.translation.y != 0.0

        def boom(self, *a, **k):
            raise RuntimeError("engine failed")
        monkeypatch.setattr(larap.Deformer, "solve", boom)
        if via_operator:
            assert op.modal(ctx, event("RET")) == {"CANCELLED"}
            assert any("engine failed" in msg for kind, msg in op.reports if "ERROR" in kind)
            session = op.session
        else:
            with pytest.raises(core.LarapError, match="engine failed"):
                session.confirm()
        monkeypatch.setattr(larap.Deformer, "solve", engine_solve)
        rt = core.runtime(obj)
        assert not session.active and not session_module.dragging(obj)
        assert coords(obj, "LARAP").astype(np.float32).tobytes() == before
        assert _snapshot_target(targets[1]) == t_before
        assert solving.stored_signature(obj) == sig_before
        assert not gpu_preview.showing(obj) and not obj.hide_get()
        assert not rt.needs_catchup and rt.lattice_nodes is None


def test_targets_parented_under_the_dragged_one_follow_at_each_step(core):
    """An Empty parented under the dragged target moves with it in the same drag step (not one
    event behind)."""
    obj, rest, left, right, targets = bar_with_handles(core)
    child, parent = targets
    child.parent = parent
    child.matrix_parent_inverse = parent.matrix_world.inverted()
    bpy.context.view_layer.update()
    session = core.PoseSession(obj, 1).begin()
    tol = 0.02 * diagonal(rest)
    for dz in (0.3, 0.6, 0.9):
        session.update(translation=(0.0, 0.0, dz))
        pose = coords(obj, "LARAP")
        assert np.abs(pose[right, 2] - rest[right, 2] - dz).max() < tol
        assert np.abs(pose[left, 2] - rest[left, 2] - dz).max() < tol
    session.confirm()
    pose = coords(obj, "LARAP")
    assert np.abs(pose[:, 2] - rest[:, 2] - 0.9).max() < tol  # the whole bar moved rigidly
