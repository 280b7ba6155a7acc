# SPDX-License-Identifier: GPL-3.0-or-later
# Run: blender -b --factory-startup --python-exit-code 1 --python tests/blender/run_tests.py -- tests/blender/test_key_edits.py
"""Hand edits of the pose key (sculpt, Edit Mode, a script) are kept in a key of their own before
LARAP writes or removes the pose key (key_edits.py)."""
import bmesh
import bpy
import numpy as np
import pytest

from conftest import activate, bar_with_handles, coords

KEY = "LARAP"


def _edit_in_edit_mode(obj, key_name, ids, dz):
    """Move vertices ``ids`` by ``dz`` in Edit Mode with the shape key ``key_name`` active, as an
    artist would (Blender writes the edit into the active key when Edit Mode ends)."""
    activate(obj)
    obj.active_shape_key_index = obj.data.shape_keys.key_blocks.find(key_name)
    bpy.ops.object.mode_set(mode="EDIT")
    bm = bmesh.from_edit_mesh(obj.data)
    bm.verts.ensure_lookup_table()
    for i in ids:
        bm.verts[int(i)].co.z += dz
    bmesh.update_edit_mesh(obj.data)
    bpy.ops.object.mode_set(mode="OBJECT")


def _keys(obj):
    return [kb.name for kb in obj.data.shape_keys.key_blocks]


def _posed(core):
    obj, rest, left, right, targets = bar_with_handles(core)
    targets[1].location.z += 0.6
    bpy.context.view_layer.update()
    assert bpy.ops.larap.solve() == {"FINISHED"}
    return obj, rest, left, right, targets


def test_an_edit_mode_edit_of_the_pose_key_is_kept_before_the_next_solve(core):
    obj, rest, left, right, targets = _posed(core)
    middle = np.flatnonzero(np.abs(rest[:, 0]) < 0.5)
    before = coords(obj, KEY)
    _edit_in_edit_mode(obj, KEY, middle, 0.25)
    edited = coords(obj, KEY)
    assert np.abs(edited[middle, 2] - before[middle, 2] - 0.25).max() < 1e-6  # the edit is in the key
    targets[1].location.z += 0.3
    bpy.context.view_layer.update()
    activate(obj)
    result = core.solve(obj)
    copy = KEY + " edits"
    assert result.kept == copy and copy in _keys(obj)
    assert "kept in the shape key %r" % copy in result.warnings[0]
    kb = obj.data.shape_keys.key_blocks[copy]
    assert np.array_equal(coords(obj, copy), edited)  # bit for bit what the artist left
    assert kb.value == 0.0 and kb.relative_key == obj.data.shape_keys.reference_key
    # The pose key holds the new pose (the middle no longer carries the edit).
    assert np.abs(coords(obj, KEY)[middle, 2] - edited[middle, 2]).max() > 0.1
    assert core.runtime(obj).kept_edits == copy
    # Kept once: later solves write over LARAP's own pose and keep nothing more.
    for dz in (0.1, 0.2):
        targets[1].location.z += dz
        bpy.context.view_layer.update()
        assert core.solve(obj).kept is None
    assert [k for k in _keys(obj) if k.startswith(copy)] == [copy]


def test_a_script_edit_is_kept_and_an_unedited_key_never_copied(core):
    obj, rest, left, right, targets = _posed(core)
    for dz in (0.1, 0.2, 0.3):  # no edit: no copy, through final and interactive writes
        targets[1].location.z += dz
        bpy.context.view_layer.update()
        assert core.solve(obj, weights="interactive").kept is None
        assert core.solve(obj).kept is None
    assert _keys(obj) == ["Basis", KEY]
    kb = obj.data.shape_keys.key_blocks[KEY]
    kb.data[0].co.x += 1e-3  # one coordinate changed is enough to be seen
    edited = coords(obj, KEY)
    targets[1].location.z += 0.1
    bpy.context.view_layer.update()
    assert core.solve(obj, weights="interactive").kept == KEY + " edits"
    assert np.array_equal(coords(obj, KEY + " edits"), edited)
    # A second copy of new edits gets a name of its own; the first is never written again.
    first = coords(obj, KEY + " edits")
    kb.data[1].co.y -= 1e-3
    targets[1].location.z += 0.1
    bpy.context.view_layer.update()
    second = core.solve(obj).kept
    assert second not in (None, KEY + " edits") and second.startswith(KEY + " edits")
    assert np.array_equal(coords(obj, KEY + " edits"), first)


