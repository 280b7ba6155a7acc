# SPDX-License-Identifier: GPL-3.0-or-later
# Retargeting a handle and rebinding keep the pose; going back to rest is its own action.
# Run: blender -b --factory-startup --python-exit-code 1 --python tests/blender/run_tests.py -- tests/blender/test_retarget_rebind.py
import bpy
import numpy as np
import pytest
from mathutils import Euler, Matrix, Vector

from conftest import activate, bar_with_handles, coords, diagonal, posed_bar


def new_empty(name, location, rotation=(0.0, 0.0, 0.0)):
    e = bpy.data.objects.new(name, None)
    bpy.context.scene.collection.objects.link(e)
    e.location = location
    e.rotation_euler = Euler(rotation)
    bpy.context.view_layer.update()
    return e


def armature(name="Arm"):
    arm_data = bpy.data.armatures.new(name)
    arm = bpy.data.objects.new(name, arm_data)
    bpy.context.scene.collection.objects.link(arm)
    activate(arm)
    bpy.ops.object.mode_set(mode="EDIT")
    b = arm_data.edit_bones.new("Tip")
    b.head, b.tail = (2.5, 1.0, 0.0), (3.5, 1.0, 0.3)
    bpy.ops.object.mode_set(mode="OBJECT")
    arm.location = (0.3, -0.2, 0.1)
    bpy.context.view_layer.update()
    return arm


def test_retarget_to_an_empty_keeps_the_pose(core):
    obj, rest, left, right, targets, pose = posed_bar(core)
    diag = diagonal(rest)
    other = new_empty("Elsewhere", (5.0, -3.0, 2.0), (0.4, 0.2, 1.1))  # far away, turned
    obj.larap.handles[1].target = other  # as the panel's field does (the update callback)
    h = obj.larap.handles[1]
    assert h.has_rest and h.rest_target == other
    activate(obj)
    assert bpy.ops.larap.solve() == {"FINISHED"}
    assert np.abs(coords(obj, "LARAP") - pose).max() < 1e-3 * diag  # no jump
    # The new target now poses the handle: moving it up moves the handle's vertices up as much.
    other.location.z += 0.4
    bpy.context.view_layer.update()
    bpy.ops.larap.solve()
    moved = coords(obj, "LARAP")
    assert abs((moved[right, 2] - pose[right, 2]).mean() - 0.4) < 0.02 * diag


def test_retarget_to_an_armature_then_a_bone_keeps_the_pose(core):
    obj, rest, left, right, targets, pose = posed_bar(core)
    diag = diagonal(rest)
    arm = armature()
    h = obj.larap.handles[1]
    h.target = arm  # first the armature object (no bone yet) ...
    activate(obj)
    bpy.ops.larap.solve()
    assert np.abs(coords(obj, "LARAP") - pose).max() < 1e-3 * diag
    h.subtarget = "Tip"  # ... then its bone: each step keeps the pose
    assert h.rest_target == arm and h.rest_subtarget == "Tip"
    bpy.ops.larap.solve()
    assert np.abs(coords(obj, "LARAP") - pose).max() < 1e-3 * diag
    arm.pose.bones["Tip"].location = (0.0, 0.0, 0.3)  # bone-local z: here the world's -x..z plane
    bpy.context.view_layer.update()
    bpy.ops.larap.solve()
    assert np.abs(coords(obj, "LARAP")[right] - pose[right]).max() > 0.1  # the bone poses it now
    # Back from the bone to an Empty: the bone name is cleared, the pose still kept.
    posed_by_bone = coords(obj, "LARAP")
    e = new_empty("Back", (0.0, 0.0, 0.0))
    h.target = e
    assert h.subtarget == ""
    bpy.ops.larap.solve()
    assert np.abs(coords(obj, "LARAP") - posed_by_bone).max() < 1e-3 * diag


