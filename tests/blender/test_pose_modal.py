# SPDX-License-Identifier: GPL-3.0-or-later
# Run: blender -b --factory-startup --python-exit-code 1 --python tests/blender/run_tests.py -- tests/blender/test_pose_modal.py
# Headless Blender has no 3D View, so the modal operator's methods run against a fake context
# (orthographic top view, 800x800 px showing x, y in [-4, 4]) and synthetic events.
import math
import types

import bpy
import numpy as np
import pytest
from mathutils import Matrix, Quaternion

from conftest import bar_with_handles, coords, diagonal

PX = 8.0 / 800.0  # world units per pixel


def fake_context(obj):
    rv3d = types.SimpleNamespace(
        view_matrix=Matrix.Translation((0.0, 0.0, -10.0)),
        is_perspective=False, view_perspective="ORTHO", view_rotation=Quaternion())
    rv3d.perspective_matrix = Matrix.Diagonal((0.25, 0.25, -0.01, 1.0)) @ rv3d.view_matrix
    headers = []
    area = types.SimpleNamespace(type="VIEW_3D", header_text_set=headers.append, tag_redraw=lambda: None)
    ctx = types.SimpleNamespace(region=types.SimpleNamespace(width=800, height=800), region_data=rv3d,
                                area=area, object=obj, scene=bpy.context.scene,
                                window_manager=types.SimpleNamespace(modal_handler_add=lambda op: None))
    return ctx, headers


def screen(x, y):
    return 400.0 + x / PX, 400.0 + y / PX


def event(type_, value="PRESS", pos=(0.0, 0.0), shift=False):
    return types.SimpleNamespace(type=type_, value=value, mouse_region_x=pos[0], mouse_region_y=pos[1],
                                 shift=shift)


def make_operator(handle=-1):
    cls = bpy.types.LARAP_OT_pose

    class FakeOp:
        pass

    op = FakeOp()
    op.handle = handle
    op.reports = []
    op.report = lambda kind, msg: op.reports.append((kind, msg))
    for name in ("invoke", "modal", "execute", "cancel", "_start", "_pick", "_pivot_2d", "_numeric_value",
                 "_axis_vec", "_compute", "_update", "_finish"):
        setattr(op, name, types.MethodType(getattr(cls, name), op))
    return op


def test_pick_drag_axis_numeric_and_cancel(core):
    obj, rest, left, right, targets = bar_with_handles(core)
    ctx, headers = fake_context(obj)
    before = coords(obj, "LARAP").astype(np.float32).tobytes()
    m_before = targets[1].matrix_world.copy()
    op = make_operator()
    assert op.invoke(ctx, event("LEFTMOUSE", pos=(0, 0))) == {"RUNNING_MODAL"}
    assert op.state == "PICK"
    start = screen(2.0, 0.2)  # on the right cap
    assert op.modal(ctx, event("LEFTMOUSE", pos=start)) == {"RUNNING_MODAL"}
    assert op.state == "DRAG" and op.session.handle_index == 1
    assert op.modal(ctx, event("MOUSEMOVE", "NOTHING", pos=(start[0], start[1] + 50))) == {"RUNNING_MODAL"}
    assert targets[1].matrix_world.translation.y == pytest.approx(50 * PX, abs=1e-4)
    assert "ms" in headers[-1] and "Move" in headers[-1]
    # Shift: precision (a tenth of the mouse motion).
    op.modal(ctx, event("MOUSEMOVE", "NOTHING", pos=(start[0], start[1] + 150), shift=True))
    assert targets[1].matrix_world.translation.y == pytest.approx(60 * PX, abs=1e-4)
    # Z lock: motion in the view plane has no Z component.
    op.modal(ctx, event("Z"))
    assert targets[1].matrix_world.translation.y == pytest.approx(0.0, abs=1e-6)
    # Typed value along the locked axis.
    for key in ("ZERO", "PERIOD", "THREE"):
        op.modal(ctx, event(key))
    assert targets[1].matrix_world.translation.z == pytest.approx(0.3, abs=1e-6)
    assert "along Z" in headers[-1] and "[0.3]" in headers[-1]
    assert coords(obj, "LARAP").astype(np.float32).tobytes() != before
    assert op.modal(ctx, event("ESC")) == {"CANCELLED"}
    assert coords(obj, "LARAP").astype(np.float32).tobytes() == before
    assert targets[1].matrix_world == m_before
    assert headers[-1] is None


