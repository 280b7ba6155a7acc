# SPDX-License-Identifier: GPL-3.0-or-later
# Run: blender -b --factory-startup --python-exit-code 1 --python tests/blender/run_tests.py -- tests/blender/test_scene_index.py
"""The answers kept between updates (scene_index.py: the bound meshes of a scene, whether a target
is in a scene, whether a mesh is in the view layer) are never the reason a change goes unseen:
each change the index is told of shows at the next update, and one it is not told of within
MAX_AGE seconds."""
import bpy
import numpy as np

from conftest import activate, bar_with_handles, coords, diagonal


def live_move(target, dz):
    target.location.z += dz
    bpy.context.view_layer.update()


def moved_by(obj, rest, idx, dz):
    """Whether the pose key holds the vertices ``idx`` moved up by ``dz`` (2% of the size)."""
    return np.abs(coords(obj, "LARAP")[idx, 2] - rest[idx, 2] - dz).max() < 0.02 * diagonal(rest)


def test_a_live_duplicate_follows_from_its_first_move(core):
    obj, rest, left, right, targets = bar_with_handles(core)
    obj.larap.live = True
    live_move(targets[1], 0.3)  # the scene's bound meshes are now kept
    assert moved_by(obj, rest, right, 0.3)
    activate(obj)
    assert bpy.ops.object.duplicate() == {"FINISHED"}  # Shift+D
    dup = bpy.context.active_object
    assert dup != obj and dup.larap.bound and dup.larap.live
    live_move(targets[1], 0.2)
    assert moved_by(obj, rest, right, 0.5) and moved_by(dup, rest, right, 0.5)


def test_a_mesh_unlinked_and_linked_again_is_followed_again(core):
    obj, rest, left, right, targets = bar_with_handles(core)
    obj.larap.live = True
    scene = bpy.context.scene
    live_move(targets[1], 0.3)
    scene.collection.objects.unlink(obj)
    live_move(targets[1], 0.2)  # out of the scene: not posed
    assert moved_by(obj, rest, right, 0.3)
    scene.collection.objects.link(obj)
    live_move(targets[1], 0.1)
    assert moved_by(obj, rest, right, 0.6)


def test_a_deleted_target_is_reported_at_the_next_solve(core):
    obj, rest, left, right, targets = bar_with_handles(core)
    obj.larap.live = True
    live_move(targets[1], 0.3)  # both targets known to be in the scene
    activate(targets[1])
    bpy.ops.object.delete()
    activate(obj)
    assert bpy.ops.larap.solve() == {"FINISHED"}
    assert any("Right" in w and "no target" in w for w in core.runtime(obj).warnings)


def test_the_preview_sees_a_collection_excluded_at_once(core, gpu_preview):
    obj, rest, left, right, targets = bar_with_handles(core)
    coll = bpy.data.collections.new("Props")
    bpy.context.scene.collection.children.link(coll)
    coll.objects.link(obj)
    bpy.context.scene.collection.objects.unlink(obj)
    bpy.context.view_layer.update()
    assert not gpu_preview.blocker(obj)
    bpy.context.view_layer.layer_collection.children["Props"].exclude = True
    bpy.context.view_layer.update()
    assert gpu_preview.blocker(obj) == "not in the current view layer"
    bpy.context.view_layer.layer_collection.children["Props"].exclude = False
    bpy.context.view_layer.update()
    assert not gpu_preview.blocker(obj)


def test_a_change_the_index_is_not_told_of_shows_within_max_age(core, monkeypatch):
    """Bound set behind the add-on's back (the ID property written directly: no update callback,
    no depsgraph report): unseen while the kept list is fresh, seen once it is MAX_AGE old."""
    from larap_blender import scene_index
    obj, rest, left, right, targets = bar_with_handles(core)
    obj.larap.live = True
    scene = bpy.context.scene
    obj.larap["bound"] = False
    scene_index.invalidate()
    assert obj not in scene_index.bound_meshes(scene)  # kept without it
    obj.larap["bound"] = True
    live_move(targets[1], 0.3)
    assert moved_by(obj, rest, right, 0.0)  # not seen yet
    monkeypatch.setattr(scene_index, "MAX_AGE", 0.0)
    live_move(targets[1], 0.2)
    assert moved_by(obj, rest, right, 0.5)


def test_bound_set_by_a_script_is_seen_at_once(core):
    """``Object.larap.bound`` written through its property (by unbind, bind or a script) makes
    the index look again, with no depsgraph update in between."""
    from larap_blender import scene_index
    obj, rest, left, right, targets = bar_with_handles(core)
    scene = bpy.context.scene
    assert obj in scene_index.bound_meshes(scene)
    obj.larap.bound = False
    assert obj not in scene_index.bound_meshes(scene)
    obj.larap.bound = True
    assert obj in scene_index.bound_meshes(scene) and obj in scene_index.bound_meshes(None)
