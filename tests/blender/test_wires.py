# SPDX-License-Identifier: GPL-3.0-or-later
# Run: blender -b --factory-startup --python-exit-code 1 --python tests/blender/run_tests.py -- tests/blender/test_wires.py
"""Loose edges in the add-on (a wire mesh, a Skin modifier's skeleton, edges beside faces): they
reach the engine as faces of two vertices, so a wire figure bends as one piece instead of tearing
into its vertices; they count in the topology (adding one asks for a rebind), the hash of a mesh
without them is the one recorded before they counted (files bound earlier need no rebind), and the
GPU preview, which draws faces, steps aside for them."""
import hashlib

import bpy
import bmesh
import larap
from larap import shapes
import numpy as np
import pytest
from mathutils import Matrix

from conftest import activate, add_group, bar_with_handles, coords, mesh_object


def wire_figure(core):
    """larap.shapes.stick_figure as a Blender mesh of edges only, bound, with the spine held by one
    Empty and the left hand (its arm's last two vertices) by another: (obj, rest, limbs, targets)."""
    V, F, limbs = shapes.stick_figure()
    me = bpy.data.meshes.new("Wire")
    me.from_pydata([tuple(map(float, v)) for v in V], [tuple(map(int, e)) for e in F], [])
    me.update()
    obj = bpy.data.objects.new("Wire", me)
    bpy.context.scene.collection.objects.link(obj)
    activate(obj)
    assert len(me.polygons) == 0 and len(me.edges) == len(F)
    add_group(obj, "Spine", limbs["spine"])
    add_group(obj, "Hand", limbs["left_arm"][-2:])
    assert bpy.ops.larap.handle_add(vertex_group="Spine") == {"FINISHED"}
    assert bpy.ops.larap.handle_add(vertex_group="Hand") == {"FINISHED"}
    obj.larap.iterations = 10
    assert bpy.ops.larap.bind() == {"FINISHED"}
    return obj, coords(obj), limbs, [h.target for h in obj.larap.handles]


def edge_stretch(obj, rest, X):
    e = np.empty(len(obj.data.edges) * 2, np.int64)
    obj.data.edges.foreach_get("vertices", e)
    e = e.reshape(-1, 2)
    return np.linalg.norm(X[e[:, 0]] - X[e[:, 1]], axis=1) / np.linalg.norm(rest[e[:, 0]] - rest[e[:, 1]], axis=1)


