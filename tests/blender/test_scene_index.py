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


def test_the_preview_draw_sees_a_collection_hidden_at_once(core, gpu_preview):
    """The draw's test (kept between redraws) follows a collection's eye, its Disable in
    Viewports and a parent's eye at the next update, and an object in two collections stays
    drawn while one of them is shown."""
    from larap_blender import scene_index
    obj, rest, left, right, targets = bar_with_handles(core)
    outer = bpy.data.collections.new("Outer")
    inner = bpy.data.collections.new("Inner")
    other = bpy.data.collections.new("Other")
    bpy.context.scene.collection.children.link(outer)
    bpy.context.scene.collection.children.link(other)
    outer.children.link(inner)
    inner.objects.link(obj)
    bpy.context.scene.collection.objects.unlink(obj)
    layer = bpy.context.view_layer
    layer.update()

    def drawn():
        layer.update()
        return gpu_preview._visible_here(obj, layer, None)
    assert drawn() and drawn()  # the second answer is the kept one
    lc_outer = layer.layer_collection.children["Outer"]
    lc_inner = lc_outer.children["Inner"]
    for hide, show in ((lambda: setattr(lc_inner, "hide_viewport", True),
                        lambda: setattr(lc_inner, "hide_viewport", False)),
                       (lambda: setattr(lc_outer, "hide_viewport", True),
                        lambda: setattr(lc_outer, "hide_viewport", False)),
                       (lambda: setattr(inner, "hide_viewport", True),
                        lambda: setattr(inner, "hide_viewport", False))):
        hide()
        assert not drawn()
        show()
        assert drawn()
    other.objects.link(obj)  # in two collections: one hidden, the other still shows it
    lc_inner.hide_viewport = True
    assert drawn()
    layer.layer_collection.children["Other"].hide_viewport = True
    assert not drawn()
    assert not scene_index.in_visible_collection(obj, None)


def test_a_change_the_index_is_not_told_of_shows_at_the_first_update_after_max_age(core, monkeypatch):
    """Bound set behind the add-on's back (the ID property written directly: no update callback,
    no depsgraph report) while the mesh's target moves: the first update after the kept list is
    MAX_AGE old reads it again, finds the mesh new to it and poses it, though that update moved
    only an unrelated object."""
    from larap_blender import scene_index
    obj, rest, left, right, targets = bar_with_handles(core)
    obj.larap.live = True
    scene = bpy.context.scene
    other = bpy.data.objects.new("Unrelated", None)
    scene.collection.objects.link(other)
    bpy.context.view_layer.update()  # the link reported (and the lists forgotten) now, not later
    obj.larap["bound"] = False
    scene_index.invalidate()
    assert obj not in scene_index.bound_meshes(scene)  # kept without it
    obj.larap["bound"] = True
    live_move(targets[1], 0.3)
    monkeypatch.setattr(scene_index, "MAX_AGE", 0.0)
    live_move(other, 0.1)
    assert moved_by(obj, rest, right, 0.3)


def test_a_mesh_linked_by_a_script_before_a_frame_step_is_posed_in_that_frame(core):
    """Changes a frame's evaluation carries (a pipeline script linking an asset, then frame_set)
    reach frame_change_post only: it tells the index too."""
    obj, rest, left, right, targets = bar_with_handles(core)
    obj.larap.live = True
    scene = bpy.context.scene
    scene.collection.objects.unlink(obj)
    bpy.context.view_layer.update()
    scene.frame_set(2)  # the scene's bound meshes read: none
    scene.collection.objects.link(obj)
    targets[1].location.z += 0.3
    scene.frame_set(3)
    assert moved_by(obj, rest, right, 0.3)


def test_the_catch_up_of_a_full_copy_of_the_scene_is_not_dropped(core):
    """Scene > New > Full Copy reports nothing to depsgraph_update_post, only to frame_change_post
    (every ID of the new scene): the catch-up must not decide from a kept list of the file's bound
    meshes that the copy's pending pose has no mesh."""
    from larap_blender import catchup, solving
    obj, rest, left, right, targets = bar_with_handles(core)
    obj.larap.live = True
    live_move(targets[1], 0.3)
    catchup.catch_up_all()  # the file's bound meshes are kept now
    assert solving.key_up_to_date(obj)
    assert bpy.ops.scene.new(type="FULL_COPY") == {"FINISHED"}
    copy = next(o for o in bpy.context.scene.objects if o.type == "MESH")
    assert copy != obj
    live_move(copy.larap.handles[1].target, 0.2)
    catchup.catch_up_all()
    assert solving.key_up_to_date(copy) and moved_by(copy, rest, right, 0.5)


