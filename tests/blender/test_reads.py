# SPDX-License-Identifier: GPL-3.0-or-later
# What Bind, a solve, adding a handle, a rebind, Bake and Apply read from Blender: every read of
# positions goes through mesh_data._get (as scripts/bench_addon_bind.py counts them), here told
# apart by what it reads (the mesh, the Basis, the pose key, the mix that gives vertex-group
# weights). What an operation has read once (its snapshot's rest shape and pose key) is not read
# again, and the arrays it shares are read only.
# Run: blender -b --factory-startup --python-exit-code 1 --python tests/blender/run_tests.py -- tests/blender/test_reads.py
import collections

import bpy
import numpy as np
import pytest

from conftest import activate, add_group, coarse, coords, diagonal, make_bar, posed_bar

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
    """The bar with its Right Empty moved up and turned, solved (conftest.posed_bar)."""
    obj, rest, _left, _right, targets, _pose = posed_bar(core)
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


# Bake and Apply (current_pose): the pose key and the Basis as their snapshot
# (transaction.preserve_on_error) read them serve current_pose's full validation and, when the key
# is behind its targets, the solve's check for hand edits before its write (whether the Basis
# changed too); Apply moves the Basis from them, and the removal of a Basis bind created takes the
# moved Basis as written. Each is read once.
STATES = ("up to date", "behind its targets", "behind, edited by hand")
EDITS = 'key_blocks["LARAP edits"].data'


@pytest.fixture
def basis_checks(core, monkeypatch):
    """What key_edits._basis_changed answered (the check for hand edits found some), in order."""
    from larap_blender import key_edits
    seen = []
    original = key_edits._basis_changed

    def spying(obj, rest=None):
        seen.append(original(obj, rest))
        return seen[-1]
    monkeypatch.setattr(key_edits, "_basis_changed", spying)
    return seen


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
def test_bake_reads_the_pose_key_and_the_basis_once(core, reads, basis_checks, state):
    from larap_blender import solving
    obj, rest, expected, key = _state(core, state)
    reads.clear()
    assert bpy.ops.larap.bake_shape_key(name="Baked") == {"FINISHED"}
    edited = state == "behind, edited by hand"
    # The snapshot: the mesh, the Basis, the pose key; the full validation: the groups (with the
    # snapshot's Basis, which a copy of hand edits compares with the recorded rest too).
    assert dict(reads) == {MESH: 1, BASIS: 1, POSE: 1, MIX: 1}
    assert basis_checks == ([False] if edited else [])
    assert np.array_equal(coords(obj, "Baked"), expected)  # the final pose of the targets, bit for bit
    assert np.array_equal(coords(obj, "LARAP"), expected) and solving.key_up_to_date(obj)
    assert np.array_equal(coords(obj, "Basis"), rest)
    names = [kb.name for kb in obj.data.shape_keys.key_blocks]
    assert names == ["Basis", "LARAP"] + (["LARAP edits"] if edited else []) + ["Baked"]
    if edited:  # the hand edits, kept as they were before the solve wrote the key
        assert np.array_equal(coords(obj, "LARAP edits"), key)


@pytest.mark.parametrize("state", STATES)
def test_apply_reads_the_pose_key_and_the_basis_once(core, reads, basis_checks, state):
    obj, rest, expected, key = _state(core, state)
    reads.clear()
    assert bpy.ops.larap.apply() == {"FINISHED"}
    edited = state == "behind, edited by hand"
    moved = rest + (expected - rest)  # the Basis moved by the pose's offsets (mesh_data.apply_offsets)
    assert not obj.larap.bound
    assert basis_checks == ([False] if edited else [])
    if edited:
        # The snapshot's three; the full validation's groups; of the keys moved, the copy of the
        # hand edits (made since the snapshot; the Basis is moved from the snapshot's).
        assert dict(reads) == {MESH: 1, BASIS: 1, POSE: 1, MIX: 1, EDITS: 1}
        assert [kb.name for kb in obj.data.shape_keys.key_blocks] == ["Basis", "LARAP edits"]
        assert np.array_equal(coords(obj, "Basis"), moved)
        assert np.array_equal(coords(obj, "LARAP edits"), key + (expected - rest))
        assert np.array_equal(coords(obj), expected)
    else:
        # ... and the Basis bind created, removed with the last key: the mesh takes its positions
        # as apply_offsets wrote them (not read back).
        assert dict(reads) == {MESH: 1, BASIS: 1, POSE: 1, MIX: 1}
        assert obj.data.shape_keys is None
        assert np.array_equal(coords(obj), moved)