def test_retarget_without_the_old_target_fits_the_pose(core):
    """A file bound before rest targets were recorded (or the old target deleted): the motion
    comes from where the pose key shows the handle's vertices."""
    obj, rest, left, right, targets, pose = posed_bar(core)
    diag = diagonal(rest)
    h = obj.larap.handles[1]
    h.rest_target = None
    h.target = new_empty("Fresh", (1.0, 2.0, 3.0), (0.3, 0.0, 0.0))
    activate(obj)
    bpy.ops.larap.solve()
    assert np.abs(coords(obj, "LARAP") - pose).max() < 0.01 * diag


def test_retarget_of_an_unbound_mesh_records_nothing(core):
    from conftest import add_group, make_bar
    obj = make_bar()
    add_group(obj, "G", [0, 1, 2])
    bpy.ops.larap.handle_add(vertex_group="G")
    h = obj.larap.handles[0]
    before = tuple(h.rest_matrix)
    h.target = new_empty("X", (1.0, 1.0, 1.0))
    assert tuple(h.rest_matrix) == before  # bind records the rest


def subdivide(obj):
    activate(obj)
    obj.active_shape_key_index = 0
    bpy.ops.object.mode_set(mode="EDIT")
    bpy.ops.mesh.select_all(action="SELECT")
    bpy.ops.mesh.subdivide()
    bpy.ops.object.mode_set(mode="OBJECT")


def group_ids(obj, name):
    from larap_blender import mesh_data
    return np.flatnonzero(mesh_data.vertex_group_weights(obj, [name])[name] > 0)


def test_rebind_after_subdivide_keeps_the_pose_and_empties_stay_with_their_vertices(core):
    obj, rest, left, right, targets, pose = posed_bar(core)
    diag = diagonal(rest)
    empty_before = targets[1].matrix_world.copy()
    gap_before = np.linalg.norm(pose[right].mean(axis=0) - np.array(targets[1].matrix_world.translation))
    n = len(rest)
    subdivide(obj)
    assert len(obj.data.vertices) > n
    with pytest.raises(RuntimeError, match="topology"):
        bpy.ops.larap.solve()
    assert bpy.ops.larap.bind() == {"FINISHED"}  # the panel's Rebind
    after = coords(obj, "LARAP")
    assert np.abs(after[:n] - pose).max() < 0.03 * diag  # subdivide keeps the old vertices first
    assert targets[1].matrix_world == empty_before  # rebind never moves a target
    ids = group_ids(obj, "Right")
    gap_after = np.linalg.norm(after[ids].mean(axis=0) - np.array(targets[1].matrix_world.translation))
    assert abs(gap_after - gap_before) < 0.02 * diag  # the Empty is still with its vertices


def test_rebind_without_a_change_changes_nothing(core):
    obj, rest, left, right, targets, pose = posed_bar(core)
    mats = [tuple(h.rest_matrix) for h in obj.larap.handles]
    assert bpy.ops.larap.bind() == {"FINISHED"}
    assert [tuple(h.rest_matrix) for h in obj.larap.handles] == mats
    assert np.abs(coords(obj, "LARAP") - pose).max() < 1e-3 * diagonal(rest)


def test_rebind_with_keep_pose_off_makes_the_current_transforms_rest(core):
    obj, rest, left, right, targets, pose = posed_bar(core)
    where = targets[1].matrix_world.copy()
    assert bpy.ops.larap.bind(keep_pose=False) == {"FINISHED"}
    assert np.abs(coords(obj, "LARAP") - rest).max() < 1e-3 * diagonal(rest)
    assert targets[1].matrix_world == where


