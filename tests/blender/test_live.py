# SPDX-License-Identifier: GPL-3.0-or-later
# Run: blender -b --factory-startup --python-exit-code 1 --python tests/blender/run_tests.py -- tests/blender/test_live.py
import bpy
import numpy as np

from conftest import bar_with_handles, coords, diagonal


def test_live_update_on_target_move(core):
    obj, rest, left, right, targets = bar_with_handles(core)
    obj.larap.live = True
    rt = core.runtime(obj)
    version = rt.pose_version
    targets[1].location.z += 0.5
    bpy.context.view_layer.update()  # fires depsgraph_update_post
    assert rt.pose_version == version + 1
    assert rt.weights == "trilinear"  # interactive weights while live
    pose = coords(obj, "LARAP")
    assert np.abs(pose[right, 2] - rest[right, 2] - 0.5).max() < 0.02 * diagonal(rest)
    # Our own mesh update does not trigger another solve (no recursion), nor does an unrelated change.
    for _ in range(3):
        bpy.context.view_layer.update()
    other = bpy.data.objects.new("Other", None)
    bpy.context.scene.collection.objects.link(other)
    other.location.x = 3
    bpy.context.view_layer.update()
    assert rt.pose_version == version + 1


def test_live_off_does_nothing(core):
    obj, rest, left, right, targets = bar_with_handles(core)
    rt = core.runtime(obj)
    version = rt.pose_version
    targets[1].location.z += 0.5
    bpy.context.view_layer.update()
    assert rt.pose_version == version


def test_live_follows_animation(core):
    obj, rest, left, right, targets = bar_with_handles(core)
    obj.larap.live = True
    e = targets[1]
    e.keyframe_insert("location", frame=1)
    e.location.z += 1.0
    e.keyframe_insert("location", frame=10)
    bpy.context.scene.frame_set(10)
    pose = coords(obj, "LARAP")
    assert np.abs(pose[right, 2] - rest[right, 2] - 1.0).max() < 0.02 * diagonal(rest)


def test_live_update_after_reload_of_runtime(core):
    """The engine cache can vanish (file load, undo); live updates rebuild it lazily."""
    obj, rest, left, right, targets = bar_with_handles(core)
    obj.larap.live = True
    core.drop_runtime()
    targets[1].location.z += 0.5
    bpy.context.view_layer.update()
    assert core.runtime(obj) is not None
    pose = coords(obj, "LARAP")
    assert np.abs(pose[right, 2] - rest[right, 2] - 0.5).max() < 0.02 * diagonal(rest)
