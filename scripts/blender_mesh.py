# SPDX-License-Identifier: GPL-3.0-or-later
"""Mesh objects made from numpy arrays inside Blender (foreach_set, no per-vertex Python), for
the scripts that run in Blender: the benchmarks (bench_blender.py, bench_preview.py) and the
report's Blender parts (report/blender_peers.py, report/render_scenes.py).

Polygons come as CSR, the layout Blender stores: ``offsets`` (#P+1, the first 0) into
``indices`` (the polygons' vertex ids, one after another)."""
import bpy
import numpy as np


def mesh_object(name, V, offsets, indices, *, smooth=False):
    """A new mesh object ``name`` linked to the scene's collection: #V by 3 positions ``V`` and the
    polygons ``offsets``/``indices``; ``smooth``: smooth shading."""
    offsets = np.asarray(offsets)
    n_polygons = len(offsets) - 1
    me = bpy.data.meshes.new(name)
    me.vertices.add(len(V))
    me.vertices.foreach_set("co", np.asarray(V, np.float32).ravel())
    me.loops.add(len(indices))
    me.loops.foreach_set("vertex_index", np.asarray(indices, np.int32))
    me.polygons.add(n_polygons)
    me.polygons.foreach_set("loop_start", offsets[:-1].astype(np.int32))
    me.polygons.foreach_set("loop_total", np.diff(offsets).astype(np.int32))
    if smooth:
        me.polygons.foreach_set("use_smooth", np.ones(n_polygons, bool))
    me.update(calc_edges=True)
    obj = bpy.data.objects.new(name, me)
    bpy.context.scene.collection.objects.link(obj)
    return obj


def quad_tube(name, n_target, segments, *, length=4.0, radius=0.25, smooth=False):
    """A closed tube along X (centred on the origin) of about ``n_target`` vertices: rings of
    ``segments`` vertices joined by quads, one n-gon cap at each end. Returns (object, #V by 3
    float32 rest positions)."""
    rings = max(3, int(round(n_target / segments)))
    xs = np.linspace(-length / 2, length / 2, rings)
    ang = np.linspace(0, 2 * np.pi, segments, endpoint=False)
    co = np.empty((rings, segments, 3), np.float32)
    co[:, :, 0] = xs[:, None]
    co[:, :, 1] = radius * np.cos(ang)[None, :]
    co[:, :, 2] = radius * np.sin(ang)[None, :]
    r = np.arange(rings - 1)[:, None]
    s = np.arange(segments)[None, :]
    a = r * segments + s
    b = r * segments + (s + 1) % segments
    quads = np.stack([a, b, b + segments, a + segments], axis=-1).reshape(-1, 4)
    caps = [np.arange(segments)[::-1], (rings - 1) * segments + np.arange(segments)]
    indices = np.concatenate([quads.ravel()] + caps)
    offsets = np.concatenate([[0], np.cumsum(np.concatenate([np.full(len(quads), 4), [segments, segments]]))])
    co = co.reshape(-1, 3)
    return mesh_object(name, co, offsets, indices, smooth=smooth), co
