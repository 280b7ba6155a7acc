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
