# SPDX-License-Identifier: GPL-3.0-or-later
# Run: blender -b --factory-startup --python-exit-code 1 --python tests/blender/run_tests.py -- tests/blender/test_bind_solve.py
import math

import bmesh
import bpy
import numpy as np
import pytest
from mathutils import Euler, Matrix, Vector

from conftest import (activate, add_group, bar_with_handles, coarse, connected_components, coords, diagonal,
                      evaluated_coords, make_bar, mesh_object, rigid_fit)


def test_bind_creates_basis_and_pose_key(core):
    obj, rest, left, right, targets = bar_with_handles(core)
    s = obj.larap
    assert s.bound and s.created_basis
    keys = obj.data.shape_keys
    assert [kb.name for kb in keys.key_blocks] == ["Basis", "LARAP"]
    assert keys.key_blocks["LARAP"].relative_key.name == "Basis"
    assert keys.key_blocks["LARAP"].value == 1.0
    assert s.bind_vertex_count == len(rest)
    # Targets at rest: the pose is the rest shape.
    assert np.abs(coords(obj, "LARAP") - rest).max() < 1e-3 * diagonal(rest)
    rt = core.runtime(obj)
    assert rt.deformer.num_vertices == len(rest) and rt.deformer.num_cells > 0
    # Handle empties sit at the group centres.
    assert (Vector(targets[1].matrix_world.translation) - Vector(rest[right].mean(axis=0))).length < 1e-5


def test_handles_follow_translated_targets(core):
    obj, rest, left, right, targets = bar_with_handles(core)
    diag = diagonal(rest)
    targets[1].location += Vector((0.0, 0.0, 1.0))
    assert bpy.ops.larap.solve() == {"FINISHED"}
    pose = coords(obj, "LARAP")
    want = rest[right] + [0.0, 0.0, 1.0]
    assert np.linalg.norm(pose[right] - want, axis=1).max() < 0.02 * diag
    assert np.linalg.norm(pose[left] - rest[left], axis=1).max() < 0.02 * diag
    middle = np.flatnonzero(np.abs(rest[:, 0]) < 0.1)
    assert 0.1 < (pose[middle, 2] - rest[middle, 2]).mean() < 0.9  # it bends
    # Basis untouched; the evaluated mesh shows the pose (key relative to Basis, value 1).
    assert np.array_equal(coords(obj, "Basis"), rest)
    assert np.abs(evaluated_coords(obj) - pose).max() < 1e-5


def test_rotation_and_scale_of_targets(core):
    obj, rest, left, right, targets = bar_with_handles(core)
    diag = diagonal(rest)
    e = targets[1]
    e.rotation_euler = Euler((0.0, math.radians(-30), 0.0))
    e.scale = (1.2, 1.2, 1.2)
    bpy.context.view_layer.update()
    bpy.ops.larap.solve()
    pose = coords(obj, "LARAP")
    c = rest[right].mean(axis=0)
    m = np.array(Matrix.Rotation(math.radians(-30), 3, "Y")) * 1.2
    want = (rest[right] - c) @ m.T + c
    assert np.linalg.norm(pose[right] - want, axis=1).max() < 0.02 * diag


def test_rigid_motion_of_all_targets_is_reproduced(core):
    obj, rest, left, right, targets = bar_with_handles(core)
    diag = diagonal(rest)
    obj.larap.iterations = 30
    motion = Matrix.Translation((0.3, -0.2, 0.5)) @ Matrix.Rotation(math.radians(25), 4, Vector((1, 1, 0.5)).normalized())
    for t in targets:
        t.matrix_world = motion @ t.matrix_world
    bpy.ops.larap.solve()
    pose = coords(obj, "LARAP")
    m = np.array(motion)
    want = rest @ m[:3, :3].T + m[:3, 3]
    err = np.linalg.norm(pose - want, axis=1).max()
    assert err < 1e-3 * diag, err