def test_a_wire_figure_bends_as_one_piece(core):
    """The hand's Empty turned 80 degrees up about the shoulder: the hand follows, every edge keeps
    its length within 10% and the arm's middle rises with it (vertices alone: each its own part,
    the middle stayed at rest and its edges stretched)."""
    obj, rest, limbs, targets = wire_figure(core)
    assert core.runtime(obj).deformer.num_components == 1
    spine = rest[limbs["spine"]]
    shoulder = spine[np.argmin(np.linalg.norm(spine - rest[limbs["left_arm"][0]], axis=1))]
    # The Empty turned about the shoulder (its world matrix times the rotation about that point).
    hand = targets[1]
    R = Matrix.Rotation(np.radians(80.0), 4, "X")
    hand.matrix_world = Matrix.Translation(shoulder) @ R @ Matrix.Translation(-shoulder) @ hand.matrix_world
    assert bpy.ops.larap.solve() == {"FINISHED"}
    X = coords(obj, "LARAP")
    stretch = edge_stretch(obj, rest, X)
    assert np.abs(stretch - 1).max() <= 0.10, (stretch.min(), stretch.max())
    arm = np.linalg.norm(rest[limbs["left_arm"][-1]] - shoulder)
    middle = limbs["left_arm"][len(limbs["left_arm"]) // 2]
    assert X[middle, 2] - rest[middle, 2] >= 0.25 * arm
    target = (np.array(R)[:3, :3] @ (rest[limbs["left_arm"][-1]] - shoulder)) + shoulder
    assert np.linalg.norm(X[limbs["left_arm"][-1]] - target) <= 0.05 * arm


def add_edges(me, pairs):
    bm = bmesh.new()
    bm.from_mesh(me)
    bm.verts.ensure_lookup_table()
    for a, b in pairs:
        bm.edges.new((bm.verts[a], bm.verts[b]))
    bm.to_mesh(me)
    bm.free()
    me.update()


def mixed_mesh():
    """A triangle (vertices 0-2), a wire 3-4-5 (edges on no face, vertices on no face) and a stray
    loose edge from the triangle's corner 1 to the wire's vertex 3."""
    obj = mesh_object("Mixed", [(0, 0, 0), (1, 0, 0), (0, 1, 0), (3, 0, 0), (5, 0, 0), (7, 0, 1)], [(0, 1, 2)])
    add_edges(obj.data, [(3, 4), (4, 5), (1, 3)])
    return obj


def test_wire_edges_reach_the_engine_after_the_polygons(core):
    """Edges whose vertices are on no face go to the engine as faces of two vertices; a stray loose
    edge that touches a face does not (it would join a faced part to whatever it reaches, and
    cell splitting would no longer tell them apart)."""
    from larap_blender import mesh_data
    obj = mixed_mesh()
    ids, offsets = mesh_data.polygons(obj.data)
    faces = [sorted(ids[offsets[k]:offsets[k + 1]].tolist()) for k in range(len(offsets) - 1)]
    assert faces[0] == [0, 1, 2] and sorted(faces[1:]) == [[3, 4], [4, 5]]
    assert mesh_data.loose_edge_count(obj.data) == 3
    d = larap.Deformer(mesh_data.rest_positions(obj), ids, face_offsets=offsets, cell_size=0.25)
    assert d.num_components == 2  # the triangle, and the wire from x = 3 to 7 in one piece


def test_wire_edges_made_by_a_script_are_read(core):
    """A wire made with foreach_set and update() (Blender 3.4 does not set MeshEdge.is_loose then):
    its edges still reach the engine, and it binds as one piece."""
    from larap_blender import mesh_data
    V, F, _ = shapes.stick_figure()
    me = bpy.data.meshes.new("ScriptWire")
    me.vertices.add(len(V))
    me.vertices.foreach_set("co", np.asarray(V, np.float32).ravel())
    me.edges.add(len(F))
    me.edges.foreach_set("vertices", np.asarray(F, np.int32).ravel())
    me.update()
    ids, offsets = mesh_data.polygons(me)
    assert len(offsets) - 1 == len(F)
    assert larap.Deformer(np.asarray(V), ids, face_offsets=offsets).num_components == 1


def old_topology_hash(me):
    """The topology hash as it was before loose edges counted (session 18)."""
    totals = np.empty(len(me.polygons), np.int32)
    me.polygons.foreach_get("loop_total", totals)
    verts = np.empty(len(me.loops), np.int32)
    me.loops.foreach_get("vertex_index", verts)
    h = hashlib.blake2b(digest_size=16)
    h.update(np.array([len(me.vertices), len(me.polygons), len(me.loops)], dtype=np.int64).tobytes())
    h.update(totals.tobytes())
    h.update(verts.tobytes())
    return h.hexdigest()


def test_a_mesh_without_wire_edges_keeps_its_topology_hash(core):
    """Suzanne, then with a stray loose edge (it does not reach the engine), then with two loose
    vertices: the hash recorded before wire edges counted. A wire edge between the two changes it."""
    from larap_blender import mesh_data
    bpy.ops.mesh.primitive_monkey_add()
    me = bpy.context.active_object.data
    assert mesh_data.topology_hash(me) == old_topology_hash(me)
    add_edges(me, [(0, 400)])  # not an edge of Suzanne's: stray
    assert mesh_data.loose_edge_count(me) == 1
    assert mesh_data.topology_hash(me) == old_topology_hash(me)
    bm = bmesh.new()
    bm.from_mesh(me)
    bm.verts.new((3.0, 0.0, 0.0))
    bm.verts.new((4.0, 0.0, 0.0))
    bm.to_mesh(me)
    bm.free()
    assert mesh_data.topology_hash(me) == old_topology_hash(me)
    n = len(me.vertices)
    add_edges(me, [(n - 2, n - 1)])
    assert mesh_data.topology_hash(me) != old_topology_hash(me)


def test_a_new_wire_edge_asks_for_a_rebind_a_stray_one_does_not(core):
    """A wire edge changes what the engine binds: the next solve asks for a Rebind. A stray loose
    edge between faced vertices changes nothing the engine sees: no Rebind, but the preview now
    steps aside for it (it would hide it)."""
    obj = mixed_mesh()
    add_group(obj, "Tri", [0, 1, 2])
    add_group(obj, "End", [5])
    assert bpy.ops.larap.handle_add(vertex_group="Tri") == {"FINISHED"}
    assert bpy.ops.larap.handle_add(vertex_group="End") == {"FINISHED"}
    assert bpy.ops.larap.bind() == {"FINISHED"}
    assert core.runtime(obj).loose_edges == 3
    add_edges(obj.data, [(3, 5)])  # a second wire edge
    with pytest.raises(RuntimeError, match="topology"):
        bpy.ops.larap.solve()
    assert bpy.ops.larap.bind() == {"FINISHED"}
    add_edges(obj.data, [(2, 4)])  # stray: vertex 2 is on the triangle
    assert bpy.ops.larap.solve() == {"FINISHED"}
    assert core.runtime(obj).loose_edges == 5


def test_the_preview_steps_aside_for_loose_edges(core, gpu_preview):
    """The preview draws faces: with a loose edge (here a stray one across the bar) it would hide
    the edge while it shows, so the mesh is written instead and the panel says why; show() refuses
    too, for a runtime validated after the blocker ran."""
    obj, rest, left, right, targets = bar_with_handles(core)
    assert gpu_preview.blocker(obj) == ""
    bm = bmesh.new()
    bm.from_mesh(obj.data)
    bm.verts.ensure_lookup_table()
    bm.edges.new((bm.verts[0], bm.verts[len(rest) - 1]))
    bm.to_mesh(obj.data)
    bm.free()
    obj.data.update()
    assert bpy.ops.larap.bind() == {"FINISHED"}
    assert "loose edges" in gpu_preview.blocker(obj)
    obj.larap.live = True
    targets[1].location.z += 0.3
    bpy.context.view_layer.update()
    assert not gpu_preview.showing(obj) and not obj.hide_get()
    assert np.abs(coords(obj, "LARAP") - rest).max() > 0.05  # written, not previewed
    rt = core.runtime(obj)
    if rt.lattice_nodes is None:
        rt.lattice_nodes = rt.deformer.lattice_deformed()
    assert gpu_preview.show(obj) is False and not obj.hide_get()