def test_a_basis_edit_keeps_the_moved_pose_key_once_and_says_why(core):
    """Blender moves the keys relative to the Basis with it: the pose key no longer holds what LARAP
    wrote. It is kept (a moved key cannot be told from a hand edit exactly), once, and the message
    names the Basis edit; through Live's fast solves too, whose record of the rest may be old."""
    obj, rest, left, right, targets = _posed(core)
    middle = np.flatnonzero(np.abs(rest[:, 0]) < 0.5)
    _edit_in_edit_mode(obj, "Basis", middle, 0.05)
    moved = coords(obj, KEY)
    activate(obj)
    targets[1].location.z += 0.1
    bpy.context.view_layer.update()
    r = core.solve(obj, weights="interactive", validate="fast")
    assert r.kept == KEY + " edits" and "the Basis was edited too" in r.warnings[0]
    assert np.array_equal(coords(obj, KEY + " edits"), moved)
    for weights in ("interactive", "final"):
        targets[1].location.z += 0.1
        bpy.context.view_layer.update()
        assert core.solve(obj, weights=weights).kept is None
    # A hand edit after Live's fast solves (which recorded the old rest's hash) is kept too.
    obj.data.shape_keys.key_blocks[KEY].data[2].co.z += 0.2
    edited = coords(obj, KEY)
    targets[1].location.z += 0.1
    bpy.context.view_layer.update()
    kept = core.solve(obj, weights="interactive", validate="fast").kept
    assert kept and np.array_equal(coords(obj, kept), edited)


def test_unbind_keeps_edits_of_the_key_it_removes_after_the_setting_was_renamed(core):
    obj, rest, left, right, targets = _posed(core)
    obj.data.shape_keys.key_blocks[KEY].data[5].co.z += 0.3
    edited = coords(obj, KEY)
    obj.larap.shape_key = "Other"  # the setting names another key; LARAP still owns "LARAP"
    activate(obj)
    assert bpy.ops.larap.unbind() == {"FINISHED"}
    assert KEY not in _keys(obj)
    assert np.array_equal(coords(obj, KEY + " edits"), edited)


def test_apply_and_bake_report_a_copy_they_made(core):
    from larap_blender import key_edits
    obj, rest, left, right, targets = _posed(core)
    obj.data.shape_keys.key_blocks[KEY].data[5].co.z += 0.3
    targets[1].location.z += 0.2  # the key is behind its targets: Bake solves and writes first
    bpy.context.view_layer.update()
    activate(obj)
    reports = []
    real = key_edits.take_messages

    def spy():
        out = real()
        reports.extend(out)
        return out
    key_edits.take_messages = spy
    try:
        assert bpy.ops.larap.bake_shape_key(name="Baked") == {"FINISHED"}
    finally:
        key_edits.take_messages = real
    assert KEY + " edits" in _keys(obj)
    assert any("kept in the shape key %r" % (KEY + " edits") in m for m in reports), reports
    assert bpy.ops.larap.apply() == {"FINISHED"}
    assert "_larap_key" not in obj


def test_bake_under_the_name_of_the_edits_copy_loses_nothing(core):
    """Bake named as the copy of hand edits will be ("LARAP edits", not there yet), with the key
    edited by hand and behind its targets: the catch-up keeps the edits under that name, so the
    bake stops with a clear message and leaves everything as it was (a review found the pose
    written over the edits, the message still naming them kept)."""
    from larap_blender.errors import LarapError
    obj, rest, left, right, targets = _posed(core)
    obj.data.shape_keys.key_blocks[KEY].data[5].co.z += 0.3
    edited = coords(obj, KEY).copy()
    targets[1].location.z += 0.2
    bpy.context.view_layer.update()
    activate(obj)
    before = {name: coords(obj, name).copy() for name in _keys(obj)}
    with pytest.raises(LarapError, match="copy of hand edits"):
        core.bake_shape_key(obj, KEY + " edits")
    assert _keys(obj) == list(before)  # put back: no copy, no bake
    for name, co in before.items():
        assert np.array_equal(coords(obj, name), co), name
    assert np.array_equal(coords(obj, KEY), edited)  # the edits, still in the pose key
    assert bpy.ops.larap.bake_shape_key(name="Baked") == {"FINISHED"}  # another name: kept, then baked
    assert np.array_equal(coords(obj, KEY + " edits"), edited)