def test_bake_after_a_basis_edit_tells_it_from_the_snapshot(core, reads, basis_checks):
    """The Basis and the pose key edited by a script, the targets moved: Bake's full validation
    rebuilds the engine on the snapshot's Basis, and the check for hand edits finds the Basis
    changed from the snapshot's too (the message says so), reading neither again."""
    from larap_blender import key_edits
    obj, rest, targets = posed(core)
    keys = obj.data.shape_keys.key_blocks
    keys["Basis"].data[5].co.z += 0.3
    keys["LARAP"].data[5].co.z += 0.3
    basis, key = coords(obj, "Basis"), coords(obj, "LARAP")
    engine = core.runtime(obj).deformer
    targets[1].location.z += 0.2
    bpy.context.view_layer.update()
    activate(obj)
    key_edits.take_messages()
    reads.clear()
    assert core.bake_shape_key(obj, "Baked").name == "Baked"
    assert dict(reads) == {MESH: 1, BASIS: 1, POSE: 1, MIX: 1}
    assert basis_checks == [True]
    assert any("the Basis was edited too" in m for m in key_edits.take_messages())
    rt = core.runtime(obj)
    assert rt.deformer is not engine and np.array_equal(rt.rest, basis)  # rebuilt on the edited Basis
    assert np.array_equal(coords(obj, "LARAP edits"), key)
    baked = coords(obj, "Baked")
    core.solve(obj, weights="final", validate="full", write=False)  # reading the Basis: the same engine
    assert core.runtime(obj).deformer is rt.deformer
    assert np.array_equal(baked, core.runtime(obj).out)


def test_a_solve_and_a_rebind_finding_hand_edits_read_the_basis_once(core, reads, basis_checks):
    """A full validation's rest (a solve's) and the snapshot's (a rebind's) serve the check for
    hand edits, which tells from them that the Basis did not change."""
    obj, rest, targets = posed(core)
    keys = obj.data.shape_keys.key_blocks
    keys["LARAP"].data[5].co.z += 0.3
    edited = coords(obj, "LARAP")
    targets[1].location.z += 0.1
    bpy.context.view_layer.update()
    reads.clear()
    assert bpy.ops.larap.solve() == {"FINISHED"}
    assert dict(reads) == {BASIS: 1, MIX: 1, POSE: 1}
    assert np.array_equal(coords(obj, "LARAP edits"), edited)
    keys["LARAP"].data[6].co.z += 0.3
    edited = coords(obj, "LARAP")
    reads.clear()
    assert bpy.ops.larap.bind() == {"FINISHED"}
    assert dict(reads) == {MESH: 1, BASIS: 1, POSE: 1, EDITS: 1, MIX: 1}  # (the snapshot reads every key)
    assert [kb.name for kb in obj.data.shape_keys.key_blocks] == ["Basis", "LARAP", "LARAP edits",
                                                                  "LARAP edits.001"]
    assert np.array_equal(coords(obj, "LARAP edits.001"), edited)
    assert basis_checks == [False, False]


def test_apply_moves_the_other_keys_from_the_snapshot(core, reads):
    """A key of the artist's moves with the Basis from the positions the snapshot read (not read
    again), bit for bit as from a read."""
    obj, rest, targets = posed(core)
    smile = obj.shape_key_add(name="Smile", from_mix=False)
    smile.data[7].co.y += 0.25
    smile.relative_key = obj.data.shape_keys.reference_key
    key, basis = coords(obj, "Smile").astype(np.float32), coords(obj, "Basis").astype(np.float32)
    targets[1].location.z += 0.2
    bpy.context.view_layer.update()
    core.solve(obj, weights="final", validate="full", write=False)
    expected = core.runtime(obj).out.copy()
    activate(obj)
    reads.clear()
    assert bpy.ops.larap.apply() == {"FINISHED"}
    assert dict(reads) == {MESH: 1, BASIS: 1, POSE: 1, MIX: 1, 'key_blocks["Smile"].data': 1}
    assert [kb.name for kb in obj.data.shape_keys.key_blocks] == ["Basis", "Smile"]
    assert np.array_equal(coords(obj, "Basis"), basis + (expected - basis))
    assert np.array_equal(coords(obj, "Smile"), key + (expected - basis))
    assert np.array_equal(coords(obj), expected)
