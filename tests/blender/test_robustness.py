# SPDX-License-Identifier: GPL-3.0-or-later
# Run: blender -b --factory-startup --python-exit-code 1 --python tests/blender/run_tests.py -- tests/blender/test_robustness.py
import bpy
import numpy as np
import pytest

from conftest import activate, bar_with_handles, coords, diagonal, make_bar


def test_removed_target_is_skipped(core):
    obj, rest, left, right, targets = bar_with_handles(core)
    targets[0].location.z += 0.5
    bpy.data.objects.remove(targets[1])
    assert obj.larap.handles[1].target is None
    assert bpy.ops.larap.solve() == {"FINISHED"}
    warnings = core.runtime(obj).warnings
    assert any("Right" in w and "no target" in w for w in warnings), warnings
    pose = coords(obj, "LARAP")
    assert np.abs(pose[left, 2] - rest[left, 2] - 0.5).max() < 0.02 * diagonal(rest)


def test_deleted_target_object_is_skipped(core):
    """bpy.ops.object.delete keeps the object alive (our pointer uses it) but out of every scene."""
    obj, rest, left, right, targets = bar_with_handles(core)
    activate(targets[1])
    bpy.ops.object.delete()
    activate(obj)
    assert bpy.ops.larap.solve() == {"FINISHED"}
    assert any("no target" in w for w in core.runtime(obj).warnings)


def test_deleted_vertex_group_is_skipped(core):
    obj, rest, left, right, targets = bar_with_handles(core)
    obj.vertex_groups.remove(obj.vertex_groups["Right"])
    targets[0].location.z += 0.5
    assert bpy.ops.larap.solve() == {"FINISHED"}
    assert any("vertex group not found" in w for w in core.runtime(obj).warnings)
    pose = coords(obj, "LARAP")
    assert np.abs(pose[left, 2] - rest[left, 2] - 0.5).max() < 0.02 * diagonal(rest)


def test_all_handles_gone_writes_rest(core):
    obj, rest, left, right, targets = bar_with_handles(core)
    for t in targets:
        bpy.data.objects.remove(t)
    assert bpy.ops.larap.solve() == {"FINISHED"}
    assert np.abs(coords(obj, "LARAP") - rest).max() < 1e-6


def test_live_handler_survives_deleted_target(core):
    obj, rest, left, right, targets = bar_with_handles(core)
    obj.larap.live = True
    targets[0].location.z += 0.2
    bpy.context.view_layer.update()
    bpy.data.objects.remove(targets[0])
    targets[1].location.z += 0.2
    bpy.context.view_layer.update()  # must not raise
    assert core.runtime(obj).last_error == ""


def test_handle_add_errors(core):
    obj, *_ = bar_with_handles(core)
    with pytest.raises(RuntimeError, match="no vertex group"):
        bpy.ops.larap.handle_add(vertex_group="Nope")
    with pytest.raises(RuntimeError, match="already a handle"):
        bpy.ops.larap.handle_add(vertex_group="Left")
    obj.vertex_groups.new(name="Empty")
    with pytest.raises(RuntimeError, match="no vertices"):
        bpy.ops.larap.handle_add(vertex_group="Empty")
    with pytest.raises(RuntimeError, match="No object named"):
        bpy.ops.larap.handle_add(vertex_group="Empty", target="Ghost")


def test_handle_remove(core):
    obj, rest, left, right, targets = bar_with_handles(core)
    name = targets[1].name
    assert bpy.ops.larap.handle_remove(index=1, delete_target=True, delete_group=True) == {"FINISHED"}
    assert len(obj.larap.handles) == 1
    assert name not in bpy.data.objects and "Right" not in obj.vertex_groups
    with pytest.raises(RuntimeError, match="No handle"):
        bpy.ops.larap.handle_remove(index=5)
    assert bpy.ops.larap.solve() == {"FINISHED"}


def test_existing_modifiers_groups_and_keys_kept(core):
    obj, rest, left, right, targets = bar_with_handles(core)
    obj.modifiers.new("Sub", "SUBSURF")
    obj.vertex_groups.new(name="Other")
    targets[1].location.z += 0.5
    bpy.ops.larap.solve()
    assert [m.name for m in obj.modifiers] == ["Sub"]
    assert {"Left", "Right", "Other"} <= set(obj.vertex_groups.keys())


def test_the_words_for_a_nan_target_a_rebind_without_target_and_an_unbound_unbind(core):
    """Each warning names its cause: a target with a NaN location is 'not a number' (it read
    'scaled to zero'); after a rebind, a handle whose target was deleted says it has no target
    (it read 'not bound (rebind)' on a mesh just rebound); Unbind on a mesh that is not bound says
    so and leaves no undo step."""
    obj, rest, left, right, targets = bar_with_handles(core)
    targets[1].location.x = float("nan")
    bpy.context.view_layer.update()
    activate(obj)
    assert bpy.ops.larap.solve() == {"FINISHED"}
    assert any("Right" in w and "not a number" in w for w in core.runtime(obj).warnings)
    targets[1].location.x = 2.0
    bpy.data.objects.remove(targets[1])
    assert bpy.ops.larap.bind() == {"FINISHED"}  # rebind, keeping the pose
    words = [w for w in core.runtime(obj).warnings if "Right" in w]
    assert words and all("no target" in w and "rebind" not in w for w in words), words
    assert bpy.ops.larap.unbind() == {"FINISHED"}
    assert bpy.ops.larap.unbind() == {"CANCELLED"}


def test_bind_from_the_panel_asks_first_for_a_lattice_of_minutes(core):
    """The estimate Bind's dialog reads: Cells as set, with Cell Size the grid around the box
    (a 4 x 0.5 x 0.5 bar at 0.01: 401 x 51 x 51 cells), Auto none."""
    from larap_blender import operators
    obj = make_bar()
    assert operators.estimated_cells(obj) == 0
    obj.larap.resolution_mode, obj.larap.cells = "CELLS", 200000
    assert operators.estimated_cells(obj) == 200000 > operators.LARGE_LATTICE
    obj.larap.resolution_mode, obj.larap.cell_size = "SIZE", 0.01
    assert operators.estimated_cells(obj) == 401 * 51 * 51
    obj.larap.cell_size = 1e-6  # the property's least: no overflow, still asks
    assert operators.estimated_cells(obj) > operators.LARGE_LATTICE