def test_a_cancelled_drag_leaves_the_edits_where_they_were(core):
    """Without the preview a drag writes the pose key: its first step keeps the edits; cancel puts
    the edited key back and removes the copy, and the next solve keeps them again, once."""
    obj, rest, left, right, targets = _posed(core)
    kb = obj.data.shape_keys.key_blocks[KEY]
    kb.data[3].co.z += 0.2
    edited = coords(obj, KEY)
    record = obj["_larap_key"]
    session = core.PoseSession(obj, 1).begin()
    r = session.update(translation=(0.0, 0.2, 0.1))
    assert r.kept == KEY + " edits" and KEY + " edits" in _keys(obj)
    session.update(translation=(0.0, 0.3, 0.1))
    session.cancel()
    assert _keys(obj) == ["Basis", KEY]
    assert np.array_equal(coords(obj, KEY), edited)
    assert obj["_larap_key"] == record
    targets[1].location.z += 0.1
    bpy.context.view_layer.update()
    assert core.solve(obj).kept == KEY + " edits"
    assert np.array_equal(coords(obj, KEY + " edits"), edited)


def test_a_confirmed_drag_keeps_the_edits(core):
    obj, rest, left, right, targets = _posed(core)
    obj.data.shape_keys.key_blocks[KEY].data[3].co.z += 0.2
    edited = coords(obj, KEY)
    session = core.PoseSession(obj, 1).begin()
    session.update(translation=(0.0, 0.2, 0.1))
    session.confirm()
    assert np.array_equal(coords(obj, KEY + " edits"), edited)
    assert _keys(obj) == ["Basis", KEY, KEY + " edits"]


def test_unbind_keeps_hand_edits_and_removes_only_what_larap_wrote(core):
    obj, rest, left, right, targets = _posed(core)
    activate(obj)
    assert bpy.ops.larap.unbind() == {"FINISHED"}
    assert obj.data.shape_keys is None  # bind created the Basis; nothing edited: all of it goes
    assert "_larap_key" not in obj

    assert bpy.ops.larap.bind() == {"FINISHED"}
    assert bpy.ops.larap.solve() == {"FINISHED"}
    obj.data.shape_keys.key_blocks[KEY].data[5].co.z += 0.3
    edited = coords(obj, KEY)
    assert bpy.ops.larap.unbind() == {"FINISHED"}
    assert _keys(obj) == ["Basis", KEY + " edits"]
    assert np.array_equal(coords(obj, KEY + " edits"), edited)
    assert obj.data.shape_keys.key_blocks[KEY + " edits"].value == 0.0
    assert np.abs(coords(obj, "Basis") - rest).max() == 0  # the mesh shows its rest shape
    assert "_larap_key" not in obj and not obj.larap.bound


def test_apply_keeps_what_is_shown_edits_included(core):
    """The pose key holds the final pose of the current targets plus a hand edit: Apply keeps what
    is shown, as it always has (no solve, so no copy)."""
    obj, rest, left, right, targets = _posed(core)
    obj.data.shape_keys.key_blocks[KEY].data[5].co.z += 0.3
    shown = coords(obj, KEY)
    activate(obj)
    assert bpy.ops.larap.apply() == {"FINISHED"}
    assert np.abs(coords(obj) - shown).max() < 1e-6  # Basis + (pose - Basis) in float32
    assert obj.data.shape_keys is None


def test_undo_restores_the_record_with_the_key(core):
    """An undo brings back an older pose key and the record of that write: no false copy."""
    obj, rest, left, right, targets = _posed(core)
    bpy.ops.ed.undo_push(message="pose A")
    targets[1].location.z += 0.3
    bpy.context.view_layer.update()
    assert bpy.ops.larap.solve() == {"FINISHED"}
    bpy.ops.ed.undo_push(message="pose B")
    name = obj.name
    assert bpy.ops.ed.undo() == {"FINISHED"}
    obj = bpy.data.objects[name]
    activate(obj)
    obj.larap.handles[1].target.location.z += 0.2
    bpy.context.view_layer.update()
    from larap_blender import core as core2
    assert core2.solve(obj).kept is None
    assert _keys(obj) == ["Basis", KEY]


def test_a_failed_operation_restores_the_record(core):
    from larap_blender.transaction import preserve_on_error
    obj, rest, left, right, targets = _posed(core)
    obj.data.shape_keys.key_blocks[KEY].data[3].co.z += 0.2
    edited = coords(obj, KEY)
    record = obj["_larap_key"]
    targets[1].location.z += 0.2
    bpy.context.view_layer.update()
    try:
        with preserve_on_error(obj):
            assert core.solve(obj).kept == KEY + " edits"
            assert obj["_larap_key"] != record  # the new pose's
            raise RuntimeError("part-way")
    except RuntimeError:
        pass
    assert _keys(obj) == ["Basis", KEY]
    assert np.array_equal(coords(obj, KEY), edited)
    assert obj["_larap_key"] == record
    assert core.solve(obj).kept == KEY + " edits"
