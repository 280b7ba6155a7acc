# SPDX-License-Identifier: GPL-3.0-or-later
# Run: blender -b --factory-startup --python-exit-code 1 --python tests/blender/run_tests.py -- tests/blender/test_handle_groups.py
# Handles reach the engine as handle groups: one transform per handle, the vertex-group weights as
# a soft falloff, a per-handle Weight; a pose does nothing per handle vertex in Python.
import bpy
import numpy as np
import pytest

from conftest import activate, bar_with_handles, coords, diagonal, make_bar


def test_each_handle_is_one_group_moved_by_its_targets_transform(core, monkeypatch):
    import larap
    seen = {}
    real = larap.Deformer.solve

    def solve(self, targets=None, iterations=5, **kw):
        seen["targets"], seen["transforms"] = targets, kw.get("transforms")
        return real(self, targets, iterations, **kw)

    monkeypatch.setattr(larap.Deformer, "solve", solve)
    obj, rest, left, right, targets = bar_with_handles(core)
    targets[1].location.z += 0.4
    bpy.context.view_layer.update()
    core.solve(obj, weights="final")
    assert seen["targets"] is None and seen["transforms"].shape == (2, 4, 4)
    np.testing.assert_allclose(seen["transforms"][1][:3, 3], [0, 0, 0.4], atol=1e-6)
    pose = coords(obj, "LARAP")
    assert np.abs(pose[right, 2] - rest[right, 2] - 0.4).max() < 0.02 * diagonal(rest)


def test_a_pose_rebuilds_no_group(core):
    """Moving targets reuses the groups built once (no per-vertex work in Python per pose)."""
    obj, rest, left, right, targets = bar_with_handles(core)
    rt = core.runtime(obj)
    cache = rt.group_cache
    for z in (0.1, 0.2, 0.3):
        targets[1].location.z = z
        bpy.context.view_layer.update()
        core.solve(obj, weights="interactive", validate="fast")
    assert core.runtime(obj).group_cache is cache


def _miss(obj, targets, right, rest, lift):
    targets[1].location.z = lift
    bpy.context.view_layer.update()
    core_solve = __import__("larap_blender.core", fromlist=["solve"]).solve
    core_solve(obj, weights="final")
    pose = coords(obj, "LARAP")
    return np.abs(pose[right, 2] - (rest[right, 2] + lift)).mean()


def test_handle_weight_makes_it_pull_harder(core):
    obj, rest, left, right, targets = bar_with_handles(core)
    obj.larap.gamma = 2.0  # stiff: the handles miss measurably
    weak = _miss(obj, targets, right, rest, 1.0)
    obj.larap.handles[1].weight = 6.0
    strong = _miss(obj, targets, right, rest, 1.0)
    assert strong < 0.5 * weak, (strong, weak)


def test_vertex_group_weights_are_a_soft_falloff(core):
    """A handle vertex painted with a small weight follows its target less than one painted 1."""
    obj, rest, left, right, targets = bar_with_handles(core)
    obj.larap.gamma = 2.0
    vg = obj.vertex_groups["Right"]
    inner = right[rest[right, 0] < np.median(rest[right, 0])]
    full = _miss(obj, targets, right, rest, 1.0)  # every vertex of 'Right' painted 1
    painted_one = coords(obj, "LARAP")
    inner_miss_one = np.abs(painted_one[inner, 2] - (rest[inner, 2] + 1.0)).mean()
    vg.add([int(i) for i in inner], 0.05, "REPLACE")  # the inner half painted 0.05
    _miss(obj, targets, right, rest, 1.0)  # the membership is read again at the next full solve
    painted_low = coords(obj, "LARAP")
    inner_miss_low = np.abs(painted_low[inner, 2] - (rest[inner, 2] + 1.0)).mean()
    assert inner_miss_low > inner_miss_one + 1e-4 * diagonal(rest), (inner_miss_low, inner_miss_one)
    assert full < 0.05 * diagonal(rest)


def test_overlapping_groups_first_handle_wins(core):
    obj, rest, left, right, targets = bar_with_handles(core)
    both = np.flatnonzero(rest[:, 0] > 1.5)
    vg = obj.vertex_groups["Left"]
    vg.add([int(i) for i in both], 1.0, "REPLACE")  # 'Left' now also holds the right end
    targets[1].location.z = 0.5
    bpy.context.view_layer.update()
    res = core.solve(obj, weights="final")
    assert not res.warnings
    pose = coords(obj, "LARAP")
    # the right end belongs to the first handle ('Left', not moved): it stays
    assert np.abs(pose[right, 2] - rest[right, 2]).max() < 0.02 * diagonal(rest)
    rt = core.runtime(obj)
    ids = np.concatenate(rt.group_cache[1])
    assert len(ids) == len(np.unique(ids))


@pytest.mark.parametrize("scale", [(0.0, 0.0, 0.0), (1.0, 1.0, 1e-10), (100.0, 100.0, 1e-9)])
def test_target_scaled_to_zero_is_skipped_with_a_warning(core, scale):
    """A target the engine would reject as singular (relative to its size) is skipped with a
    warning; the other handle still poses."""
    obj, rest, left, right, targets = bar_with_handles(core)
    targets[1].scale = scale
    targets[0].location.z += 0.5
    bpy.context.view_layer.update()
    res = core.solve(obj, weights="final")
    assert any("'Right' skipped" in w and "scaled to zero" in w for w in res.warnings)
    assert res.handles == len(left)
    assert np.abs(coords(obj, "LARAP")[left, 2] - rest[left, 2] - 0.5).max() < 0.02 * diagonal(rest)


