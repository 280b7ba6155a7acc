# SPDX-License-Identifier: GPL-3.0-or-later
# What Bind, a solve, adding a handle, a rebind, Bake and Apply read from Blender: every read of
# positions goes through mesh_data._get (as scripts/bench_addon_bind.py counts them), here told
# apart by what it reads (the mesh, the Basis, the pose key, the mix that gives vertex-group
# weights). What an operation has read once (its snapshot's rest shape and pose key) is not read
# again, and the arrays it shares are read only.
# Run: blender -b --factory-startup --python-exit-code 1 --python tests/blender/run_tests.py -- tests/blender/test_reads.py
import collections
import math

import bpy
import numpy as np
import pytest
from mathutils import Euler

from conftest import activate, add_group, bar_with_handles, coarse, coords, diagonal, make_bar

MESH = "vertices"
BASIS = 'key_blocks["Basis"].data'
POSE = 'key_blocks["LARAP"].data'
MIX = 'key_blocks["_larap_mix"].data'  # the mix that gives three groups' weights (vertex_group_weights)


@pytest.fixture
def reads(core, monkeypatch):
    """A Counter of the positions read through mesh_data._get, by what they are read from."""
    from larap_blender import mesh_data
    count = collections.Counter()
    original = mesh_data._get

    def counted(collection, attr, n, dtype, width=1):
        if attr == "co":
            count[collection.path_from_id()] += 1
        return original(collection, attr, n, dtype, width)
    monkeypatch.setattr(mesh_data, "_get", counted)  # (mesh_data's functions look _get up at each call)
    return count


def posed(core):
    """The bar with its Right Empty moved up and turned, solved."""
    obj, rest, left, right, targets = bar_with_handles(core)
    targets[1].location.z += 0.6
    targets[1].rotation_euler = Euler((0.0, math.radians(-30), 0.0))
    bpy.context.view_layer.update()
    assert bpy.ops.larap.solve() == {"FINISHED"}
    return obj, rest, targets


def test_bind_solve_and_rebind_read_each_shape_once(core, reads):
    obj = make_bar()
    rest = coords(obj)
    add_group(obj, "Left", np.flatnonzero(rest[:, 0] < -1.8))
    add_group(obj, "Right", np.flatnonzero(rest[:, 0] > 1.8))
    assert bpy.ops.larap.handle_add(vertex_group="Left") == {"FINISHED"}
    assert bpy.ops.larap.handle_add(vertex_group="Right") == {"FINISHED"}
    coarse(obj)
    targets = [h.target for h in obj.larap.handles]
    reads.clear()
    assert bpy.ops.larap.bind() == {"FINISHED"}  # first Bind: the snapshot's mesh is the rest
    # (the handle groups are read with it, before the solve, whose fast validation would read the Basis)
    assert dict(reads) == {MESH: 1, MIX: 1}
    targets[1].location.z += 0.1
    bpy.context.view_layer.update()
    reads.clear()
    assert bpy.ops.larap.solve() == {"FINISHED"}  # full validation: the rest; the pose key before its write
    assert dict(reads) == {BASIS: 1, MIX: 1, POSE: 1}
    pose = coords(obj, "LARAP")
    reads.clear()
    assert bpy.ops.larap.bind() == {"FINISHED"}  # rebind: the snapshot's Basis and pose key serve it all
    assert dict(reads) == {MESH: 1, BASIS: 1, POSE: 1, MIX: 1}
    assert np.abs(coords(obj, "LARAP") - pose).max() < 1e-3 * diagonal(rest)


def test_a_rebind_fits_a_handle_without_rest_to_the_snapshot(core, reads):
    """A handle with no rest (a retarget that could not record one) gets one at rebind from the
    pose key (targets.pose_fit), fed the snapshot's rest and pose key: the same rest as when it
    read them from Blender, bit for bit."""
    from larap_blender import targets as targets_module
    obj, rest, targets = posed(core)
    pose = coords(obj, "LARAP")
    h = obj.larap.handles[1]
    h.has_rest = False
    motion = targets_module.pose_fit(obj, h)  # reading the vertex group, the Basis and the pose key
    expected = tuple(targets_module.flat(motion.inverted_safe() @ targets_module.target_matrix(h)))
    reads.clear()
    assert bpy.ops.larap.bind() == {"FINISHED"}
    assert dict(reads) == {MESH: 1, BASIS: 1, POSE: 1, MIX: 1}
    assert h.has_rest and tuple(h.rest_matrix) == expected
    assert np.abs(coords(obj, "LARAP") - pose).max() < 0.01 * diagonal(rest)  # the pose kept (a fit)


def test_a_handle_with_a_target_added_to_a_posed_mesh_reads_the_rest_once(core, reads):
    obj, rest, targets = posed(core)
    add_group(obj, "Mid", np.flatnonzero(np.abs(rest[:, 0]) < 0.1))
    empty = bpy.data.objects.new("MidTarget", None)
    bpy.context.scene.collection.objects.link(empty)
    empty.location = (0.0, 4.0, 0.0)
    bpy.context.view_layer.update()
    activate(obj)
    reads.clear()
    assert bpy.ops.larap.handle_add(vertex_group="Mid", target="MidTarget") == {"FINISHED"}
    # The rest for the group and the fit that keeps the pose; the pose key for the fit.
    assert dict(reads) == {BASIS: 1, MIX: 1, POSE: 1}
    assert obj.larap.handles[2].has_rest