def test_the_catch_up_reads_the_file_again_before_it_drops_a_pending_mesh(core):
    """A mesh behind its targets, missing from the kept list of the file's bound meshes (bound
    set behind the add-on's back): the catch-up looks again and writes its pose rather than
    forgetting it."""
    from larap_blender import catchup, handlers, scene_index, solving
    obj, rest, left, right, targets = bar_with_handles(core)
    obj.larap.live = True
    live_move(targets[1], 0.3)
    catchup.catch_up_all()
    obj.larap["bound"] = False
    scene_index.invalidate()
    assert obj not in scene_index.bound_meshes(None)  # kept without it
    obj.larap["bound"] = True
    with handlers.suspend_live():
        live_move(targets[1], 0.2)
    core.runtime(obj).needs_catchup = True  # as a live move leaves it
    catchup.catch_up_all()
    assert solving.key_up_to_date(obj) and moved_by(obj, rest, right, 0.5)


def test_an_undo_right_after_the_lists_were_read_keeps_the_engines(core):
    """Undo replaces the objects: the lists kept before it are not what undo_post prunes the
    runtime cache by (it would drop every engine and rebuild them)."""
    from larap_blender import catchup, scene_index
    obj, rest, left, right, targets = bar_with_handles(core)
    obj.larap.live = True
    live_move(targets[1], 0.3)
    assert bpy.ops.ed.undo_push(message="posed") == {"FINISHED"}
    live_move(targets[0], 0.1)
    assert bpy.ops.ed.undo_push(message="moved") == {"FINISHED"}
    catchup.catch_up_all()
    scene_index.bound_meshes(None), scene_index.bound_meshes(bpy.context.scene)
    key = obj.larap.runtime_id
    engine = core._RUNTIMES[key]
    assert bpy.ops.ed.undo() == {"FINISHED"}
    assert core._RUNTIMES.get(key) is engine
    obj, target = bpy.data.objects["Bar"], bpy.data.objects["LARAP_target_Right"]
    live_move(target, 0.2)
    assert moved_by(obj, rest, right, 0.5)


def test_an_answer_is_not_given_for_another_object_at_the_same_address(core):
    """A freed object's address is soon reused (a script removes an orphan and makes an Empty):
    the kept answer belongs to the object it was made for."""
    from larap_blender import scene_index
    bar_with_handles(core)
    orphan = bpy.data.objects.new("Orphan", None)
    assert not scene_index.target_alive(orphan)
    bpy.data.objects.remove(orphan)
    empty = bpy.data.objects.new("Empty", None)
    bpy.context.scene.collection.objects.link(empty)
    assert scene_index.target_alive(empty)


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


def test_the_view_layer_answer_is_not_given_for_another_object_at_the_same_address(core):
    from larap_blender import scene_index
    bar_with_handles(core)
    view_layer = bpy.context.view_layer
    first = bpy.data.objects.new("First", None)
    bpy.context.scene.collection.objects.link(first)
    view_layer.update()  # its base is made when the view layer is synced
    assert scene_index.in_view_layer(first, view_layer)
    bpy.data.objects.remove(first)
    second = bpy.data.objects.new("Second", None)  # in no collection
    assert not scene_index.in_view_layer(second, view_layer)


def test_a_scene_made_where_a_removed_one_was_does_not_get_its_meshes(core):
    from larap_blender import scene_index
    obj, *_ = bar_with_handles(core)
    old = bpy.data.scenes.new("Old")
    old.collection.objects.link(obj)
    assert obj in scene_index.bound_meshes(old)
    bpy.data.scenes.remove(old)
    new = bpy.data.scenes.new("New")
    assert obj not in scene_index.bound_meshes(new)


def test_a_view_layer_made_where_a_removed_one_was_gets_its_own_answer(core):
    from larap_blender import scene_index
    obj, *_ = bar_with_handles(core)
    scene = bpy.context.scene
    props = bpy.data.collections.new("Props")
    scene.collection.children.link(props)
    props.objects.link(obj)
    scene.collection.objects.unlink(obj)
    first = scene.view_layers.new("First")
    first.layer_collection.children["Props"].exclude = True
    first.update()
    assert not scene_index.in_view_layer(obj, first)
    scene.view_layers.remove(first)
    second = scene.view_layers.new("Second")  # Props included
    second.update()
    assert scene_index.in_view_layer(obj, second)