def test_back_to_rest_moves_the_targets_back_and_the_mesh_with_them(core):
    obj, rest, left, right, targets, pose = posed_bar(core)
    rest_mats = [Matrix([h.rest_matrix[i:i + 4] for i in (0, 4, 8, 12)]) for h in obj.larap.handles]
    assert bpy.ops.larap.back_to_rest() == {"FINISHED"}
    for t, m in zip(targets, rest_mats):
        assert (t.matrix_world.translation - m.translation).length < 1e-5
        assert np.allclose(np.array(t.matrix_world), np.array(m), atol=1e-5)
    assert np.abs(coords(obj, "LARAP") - rest).max() < 1e-3 * diagonal(rest)
    # One undo step: the pose comes back.
    assert "UNDO" in bpy.types.LARAP_OT_back_to_rest.bl_options


def test_adding_a_handle_with_a_user_target_to_a_posed_mesh_does_not_jump(core):
    from conftest import add_group
    obj, rest, left, right, targets, pose = posed_bar(core)
    mid = np.flatnonzero(np.abs(rest[:, 0]) < 0.1)
    add_group(obj, "Mid", mid)
    new_empty("MidTarget", (0.0, 4.0, 0.0))
    activate(obj)
    assert bpy.ops.larap.handle_add(vertex_group="Mid", target="MidTarget") == {"FINISHED"}
    bpy.ops.larap.solve()
    assert np.abs(coords(obj, "LARAP") - pose).max() < 0.01 * diagonal(rest)


def _bone_handle_bar(core):
    """The bar with its Right handle on the bone "Tip" (bound there), the bone posed, solved."""
    obj, rest, left, right, targets = bar_with_handles(core)
    arm = armature()
    activate(arm)
    bpy.ops.object.mode_set(mode="EDIT")
    other = arm.data.edit_bones.new("Other")  # a second bone, elsewhere
    other.head, other.tail = (-2.5, 1.0, 0.0), (-3.5, 1.0, 0.3)
    bpy.ops.object.mode_set(mode="OBJECT")
    h = obj.larap.handles[1]
    h.target = arm
    h.subtarget = "Tip"
    activate(obj)
    assert bpy.ops.larap.bind() == {"FINISHED"}
    arm.pose.bones["Tip"].location = (0.0, 0.4, 0.5)
    arm.pose.bones["Tip"].rotation_mode = "XYZ"
    arm.pose.bones["Tip"].rotation_euler = Euler((0.3, 0.0, 0.2))
    bpy.context.view_layer.update()
    assert bpy.ops.larap.solve() == {"FINISHED"}
    pose = coords(obj, "LARAP")
    assert np.abs(pose[right] - rest[right]).max() > 0.2  # really posed by the bone
    return obj, rest, right, arm, pose


def test_a_renamed_bone_is_followed(core):
    """Blender renames a bone in its constraints and vertex groups, not in an add-on's settings:
    the handle finds its bone again by the bone's rest in the armature, and the pose stays."""
    obj, rest, right, arm, pose = _bone_handle_bar(core)
    from larap_blender.targets import handle_problems
    arm.data.bones["Tip"].name = "Finger"
    assert "Finger" in arm.pose.bones and "Tip" not in arm.pose.bones
    assert handle_problems(obj) == []  # the panel sees no missing bone, before anything is solved
    activate(obj)
    result = core.solve(obj)
    h = obj.larap.handles[1]
    assert h.subtarget == "Finger" and h.rest_subtarget in ("", "Finger")
    assert any("'Tip' was renamed 'Finger'" in w for w in result.warnings)
    assert np.array_equal(coords(obj, "LARAP"), pose)  # the same targets: the same pose, bit for bit
    # The handle follows the renamed bone from now on, also in a drag and with Live.
    arm.data.bones["Finger"].name = "Digit"
    session = core.PoseSession(obj, 1).begin()
    assert session.bone == "Digit"
    session.cancel()
    obj.larap.live = True
    arm.data.bones["Digit"].name = "Claw"
    arm.pose.bones["Claw"].location.z += 0.3
    bpy.context.view_layer.update()
    assert h.subtarget == "Claw"
    assert np.abs(coords(obj, "LARAP")[right] - pose[right]).max() > 0.05  # posed by the moved bone