def test_the_rest_shape_and_the_snapshot_are_read_only(core, monkeypatch):
    """The runtime's rest is the snapshot's array (no copy): neither can be written by mistake."""
    obj, rest, targets = posed(core)
    seen = []
    original = core._bind

    def spying(obj_, keep_pose, p, snap):
        seen.append(snap)
        return original(obj_, keep_pose, p, snap)
    monkeypatch.setattr(core, "_bind", spying)
    assert bpy.ops.larap.bind() == {"FINISHED"}
    snap, = seen
    arrays = [snap["mesh"]] + [entry[1] for entry in snap["keys"]]
    assert [e[0] for e in snap["keys"]] == ["Basis", "LARAP"]
    assert not any(a.flags.writeable for a in arrays)
    rt = core.runtime(obj)
    assert rt.rest is snap["rest"] and rt.rest is snap["keys"][0][1]  # the Basis as the snapshot read it
    with pytest.raises(ValueError, match="read-only"):
        rt.rest[0, 0] = 1.0
    assert rt.out.flags.writeable  # the solve's own buffer
    assert bpy.ops.larap.solve() == {"FINISHED"}  # a full validation: the rest read again, read only again
    assert core.runtime(obj).rest is not snap["rest"] and not core.runtime(obj).rest.flags.writeable
    assert np.array_equal(core.runtime(obj).rest, rest.astype(np.float32))


# Bake and Apply (current_pose): the pose key as their snapshot (transaction.preserve_on_error) read
# it serves current_pose and, when the key is behind its targets, the solve's check for hand edits
# before its write. The Basis is read again by current_pose's full validation (and by Apply's move
# of the keys, and the removal of a Basis bind created); those reads are not the pose key's.
STATES = ("up to date", "behind its targets", "behind, edited by hand")
EDITS = 'key_blocks["LARAP edits"].data'


def _state(core, state):
    """The posed bar with its pose key in ``state``; returns (obj, rest, the final solve of the
    targets as they are now, the pose key's positions now)."""
    obj, rest, targets = posed(core)
    if state != "up to date":
        if state == "behind, edited by hand":
            obj.data.shape_keys.key_blocks["LARAP"].data[5].co.z += 0.3
        targets[1].location.z += 0.2
        bpy.context.view_layer.update()
    key = coords(obj, "LARAP").astype(np.float32)
    core.solve(obj, weights="final", validate="full", write=False)  # what a final solve writes (deterministic)
    expected = core.runtime(obj).out.copy()
    assert np.array_equal(coords(obj, "LARAP"), key)  # (that solve wrote nothing)
    assert np.array_equal(key, expected) == (state == "up to date")
    activate(obj)
    return obj, rest.astype(np.float32), expected, key


@pytest.mark.parametrize("state", STATES)
def test_bake_reads_the_pose_key_once(core, reads, state):
    from larap_blender import solving
    obj, rest, expected, key = _state(core, state)
    reads.clear()
    assert bpy.ops.larap.bake_shape_key(name="Baked") == {"FINISHED"}
    edited = state == "behind, edited by hand"
    # The snapshot: the mesh, the Basis, the pose key; the full validation: the Basis and the
    # groups; a copy of hand edits: the Basis (whether it changed too).
    assert dict(reads) == {MESH: 1, BASIS: 3 if edited else 2, POSE: 1, MIX: 1}
    assert np.array_equal(coords(obj, "Baked"), expected)  # the final pose of the targets, bit for bit
    assert np.array_equal(coords(obj, "LARAP"), expected) and solving.key_up_to_date(obj)
    assert np.array_equal(coords(obj, "Basis"), rest)
    names = [kb.name for kb in obj.data.shape_keys.key_blocks]
    assert names == ["Basis", "LARAP"] + (["LARAP edits"] if edited else []) + ["Baked"]
    if edited:  # the hand edits, kept as they were before the solve wrote the key
        assert np.array_equal(coords(obj, "LARAP edits"), key)


@pytest.mark.parametrize("state", STATES)
def test_apply_reads_the_pose_key_once(core, reads, state):
    obj, rest, expected, key = _state(core, state)
    reads.clear()
    assert bpy.ops.larap.apply() == {"FINISHED"}
    edited = state == "behind, edited by hand"
    moved = rest + (expected - rest)  # the Basis moved by the pose's offsets (mesh_data.apply_offsets)
    assert not obj.larap.bound
    if edited:
        # The snapshot's three; the full validation's Basis and groups; the copy's check of the
        # Basis; the keys moved (the Basis, the copy).
        assert dict(reads) == {MESH: 1, BASIS: 4, POSE: 1, MIX: 1, EDITS: 1}
        assert [kb.name for kb in obj.data.shape_keys.key_blocks] == ["Basis", "LARAP edits"]
        assert np.array_equal(coords(obj, "Basis"), moved)
        assert np.array_equal(coords(obj, "LARAP edits"), key + (expected - rest))
        assert np.array_equal(coords(obj), expected)
    else:
        # ... and the Basis bind created, removed with the last key: the mesh takes its positions.
        assert dict(reads) == {MESH: 1, BASIS: 4, POSE: 1, MIX: 1}
        assert obj.data.shape_keys is None
        assert np.array_equal(coords(obj), moved)