def test_object_transform_is_respected(core):
    """Targets move in world space; handles go where the target's motion carries them in local space."""
    obj = make_bar()
    obj.matrix_world = Matrix.Translation((5, 0, 0)) @ Matrix.Rotation(math.radians(90), 4, "Z") @ Matrix.Scale(2.0, 4)
    rest = coords(obj)
    right = np.flatnonzero(rest[:, 0] > 1.8)
    left = np.flatnonzero(rest[:, 0] < -1.8)
    add_group(obj, "Left", left)
    add_group(obj, "Right", right)
    bpy.ops.larap.handle_add(vertex_group="Left")
    bpy.ops.larap.handle_add(vertex_group="Right")
    coarse(obj)
    bpy.ops.larap.bind()
    t = obj.larap.handles[1].target
    t.location += Vector((0.0, 0.0, 2.0))  # world +2 z = local +1 z (scale 2)
    bpy.ops.larap.solve()
    pose = coords(obj, "LARAP")
    assert np.linalg.norm(pose[right] - (rest[right] + [0, 0, 1.0]), axis=1).max() < 0.02 * diagonal(rest)


def test_sleeve_without_handle_follows_the_arm(core):
    """An open sleeve a third of a cell off an arm, in the same object, with no handle: it has
    cells of its own (Parts Apart) and follows the arm's bend, keeping its distance to the arm."""
    length, radius, segments, gap = 4.0, 0.25, 16, 0.05
    ang = np.linspace(0, 2 * math.pi, segments, endpoint=False)
    ring = lambda x, r: [(x, r * math.cos(a), r * math.sin(a)) for a in ang]
    xs = np.linspace(-length / 2, length / 2, 41)
    sleeve_xs = xs[np.abs(xs) <= 0.7 + 1e-9]
    verts = [v for x in xs for v in ring(x, radius)] + [v for x in sleeve_xs for v in ring(x, radius + gap)]
    faces = []
    for first, rings in ((0, len(xs)), (len(xs) * segments, len(sleeve_xs))):
        for r in range(rings - 1):
            for k in range(segments):
                a, b = first + r * segments + k, first + r * segments + (k + 1) % segments
                faces.append((a, b, b + segments, a + segments))
    faces.append(tuple(reversed(range(segments))))
    faces.append(tuple((len(xs) - 1) * segments + k for k in range(segments)))
    obj = mesh_object("ArmInSleeve", verts, faces)
    rest = coords(obj)
    arm = np.arange(len(xs) * segments)
    sleeve = np.arange(len(xs) * segments, len(rest))
    add_group(obj, "Shoulder", arm[rest[arm, 0] < -1.6])
    add_group(obj, "Hand", arm[rest[arm, 0] > 1.6])
    bpy.ops.larap.handle_add(vertex_group="Shoulder")
    bpy.ops.larap.handle_add(vertex_group="Hand")
    obj.larap.resolution_mode = "SIZE"
    obj.larap.cell_size = 0.15
    obj.larap.iterations = 30
    assert bpy.ops.larap.bind() == {"FINISHED"}
    assert core.runtime(obj).deformer.num_components == 2  # the sleeve has cells of its own
    hand = obj.larap.handles[1].target
    hand.matrix_world = (Matrix.Translation((0.0, 0.0, 0.0)) @ Matrix.Rotation(math.radians(60), 4, "Z")
                         @ hand.matrix_world)  # the forearm turned 60 degrees about the elbow
    assert bpy.ops.larap.solve() == {"FINISHED"}
    pose = coords(obj, "LARAP")
    under = arm[len(xs) // 2 * segments - len(sleeve_xs) // 2 * segments:][:len(sleeve)]
    assert np.allclose(np.linalg.norm(rest[sleeve] - rest[under], axis=1), gap)
    posed = np.linalg.norm(pose[sleeve] - pose[under], axis=1)
    assert np.abs(posed - gap).max() <= 0.25 * gap, (posed.min(), posed.max())
    assert np.linalg.norm(pose[sleeve] - rest[sleeve], axis=1).mean() > 0.1  # it followed the bend


def suzanne_with_handles(core):
    bpy.ops.mesh.primitive_monkey_add()
    obj = bpy.context.object
    rest = coords(obj)
    comp = connected_components(obj)
    labels, counts = np.unique(comp, return_counts=True)
    assert len(labels) == 3, "Suzanne has a head and two eyes"
    head = comp == labels[np.argmax(counts)]
    eyes = np.flatnonzero(~head)
    z = rest[:, 2]
    h = z[head].max() - z[head].min()
    top = np.flatnonzero(head & (z > z[head].max() - 0.15 * h))
    bottom = np.flatnonzero(head & (z < z[head].min() + 0.15 * h))
    add_group(obj, "Top", top)
    add_group(obj, "Bottom", bottom)
    bpy.ops.larap.handle_add(vertex_group="Top")
    bpy.ops.larap.handle_add(vertex_group="Bottom")
    coarse(obj)
    obj.larap.iterations = 20
    assert bpy.ops.larap.bind() == {"FINISHED"}
    return obj, rest, eyes, top, bottom


def test_suzanne_eyes_follow_the_head(core):
    obj, rest, eyes, top, bottom = suzanne_with_handles(core)
    diag = diagonal(rest)
    centre = Vector(rest.mean(axis=0))
    motion = (Matrix.Translation(centre) @ Matrix.Rotation(math.radians(30), 4, "Z")
              @ Matrix.Translation(-centre))
    for h in obj.larap.handles:
        h.target.matrix_world = motion @ h.target.matrix_world
    bpy.ops.larap.solve()
    pose = coords(obj, "LARAP")
    m = np.array(motion)
    want = rest @ m[:3, :3].T + m[:3, 3]
    # The eyes (separate parts, no handle) move rigidly with the head.
    assert np.linalg.norm(pose[eyes] - want[eyes], axis=1).max() < 0.02 * diag
    r, t = rigid_fit(rest[eyes], pose[eyes])
    assert np.linalg.norm(rest[eyes] @ r.T + t - pose[eyes], axis=1).max() < 0.01 * diag


def test_suzanne_bend_keeps_eyes_rigid(core):
    obj, rest, eyes, top, bottom = suzanne_with_handles(core)
    diag = diagonal(rest)
    top_t = obj.larap.handles[0].target
    top_t.location += Vector((0.3, 0.0, 0.0))
    bpy.ops.larap.solve()
    pose = coords(obj, "LARAP")
    assert np.linalg.norm(pose[top] - (rest[top] + [0.3, 0, 0]), axis=1).max() < 0.02 * diag
    assert np.linalg.norm(pose[bottom] - rest[bottom], axis=1).max() < 0.02 * diag
    # Each eye stays (nearly) rigid.
    comp = connected_components(obj)
    for c in np.unique(comp[eyes]):
        idx = eyes[comp[eyes] == c]
        r, t = rigid_fit(rest[idx], pose[idx])
        assert np.linalg.norm(rest[idx] @ r.T + t - pose[idx], axis=1).max() < 0.01 * diag


def test_handle_from_edit_mode_selection(core):
    obj = make_bar()
    rest = coords(obj)
    bpy.ops.object.mode_set(mode="EDIT")
    bm = bmesh.from_edit_mesh(obj.data)
    want = set()
    for v in bm.verts:
        v.select_set(v.co.x > 1.8)
        if v.co.x > 1.8:
            want.add(v.index)
    bm.select_flush_mode()
    bmesh.update_edit_mesh(obj.data)
    assert bpy.ops.larap.handle_add() == {"FINISHED"}
    assert obj.mode == "EDIT"
    bpy.ops.object.mode_set(mode="OBJECT")
    h = obj.larap.handles[0]
    assert h.vertex_group == "LARAP_handle_1"
    w = core.vertex_group_weights(obj, ["LARAP_handle_1"])["LARAP_handle_1"]
    assert set(np.flatnonzero(w > 0).tolist()) == want
    assert h.target is not None and h.target.type == "EMPTY"
    centre = rest[sorted(want)].mean(axis=0)
    assert (h.target.matrix_world.translation - Vector(centre)).length < 1e-5


def test_handle_with_given_target_and_bone(core):
    obj = make_bar()
    rest = coords(obj)
    add_group(obj, "Right", np.flatnonzero(rest[:, 0] > 1.8))
    add_group(obj, "Left", np.flatnonzero(rest[:, 0] < -1.8))
    arm_data = bpy.data.armatures.new("Arm")
    arm = bpy.data.objects.new("Arm", arm_data)
    bpy.context.scene.collection.objects.link(arm)
    activate(arm)
    bpy.ops.object.mode_set(mode="EDIT")
    b = arm_data.edit_bones.new("Tip")
    b.head, b.tail = (2.0, 0, 0), (2.5, 0, 0)
    bpy.ops.object.mode_set(mode="POSE")
    bpy.ops.object.mode_set(mode="OBJECT")
    bpy.context.view_layer.update()
    activate(obj)
    assert bpy.ops.larap.handle_add(vertex_group="Right", target="Arm", bone="Tip") == {"FINISHED"}
    assert bpy.ops.larap.handle_add(vertex_group="Left") == {"FINISHED"}
    add_group(obj, "Mid", np.flatnonzero(np.abs(rest[:, 0]) < 0.1))
    with pytest.raises(RuntimeError, match="not found"):
        bpy.ops.larap.handle_add(vertex_group="Mid", target="Arm", bone="Nope")
    coarse(obj)
    bpy.ops.larap.bind()
    arm.pose.bones["Tip"].location = (0.0, 0.0, 0.5)  # bone-local: y along the bone, here world x
    bpy.context.view_layer.update()
    bpy.ops.larap.solve()
    pose = coords(obj, "LARAP")
    right = np.flatnonzero(rest[:, 0] > 1.8)
    moved = arm.matrix_world @ arm.pose.bones["Tip"].matrix
    rest_m = arm.matrix_world @ arm.data.bones["Tip"].matrix_local
    delta = np.array(moved @ rest_m.inverted())
    want = rest[right] @ delta[:3, :3].T + delta[:3, 3]
    assert np.abs(delta[:3, 3]).max() > 0.4
    assert np.linalg.norm(pose[right] - want, axis=1).max() < 0.02 * diagonal(rest)


def test_point_cloud_binds(core):
    rng = np.random.default_rng(1)
    pts = rng.uniform(-1, 1, size=(300, 3))
    pts[:, 0] *= 2
    obj = mesh_object("Cloud", pts)
    add_group(obj, "A", np.flatnonzero(pts[:, 0] > 1.6))
    add_group(obj, "B", np.flatnonzero(pts[:, 0] < -1.6))
    bpy.ops.larap.handle_add(vertex_group="A")
    bpy.ops.larap.handle_add(vertex_group="B")
    coarse(obj)
    assert bpy.ops.larap.bind() == {"FINISHED"}
    obj.larap.handles[0].target.location.z += 0.5
    assert bpy.ops.larap.solve() == {"FINISHED"}
    pose = coords(obj, "LARAP")
    a = np.flatnonzero(pts[:, 0] > 1.6)
    assert np.abs(pose[a, 2] - pts[a, 2] - 0.5).max() < 0.05 * diagonal(pts)


def test_topology_change_detected_and_rebind(core):
    obj, rest, left, right, targets = bar_with_handles(core)
    obj.data.vertices.add(1)
    obj.data.vertices[-1].co = obj.data.vertices[0].co  # add() leaves it uninitialised (NaN at times)
    obj.data.update()
    with pytest.raises(RuntimeError, match="topology") as info:
        bpy.ops.larap.solve()
    assert "Traceback" not in str(info.value)
    assert bpy.ops.larap.bind() == {"FINISHED"}
    targets[1].location.z += 0.5
    assert bpy.ops.larap.solve() == {"FINISHED"}
    assert obj.larap.bind_vertex_count == len(rest) + 1


def test_face_change_with_same_vertex_count_detected(core):
    obj, rest, left, right, targets = bar_with_handles(core)
    # Flip one face's winding via bmesh: same counts, different topology hash.
    bm = bmesh.new()
    bm.from_mesh(obj.data)
    bm.faces.ensure_lookup_table()
    bmesh.ops.reverse_faces(bm, faces=[bm.faces[0]])
    bm.to_mesh(obj.data)
    bm.free()
    with pytest.raises(RuntimeError, match="topology"):
        bpy.ops.larap.solve()


def test_solve_from_edit_mode_switches_out(core):
    obj, rest, left, right, targets = bar_with_handles(core)
    targets[1].location.z += 0.5
    bpy.ops.object.mode_set(mode="EDIT")
    assert bpy.ops.larap.solve() == {"FINISHED"}
    assert obj.mode == "OBJECT"
    assert np.abs(coords(obj, "LARAP")[right, 2] - rest[right, 2] - 0.5).max() < 0.02 * diagonal(rest)


def test_engine_error_is_reported(core):
    obj = make_bar()
    obj.larap.resolution_mode = "SIZE"
    obj.larap.cell_size = 1e-5  # an absurd lattice: the engine refuses (MemoryError/ValueError)
    with pytest.raises(RuntimeError, match="Bind failed") as info:
        bpy.ops.larap.bind()
    assert "Traceback" not in str(info.value)
    assert not obj.larap.bound


def test_apply_writes_the_pose_into_the_mesh(core):
    obj, rest, left, right, targets = bar_with_handles(core)
    targets[1].location.z += 1.0
    bpy.ops.larap.solve()
    pose = coords(obj, "LARAP")
    assert bpy.ops.larap.apply() == {"FINISHED"}
    assert obj.data.shape_keys is None  # bind created Basis; nothing else was there
    assert not obj.larap.bound
    got = coords(obj)
    assert np.abs(got - pose).max() < 1e-3 * diagonal(rest)
    assert np.abs(got[right, 2] - rest[right, 2] - 1.0).max() < 0.02 * diagonal(rest)
    assert len(obj.vertex_groups) == 2 and len(obj.larap.handles) == 2


def test_apply_keeps_existing_shape_keys(core):
    obj = make_bar()
    rest = coords(obj)
    obj.shape_key_add(name="Basis")
    fat = obj.shape_key_add(name="Fat")
    fat_co = (rest * [1.0, 1.5, 1.5]).astype(np.float32)
    fat.data.foreach_set("co", fat_co.ravel())
    add_group(obj, "Left", np.flatnonzero(rest[:, 0] < -1.8))
    add_group(obj, "Right", np.flatnonzero(rest[:, 0] > 1.8))
    bpy.ops.larap.handle_add(vertex_group="Left")
    bpy.ops.larap.handle_add(vertex_group="Right")
    coarse(obj)
    bpy.ops.larap.bind()
    assert not obj.larap.created_basis
    assert np.array_equal(coords(obj, "Fat"), fat_co.astype(np.float64))  # untouched by bind
    obj.larap.handles[1].target.location.z += 1.0
    bpy.ops.larap.solve()
    pose = coords(obj, "LARAP")
    bpy.ops.larap.apply()
    names = [kb.name for kb in obj.data.shape_keys.key_blocks]
    assert names == ["Basis", "Fat"]
    assert np.abs(coords(obj, "Basis") - pose).max() < 1e-5
    # Fat keeps its offset from Basis.
    assert np.abs((coords(obj, "Fat") - coords(obj, "Basis")) - (fat_co - rest)).max() < 1e-4


def test_unbind_removes_pose_key(core):
    obj, rest, left, right, targets = bar_with_handles(core)
    assert bpy.ops.larap.unbind() == {"FINISHED"}
    assert obj.data.shape_keys is None
    assert not obj.larap.bound and core.runtime(obj) is None
    assert len(obj.larap.handles) == 2


def test_settings_changes_rebuild_lazily(core):
    obj, rest, left, right, targets = bar_with_handles(core)
    before = core.runtime(obj).deformer
    obj.larap.resolution_mode = "CELLS"
    obj.larap.cells = 500
    targets[1].location.z += 0.3
    bpy.ops.larap.solve()
    after = core.runtime(obj).deformer
    assert after is not before
    obj.larap.gamma = 0.5  # no rebuild for gamma
    bpy.ops.larap.solve()
    assert core.runtime(obj).deformer is after and abs(after.gamma - 0.5) < 1e-6


def test_polygons_reach_the_engine_as_blenders_own_csr(core):
    """Quads and n-gons go to the engine as Blender's loop array (no triangulation in Python),
    in polygon order, and the engine binds them like the same polygons given as a list."""
    import larap
    from larap_blender import mesh_data
    bpy.ops.mesh.primitive_cylinder_add(vertices=12, radius=0.5, depth=2.0)  # quads + two 12-gons
    obj = bpy.context.active_object
    me = obj.data
    ids, offsets = mesh_data.polygons(me)
    expected = [list(p.vertices) for p in me.polygons]
    assert offsets[0] == 0 and offsets[-1] == len(ids) and len(offsets) == len(expected) + 1
    assert [list(ids[offsets[k]:offsets[k + 1]]) for k in range(len(expected))] == expected
    rest = mesh_data.rest_positions(obj)
    a = larap.Deformer(rest, ids, face_offsets=offsets, cells=300)
    b = larap.Deformer(rest, expected, cells=300)
    np.testing.assert_array_equal(a.lattice_rest(), b.lattice_rest())


def test_keep_parts_apart_reaches_the_engine(core, monkeypatch):
    """The "Parts Apart" setting (cell splitting, on by default) is what the engine is built
    with, and changing it rebuilds the engine at the next solve."""
    import larap
    seen = []
    real = larap.Deformer.__init__

    def init(self, *a, **k):
        seen.append(k.get("split_cells"))
        real(self, *a, **k)

    monkeypatch.setattr(larap.Deformer, "__init__", init)
    obj, rest, left, right, targets = bar_with_handles(core)
    assert obj.larap.split_cells and seen[-1] is True
    obj.larap.split_cells = False
    core.solve(obj, weights="final")
    assert seen[-1] is False