def test_a_bone_renamed_and_moved_or_ambiguous_is_not_guessed(core):
    obj, rest, right, arm, pose = _bone_handle_bar(core)
    from larap_blender.targets import bone_name, handle_problems
    h = obj.larap.handles[1]

    def edit(fn):
        activate(arm)
        bpy.ops.object.mode_set(mode="EDIT")
        fn(arm.data.edit_bones)
        bpy.ops.object.mode_set(mode="OBJECT")

    def rename_and_move(bones):
        bones["Tip"].name = "Moved"
        bones["Moved"].head.x += 0.25
    edit(rename_and_move)
    assert any("bone 'Tip' not found" in p for p in handle_problems(obj))
    edit(lambda bones: setattr(bones["Moved"].head, "x", bones["Moved"].head.x - 0.25))
    assert bone_name(h) == "Moved"  # back where it was: found again

    def twin(bones):  # a second bone where the recorded one is: neither is taken
        t = bones.new("Twin")
        t.head, t.tail, t.roll = bones["Moved"].head.copy(), bones["Moved"].tail.copy(), bones["Moved"].roll
    edit(twin)
    assert bone_name(h) == "Tip"
    assert any("bone 'Tip' not found" in p for p in handle_problems(obj))
    activate(obj)
    core.solve(obj)
    assert h.subtarget == "Tip"


def test_rebind_and_bind_after_a_bone_rename(core):
    """Bind records the handle's rest through the renamed bone (it raised KeyError on the old name)."""
    obj, rest, right, arm, pose = _bone_handle_bar(core)
    arm.data.bones["Tip"].name = "Finger"
    activate(obj)
    assert bpy.ops.larap.bind() == {"FINISHED"}  # Rebind, keeping the pose
    h = obj.larap.handles[1]
    assert h.subtarget == "Finger" and h.rest_subtarget == "Finger"
    assert np.abs(coords(obj, "LARAP") - pose).max() < 1e-3 * diagonal(rest)
    assert bpy.ops.larap.unbind() == {"FINISHED"}
    arm.data.bones["Finger"].name = "Digit"
    assert bpy.ops.larap.bind() == {"FINISHED"}
    assert h.subtarget == "Digit"


def test_flipped_names_follow_the_bone_and_another_armature_is_not_searched(core):
    obj, rest, right, arm, pose = _bone_handle_bar(core)
    from larap_blender.targets import bone_name
    h = obj.larap.handles[1]
    arm.data.bones["Tip"].name = "tmp"  # swap the two bones' names (as Flip Names does for .L/.R)
    arm.data.bones["Other"].name = "Tip"
    arm.data.bones["tmp"].name = "Other"
    assert bone_name(h) == "Other"  # the name "Tip" now belongs to the other bone
    activate(obj)
    core.solve(obj)
    assert h.subtarget == "Other" and np.array_equal(coords(obj, "LARAP"), pose)
    # Retargeted to another armature with a bone at the same rest and no bone of that name:
    # the record is the first armature's, so nothing is adopted there.
    arm2 = armature("Arm2")
    h.target = arm2
    assert h.subtarget == "Other" and bone_name(h) == "Other"


def test_picking_another_bone_of_the_armature_is_kept(core):
    """The bone record follows renames, never an artist's pick: a handle moved to another bone of
    the same armature stays on it (it is not taken back to the recorded bone), and keeps the pose."""
    obj, rest, right, arm, pose = _bone_handle_bar(core)
    h = obj.larap.handles[1]
    h.subtarget = "Other"  # as the panel's field does
    activate(obj)
    core.solve(obj)
    assert h.subtarget == "Other" and h.rest_subtarget == "Other"
    assert np.abs(coords(obj, "LARAP") - pose).max() < 1e-3 * diagonal(rest)
    arm.data.bones["Other"].name = "Renamed"  # and the record is now the new bone's
    core.solve(obj)
    assert h.subtarget == "Renamed"
