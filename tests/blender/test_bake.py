# SPDX-License-Identifier: GPL-3.0-or-later
# Run: blender -b --factory-startup --python-exit-code 1 --python tests/blender/run_tests.py -- tests/blender/test_bake.py
import bpy
import numpy as np
import pytest

from conftest import bar_with_handles, coords, diagonal


def test_bake_shape_key(core):
    obj, rest, left, right, targets = bar_with_handles(core)
    targets[1].location.z += 1.0
    assert bpy.ops.larap.bake_shape_key(name="Bent") == {"FINISHED"}
    keys = obj.data.shape_keys.key_blocks
    assert [kb.name for kb in keys] == ["Basis", "LARAP", "Bent"]
    bent = keys["Bent"]
    assert bent.relative_key.name == "Basis" and bent.value == 0.0
    co = coords(obj, "Bent")
    assert np.abs(co - coords(obj, "LARAP")).max() < 1e-6
    assert np.abs(co[right, 2] - rest[right, 2] - 1.0).max() < 0.02 * diagonal(rest)
    assert np.array_equal(coords(obj, "Basis"), rest)
    with pytest.raises(RuntimeError, match="other than"):
        bpy.ops.larap.bake_shape_key(name="LARAP")


def test_bake_animation(core):
    obj, rest, left, right, targets = bar_with_handles(core)
    scene = bpy.context.scene
    e = targets[1]
    z0 = e.location.z
    e.keyframe_insert("location", frame=1)
    e.location.z = z0 + 1.0
    e.keyframe_insert("location", frame=5)
    scene.frame_set(3)
    assert bpy.ops.larap.bake_animation(frame_start=1, frame_end=5) == {"FINISHED"}
    assert scene.frame_current == 3
    keys = obj.data.shape_keys
    names = ["LARAP_%04d" % f for f in range(1, 6)]
    assert [kb.name for kb in keys.key_blocks][3:] == names[1:]  # Basis, LARAP, LARAP_0001, ...
    assert keys.key_blocks["LARAP"].value == 0.0
    fcurves = keys.animation_data.action.fcurves
    for f, name in zip(range(1, 6), names):
        fc = fcurves.find('key_blocks["%s"].value' % name)
        assert fc is not None
        assert fc.evaluate(f) == pytest.approx(1.0)
        assert fc.evaluate(f - 1) == pytest.approx(0.0)
        assert fc.evaluate(f + 1) == pytest.approx(0.0)
        assert keys.key_blocks[name].relative_key.name == "Basis"
    first, last = coords(obj, names[0]), coords(obj, names[-1])
    diag = diagonal(rest)
    assert np.abs(first - rest).max() < 0.02 * diag  # frame 1: targets at rest
    assert np.abs(last[right, 2] - rest[right, 2] - 1.0).max() < 0.02 * diag
    mid = coords(obj, names[2])
    assert 0.2 < (mid[right, 2] - rest[right, 2]).mean() < 0.8
    # Playing back: at frame 5 the evaluated mesh is the frame-5 pose.
    scene.frame_set(5)
    dg = bpy.context.evaluated_depsgraph_get()
    ev = obj.evaluated_get(dg).data
    buf = np.empty(len(ev.vertices) * 3, np.float32)
    ev.vertices.foreach_get("co", buf)
    assert np.abs(buf.reshape(-1, 3) - last).max() < 1e-4


def test_bake_animation_empty_range_reports(core):
    obj, *_ = bar_with_handles(core)
    with pytest.raises(RuntimeError, match="empty"):
        bpy.ops.larap.bake_animation(frame_start=5, frame_end=2)