def test_a_small_uniform_scale_is_not_singular(core):
    obj, rest, left, right, targets = bar_with_handles(core)
    targets[1].scale = (1e-5, 1e-5, 1e-5)  # below the old absolute 1e-12
    bpy.context.view_layer.update()
    res = core.solve(obj, weights="final")
    assert not res.warnings and res.handles == len(left) + len(right)


def test_a_weight_painted_after_the_pose_makes_bake_solve_again(core):
    """The stored pose signature covers the handle groups' content: after a converged pose, a
    painted weight makes the pose key stale, and Bake writes the final pose of the new weights."""
    from larap_blender import solving
    from test_catchup import final_pose
    obj, rest, left, right, targets = bar_with_handles(core)
    targets[1].location.z += 0.8
    targets[1].rotation_euler.x = 0.6
    assert bpy.ops.larap.solve() == {"FINISHED"}
    stale = coords(obj, "LARAP")
    assert solving.key_up_to_date(obj)
    middle = np.flatnonzero(np.abs(rest[:, 0]) < 0.15)
    obj.vertex_groups["Right"].add([int(i) for i in middle], 1.0, "REPLACE")  # paint the middle in
    assert bpy.ops.larap.bake_shape_key(name="Baked") == {"FINISHED"}
    baked = coords(obj, "Baked")
    assert np.abs(baked[middle] - stale[middle]).max() > 0.05 * diagonal(rest)
    assert np.array_equal(baked.astype(np.float32), final_pose(core, obj))
    assert solving.key_up_to_date(obj)


def test_a_group_nobody_was_assigned_to_is_empty_not_every_vertex(core):
    """A mesh on which no vertex was ever assigned to a group has no weight layer, and Blender's
    mixer then ignores a key's vertex-group mask: a group created and not Assigned read as every
    vertex at weight 1 (the whole mesh became one handle). It reads as empty, and Add Handle says
    so; once vertices are assigned, it is the handle they make."""
    from larap_blender import mesh_data
    obj = make_bar()
    activate(obj)
    obj.vertex_groups.new(name="Forgot")
    w = mesh_data.vertex_group_weights(obj, ["Forgot"])["Forgot"]
    assert w.shape == (len(obj.data.vertices),) and not w.any()
    with pytest.raises(RuntimeError, match="has no vertices"):
        bpy.ops.larap.handle_add(vertex_group="Forgot")
    obj.vertex_groups["Forgot"].add([0, 1, 2], 1.0, "REPLACE")
    w = mesh_data.vertex_group_weights(obj, ["Forgot"])["Forgot"]
    assert np.flatnonzero(w).tolist() == [0, 1, 2] and np.allclose(w[:3], 1.0, atol=1e-6)
    everyone = obj.vertex_groups.new(name="Everyone")  # a group that really holds every vertex
    everyone.add(list(range(len(obj.data.vertices))), 1.0, "REPLACE")
    assert np.allclose(mesh_data.vertex_group_weights(obj, ["Everyone"])["Everyone"], 1.0, atol=1e-6)


@pytest.mark.parametrize("keys", [False, True])
def test_vertex_group_weights_of_many_groups_in_one_call(keys):
    """Seven groups read together (three per mix, on x, y and z; the last mix holds one): each
    group's own weights, an empty group among them and one left unassigned read as empty, and the
    object's shape keys as they were (names, mutes, values, active key) with or without keys."""
    from larap_blender import mesh_data
    obj = make_bar()
    activate(obj)
    n = len(obj.data.vertices)
    if keys:
        obj.shape_key_add(name="Basis", from_mix=False)
        other = obj.shape_key_add(name="Other", from_mix=False)
        other.value, other.mute = 0.3, True
        obj.active_shape_key_index = 1
    rng = np.random.default_rng(5)
    expect = {}
    for g in range(7):
        name = "G%d" % g
        vg = obj.vertex_groups.new(name=name)
        w = np.zeros(n, np.float32)
        if g != 4:  # G4: created, never assigned
            ids = rng.choice(n, size=n // 5, replace=False)
            w[ids] = rng.choice([0.25, 0.5, 0.75, 1.0], size=len(ids))
            for wt in (0.25, 0.5, 0.75, 1.0):
                vg.add([int(i) for i in ids[w[ids] == wt]], wt, "REPLACE")
        expect[name] = w
    before = [(kb.name, kb.mute, kb.value) for kb in obj.data.shape_keys.key_blocks] if keys else None
    got = mesh_data.vertex_group_weights(obj, list(expect))
    assert list(got) == list(expect)
    for name, w in expect.items():
        np.testing.assert_allclose(got[name], w, atol=1e-6, err_msg=name)
    assert not got["G4"].any()
    if keys:
        assert [(kb.name, kb.mute, kb.value) for kb in obj.data.shape_keys.key_blocks] == before
        assert obj.active_shape_key_index == 1
    else:
        assert obj.data.shape_keys is None