def test_rotate_scale_and_confirm(core):
    obj, rest, left, right, targets = bar_with_handles(core)
    ctx, headers = fake_context(obj)
    op = make_operator(handle=1)
    centre = targets[1].matrix_world.translation  # the Empty sits at the handle's centre = the pivot
    pivot = screen(centre.x, centre.y)
    assert op.invoke(ctx, event("MOUSEMOVE", pos=(pivot[0] + 100, pivot[1]))) == {"RUNNING_MODAL"}
    assert op.state == "DRAG"
    op.modal(ctx, event("R"))
    # Counter-clockwise on screen = positive about +Z (towards the viewer).
    a = math.radians(30)
    op.modal(ctx, event("MOUSEMOVE", "NOTHING", pos=(pivot[0] + 100 * math.cos(a), pivot[1] + 100 * math.sin(a))))
    assert targets[1].matrix_world.to_euler().z == pytest.approx(a, abs=1e-4)
    # Switching mode restarts from the grabbed state, as in Blender's transform.
    op.modal(ctx, event("S"))
    op.modal(ctx, event("MOUSEMOVE", "NOTHING", pos=(pivot[0] + 110 * math.cos(a), pivot[1] + 110 * math.sin(a))))
    assert targets[1].matrix_world.to_scale().x == pytest.approx(1.1, abs=1e-4)
    assert targets[1].matrix_world.to_euler().z == pytest.approx(0.0, abs=1e-6)
    assert op.modal(ctx, event("RET")) == {"FINISHED"}
    assert core.runtime(obj).weights == "bspline"
    pose = coords(obj, "LARAP")
    c = rest[right].mean(axis=0)
    m = np.eye(3) * 1.1
    want = (rest[right] - c) @ m.T + c
    assert np.linalg.norm(pose[right] - want, axis=1).max() < 0.02 * diagonal(rest)


def test_pick_misses_and_errors(core):
    obj, *_ = bar_with_handles(core)
    ctx, headers = fake_context(obj)
    op = make_operator()
    op.invoke(ctx, event("LEFTMOUSE"))
    assert op.modal(ctx, event("LEFTMOUSE", pos=screen(0.0, 3.0))) == {"RUNNING_MODAL"}  # nothing near
    assert op.state == "PICK"
    assert op.modal(ctx, event("MIDDLEMOUSE")) == {"PASS_THROUGH"}  # navigation still works
    assert op.modal(ctx, event("RIGHTMOUSE")) == {"CANCELLED"}
    ctx.area = None
    assert make_operator().invoke(ctx, event("LEFTMOUSE")) == {"CANCELLED"}


def test_hover_reads_the_pose_once_per_pose(core, monkeypatch):
    """Hovering while Pose waits for a click reads the pose key and projects the handle vertices
    once per pose and view, not at each mouse move; a new pose is read again."""
    from larap_blender import modal, overlay, session
    obj, rest, left, right, targets = bar_with_handles(core)
    reads = {"key": 0, "project": 0}
    key_positions, project = session.key_positions, modal._project

    def counted_key(*a, **k):
        reads["key"] += 1
        return key_positions(*a, **k)

    def counted_project(*a, **k):
        reads["project"] += 1
        return project(*a, **k)
    monkeypatch.setattr(session, "key_positions", counted_key)
    monkeypatch.setattr(modal, "_project", counted_project)
    ctx, _ = fake_context(obj)
    op = make_operator()
    assert op.invoke(ctx, event("MOUSEMOVE", pos=(0, 0))) == {"RUNNING_MODAL"}
    for x in range(0, 800, 20):
        op.modal(ctx, event("MOUSEMOVE", "NOTHING", pos=(x, 400)))
    op.modal(ctx, event("MOUSEMOVE", "NOTHING", pos=screen(2.0, 0.2)))
    assert reads == {"key": 1, "project": 1}
    assert overlay.picking(obj) == 1  # over the right cap
    # A new pose (a solve) is read and projected again, and picking sees it.
    targets[1].location.y += 1.0
    bpy.ops.larap.solve()
    op.modal(ctx, event("MOUSEMOVE", "NOTHING", pos=screen(2.0, 1.2)))
    assert reads == {"key": 2, "project": 2}
    assert overlay.picking(obj) == 1
    pts, owner = session.handle_points(obj, refresh=False)
    assert np.abs(pts[owner == 1] - coords(obj, "LARAP")[right]).max() < 1e-6  # object at the origin
    op.modal(ctx, event("ESC"))
