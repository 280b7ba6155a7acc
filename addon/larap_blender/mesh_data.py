# SPDX-License-Identifier: GPL-3.0-or-later
"""Mesh data in and out of Blender: the ONLY place that writes vertex positions and shape keys.

Everything goes through numpy with ``foreach_get``/``foreach_set`` on float32 buffers (ids are
read as uint32: :func:`_get_ids`); nothing loops over vertices in Python. Positions are
object-local, (n, 3) float32.

Reads: rest positions (the Basis key, or the mesh when it has no keys), any key's positions, the
polygon topology (its hash, and a fan triangulation for the engine), vertex-group weights and the
selection. Writes: the pose key (``Object.larap.shape_key``, relative to Basis, created and owned
by LARAP), other keys LARAP adds (bake; a copy of hand edits of the pose key, key_edits.py), the
mesh vertices (apply, undoing a created Basis) and the restores of a snapshot (transaction.py).
With shape keys present, writing ``vertices.co`` has no visible effect: write the key.
"""
import hashlib

import numpy as np

from .errors import LarapError


def _get(collection, attr, count, dtype, width=1):
    """``attr`` of the ``count`` items of ``collection`` with one ``foreach_get``: (count,) or
    (count, width) of ``dtype``."""
    buf = np.empty(count * width, dtype=dtype)
    collection.foreach_get(attr, buf)
    return buf if width == 1 else buf.reshape(count, width)


def _get_ids(collection, attr, count, width=1):
    """Like :func:`_get` for an index or count attribute (vertex, edge and loop ids, loop totals),
    returned as int32. Blender declares these unsigned, and ``foreach_get`` copies in one block
    only into a buffer of the attribute's own type; into an int32 buffer it goes item by item
    (the 4M loops' ``vertex_index`` of a 1M-vertex mesh: 115 ms, against 7 ms into uint32, Blender
    3.4.1). So they are read as uint32 and viewed as int32: the same bits, every id and count
    being below 2**31."""
    return _get(collection, attr, count, np.uint32, width).view(np.int32)


def read_only(a):
    """``a``, marked read only (an array several holders share: the runtime's rest shape, a
    snapshot's positions): a numpy write to it raises instead of changing what the others see.
    Blender's ``foreach_get`` ignores the flag: never read into such an array (``_get`` always
    reads into a new one)."""
    a.flags.writeable = False
    return a


# ----------------------------------------------------------------------------------------------
# Positions (read)

def mesh_positions(me):
    """(n,3) float32 positions of the mesh vertices (not what the keys show)."""
    return _get(me.vertices, "co", len(me.vertices), np.float32, 3)


def block_positions(kb, n):
    """(n,3) float32 positions stored in the shape key ``kb`` of an n-vertex mesh."""
    return _get(kb.data, "co", n, np.float32, 3)


def rest_positions(obj):
    """(n,3) float32 rest positions: the Basis key, or the mesh vertices when there are no keys."""
    me = obj.data
    keys = me.shape_keys
    if keys is not None and keys.reference_key is not None:
        return block_positions(keys.reference_key, len(me.vertices))
    return mesh_positions(me)


def key_positions(obj, name):
    """(n,3) float32 positions of the key ``name``, or None when there is no such key."""
    me = obj.data
    kb = me.shape_keys.key_blocks.get(name) if me.shape_keys else None
    if kb is None:
        return None
    return block_positions(kb, len(me.vertices))


def array_hash(a):
    return hashlib.blake2b(np.ascontiguousarray(a).tobytes(), digest_size=16).hexdigest()


# ----------------------------------------------------------------------------------------------
# Topology (read)

def topology_arrays(me):
    """(loop_start, loop_total, loop vertex ids, wire edges): Blender's polygons as int32 arrays,
    and the (k, 2) int32 vertex ids of its wire edges (:func:`wire_edges`)."""
    totals = _get_ids(me.polygons, "loop_total", len(me.polygons))
    starts = _get_ids(me.polygons, "loop_start", len(me.polygons))
    verts = _get_ids(me.loops, "vertex_index", len(me.loops))
    return starts, totals, verts, wire_edges(me, verts)


def loop_triangles(me):
    """(t, 3) int32 vertex ids of the mesh's loop triangles (``Mesh.calc_loop_triangles`` first)."""
    me.calc_loop_triangles()
    return _get_ids(me.loop_triangles, "vertices", len(me.loop_triangles), 3)


def wire_edges(me, loop_verts=None):
    """(k, 2) int32 vertex ids of the edges that are wire: on no face, and neither of their
    vertices on a face (a wire mesh, a Skin modifier's skeleton, a wire part beside faces). A
    stray loose edge between faced parts is left out, so it never joins them (it would glue two
    fingers' lattices). Found from the loops, not from ``MeshEdge.is_loose``: Blender 3.4 keeps
    that flag stored, and ``Mesh.update()`` does not recompute it (edges added with
    ``foreach_set`` read not loose)."""
    n = len(me.edges)
    if n == 0:
        return np.zeros((0, 2), np.int32)
    edges = _get_ids(me.edges, "vertices", n, 2)
    if len(me.loops):
        if loop_verts is None:
            loop_verts = _get_ids(me.loops, "vertex_index", len(me.loops))
        on_face = np.zeros(len(me.vertices), bool)
        on_face[loop_verts] = True
        wire = ~(on_face[edges[:, 0]] | on_face[edges[:, 1]])  # an edge of a face has its vertices on it
        edges = edges[wire]
    return np.ascontiguousarray(edges)


def loose_edge_count(me):
    """How many edges are on no face (wire edges and stray ones): the GPU preview, which draws
    faces, would hide them. One read of the loops' edges (7-30 ms at 4M loops, Blender 3.4.1)."""
    n = len(me.edges)
    if n == 0 or len(me.loops) == 0:
        return n
    used = np.zeros(n, bool)
    used[_get_ids(me.loops, "edge_index", len(me.loops))] = True
    return int(n - np.count_nonzero(used))


def topology_hash(me, arrays=None):
    """The polygons' hash, and the wire edges' when there are any (so the hash of a mesh without
    them is the one recorded before wire edges counted: files bound then need no rebind)."""
    starts, totals, verts, loose = arrays or topology_arrays(me)
    h = hashlib.blake2b(digest_size=16)
    h.update(np.array([len(me.vertices), len(me.polygons), len(me.loops)], dtype=np.int64).tobytes())
    h.update(totals.tobytes())
    h.update(verts.tobytes())
    if len(loose):
        h.update(b"wire edges")
        h.update(np.ascontiguousarray(loose).tobytes())
    return h.hexdigest()


def polygons(me, arrays=None):
    """Blender's polygons as the engine takes them: (vertex ids (L,), offsets (P+1,)), polygon p
    being ids[offsets[p]:offsets[p+1]]. Blender stores each polygon's loops contiguously and in
    polygon order, so this is its own loop array, handed over without triangulating. Wire edges
    follow as faces of two vertices (the engine keeps the cells they pass through)."""
    starts, totals, verts, loose = arrays or topology_arrays(me)
    offsets = np.zeros(len(totals) + 1, dtype=np.int64)
    np.cumsum(totals, out=offsets[1:])
    if len(starts) and not np.array_equal(starts, offsets[:-1]):  # not in order: gather it
        idx = np.repeat(starts.astype(np.int64) - offsets[:-1], totals) + np.arange(offsets[-1])
        verts = verts[idx]
    if len(loose):
        verts = np.concatenate([verts, loose.reshape(-1)])
        offsets = np.concatenate([offsets, offsets[-1] + 2 * np.arange(1, len(loose) + 1, dtype=np.int64)])
    return verts, offsets


# ----------------------------------------------------------------------------------------------
# Vertex groups and selection (read)

def vertex_group_weights(obj, names, rest=None):
    """{name: (n,) float32 weights} for vertex groups, without a Python loop over vertices.

    Blender exposes vertex-group membership only per vertex, so this lets Blender's shape-key
    mixer do it in C: temporary keys = Basis + (1,0,0), Basis + (0,1,0) and Basis + (0,0,1), each
    masked by a group, mixed alone with ``shape_key_add(from_mix=True)``, give Basis + the three
    groups' weights on x, y and z: one mix and one read for three groups, the temporary keys
    written once and masked by the next three groups in turn (at 1M vertices a key's write or read
    costs about 45 ms, a mix 13 ms). The temporary keys are removed and the mesh's shape-key state
    is restored.

    ``rest``: the object's :func:`rest_positions` when the caller has just read them (nothing
    changed since), which are the Basis positions this needs (a mesh without keys gets a
    temporary Basis copied from its vertices): the Basis is then not read again.
    """
    me = obj.data
    n = len(me.vertices)
    out = {}
    names = [nm for nm in dict.fromkeys(names) if nm in obj.vertex_groups]
    if not names or n == 0:
        return out
    had_keys = me.shape_keys is not None
    active_index = obj.active_shape_key_index
    show_only = obj.show_only_shape_key
    if not had_keys:
        obj.shape_key_add(name="Basis", from_mix=False)
    key = me.shape_keys
    basis = key.reference_key
    use_relative = key.use_relative
    saved_mutes = [(kb.name, kb.mute) for kb in key.key_blocks]
    base = rest if rest is not None else block_positions(basis, n)
    try:
        key.use_relative = True
        obj.show_only_shape_key = False
        for kb in key.key_blocks:
            if kb != basis:
                kb.mute = True
        basis_mute = basis.mute
        basis.mute = False
        tmps = []
        try:
            for axis in range(min(3, len(names))):
                tmp = obj.shape_key_add(name="_larap_tmp", from_mix=False)
                tmps.append(tmp)
                raised = base.copy()
                raised[:, axis] += np.float32(1.0)
                write_block(tmp, raised)
                tmp.relative_key = basis
                tmp.slider_min, tmp.slider_max = 0.0, 1.0
                tmp.value = 1.0
            for first in range(0, len(names), 3):
                batch = names[first:first + 3]
                for axis, tmp in enumerate(tmps):  # a key without a group of this batch stays out
                    tmp.vertex_group = batch[axis] if axis < len(batch) else ""
                    tmp.mute = axis >= len(batch)
                mix = obj.shape_key_add(name="_larap_mix", from_mix=True)
                try:
                    mixed = block_positions(mix, n)
                finally:
                    obj.shape_key_remove(mix)
                for axis, name in enumerate(batch):
                    w = (mixed[:, axis] - base[:, axis]).astype(np.float32)
                    if _mask_ignored(obj, name, w):
                        w = np.zeros(n, np.float32)
                    out[name] = w
        finally:
            for tmp in reversed(tmps):
                obj.shape_key_remove(tmp)
        basis.mute = basis_mute
    finally:
        if not had_keys:
            obj.shape_key_clear()
        else:
            key.use_relative = use_relative
            for name, mute in saved_mutes:
                kb = key.key_blocks.get(name)
                if kb is not None:
                    kb.mute = mute
            obj.active_shape_key_index = active_index
        obj.show_only_shape_key = show_only
    return out


def _mask_ignored(obj, name, w):
    """Whether the mixer ignored the vertex-group mask: a mesh on which no vertex was ever
    assigned to a group has no weight layer, and Blender then mixes the key at full weight
    everywhere (a group the artist created and forgot to Assign read as every vertex). Checked
    on vertex 0 when the group reads as every vertex at weight 1 (to float32 rounding)."""
    if len(w) == 0 or not bool(np.all(np.abs(w - 1.0) < 1e-4)):  # (mixed in float32)
        return False
    index = obj.vertex_groups[name].index
    return not any(g.group == index and g.weight > 1.0 - 1e-4 for g in obj.data.vertices[0].groups)


def selected_vertices(obj):
    me = obj.data
    if obj.mode == "EDIT":
        obj.update_from_editmode()
    sel = _get(me.vertices, "select", len(me.vertices), bool)
    return np.flatnonzero(sel)


# ----------------------------------------------------------------------------------------------
# Positions (write): every write of vertex or key positions in the add-on is one of these

def write_block(kb, co):
    """Write (n,3) positions into the shape key ``kb`` with one foreach_set (no copy when ``co``
    is already C-contiguous float32)."""
    buf = co if (co.dtype == np.float32 and co.flags.c_contiguous) else np.ascontiguousarray(co, dtype=np.float32)
    kb.data.foreach_set("co", buf.reshape(-1))


def set_mesh_positions(me, co):
    """Write (n,3) positions into the mesh vertices (only visible when the mesh has no keys)."""
    buf = np.ascontiguousarray(co, dtype=np.float32)
    me.vertices.foreach_set("co", buf.reshape(-1))


def write_key(obj, name, co):
    """Write (n,3) positions into the key ``name`` (added when missing), relative to Basis.
    The caller has checked that ``name`` is not the Basis or pose key."""
    keys = obj.data.shape_keys
    kb = keys.key_blocks.get(name)
    if kb is None:
        kb = obj.shape_key_add(name=name, from_mix=False)
    write_block(kb, co)
    kb.relative_key = keys.reference_key
    obj.data.update_tag()
    return kb


def add_key_copy(obj, name, co):
    """A new key holding (n,3) positions ``co``, relative to Basis, at value 0, named ``name`` (or
    ``name.001`` ... when taken: never an existing key)."""
    keys = obj.data.shape_keys
    kb = obj.shape_key_add(name=name, from_mix=False)
    write_block(kb, co)
    kb.relative_key = keys.reference_key
    kb.value = 0.0
    obj.data.update_tag()
    return kb


def remove_keys(obj, names):
    """Remove the shape keys ``names`` that exist (keys LARAP added in an operation it undoes)."""
    keys = obj.data.shape_keys
    for name in names:
        kb = keys.key_blocks.get(name) if keys is not None else None
        if kb is not None and kb != keys.reference_key:
            obj.shape_key_remove(kb)
            keys = obj.data.shape_keys


def apply_offsets(obj, pose, rest, skip, known=None):
    """Move the mesh to ``pose`` and every key but ``skip`` by ``pose - rest`` (keys keep their
    offsets to one another). ``rest``: the rest positions as they are now (:func:`rest_positions`),
    which are the Basis's: the Basis becomes ``rest + (pose - rest)`` without being read.
    ``known``: {key name: (n,3) float32 positions} of other keys the caller has read, nothing
    written to them since (not read again). Returns what the Basis holds now (float32, as written:
    what reading it back gives), or None when the mesh has no keys."""
    me = obj.data
    delta = pose - rest
    keys = me.shape_keys
    moved = None
    if keys is not None:
        n = len(me.vertices)
        basis = keys.reference_key
        known = known or {}
        for kb in keys.key_blocks:
            if kb.name == skip:
                continue
            if kb == basis:
                moved = np.ascontiguousarray(rest + delta, dtype=np.float32)
                write_block(kb, moved)
            else:
                co = known.get(kb.name)
                write_block(kb, (block_positions(kb, n) if co is None else co) + delta)
    set_mesh_positions(me, pose)
    return moved


# ----------------------------------------------------------------------------------------------
# The pose key (LARAP creates it, owns it, and never writes a key it did not create)

def ensure_pose_key(obj, settings=None):
    """Basis (created from the mesh if there are no keys) and the pose key, relative to Basis."""
    s = settings or obj.larap
    me = obj.data
    if not s.shape_key:
        raise LarapError("The pose shape key has no name (LARAP > Settings > Shape Key)")
    keys = me.shape_keys
    kb = keys.key_blocks.get(s.shape_key) if keys is not None else None
    if kb is not None:
        if kb == keys.reference_key:
            raise LarapError("The pose shape key %r is the Basis key; choose another name" % s.shape_key)
        if kb.name != s.owned_key_name:
            if s.bound and not s.owned_key_name:
                s.owned_key_name = kb.name  # bound by an add-on version that did not record ownership
            else:
                raise LarapError("%r already has a shape key %r that LARAP did not create; LARAP does not "
                                 "overwrite it: rename that key or set another pose key name "
                                 "(LARAP > Settings > Shape Key)" % (obj.name, s.shape_key))
        return kb, False
    created_basis = False
    if me.shape_keys is None:
        obj.shape_key_add(name="Basis", from_mix=False)
        created_basis = True
    keys = me.shape_keys
    kb = obj.shape_key_add(name=s.shape_key, from_mix=False)
    kb.relative_key = keys.reference_key
    kb.value = 1.0
    s.owned_key_name = kb.name
    return kb, created_basis


def write_pose(obj, co, settings=None):
    """Write (n,3) positions into the pose key with one foreach_set and tag the mesh."""
    kb, _ = ensure_pose_key(obj, settings)
    write_block(kb, co)
    obj.data.update_tag()
    return kb


def restore_pose_key(obj, co):
    """Put the pose key back as it was: its positions ``co``, or no pose key when ``co`` is None."""
    s = obj.larap
    keys = obj.data.shape_keys
    kb = keys.key_blocks.get(s.shape_key) if keys else None
    if co is not None:
        if kb is None:
            kb, _ = ensure_pose_key(obj, s)
        write_block(kb, co)
    elif kb is not None:
        obj.shape_key_remove(kb)
    obj.data.update_tag()


def remove_pose_key(obj, basis=None):
    """Remove only what LARAP made: its pose key, and the Basis when bind created it and no other
    key is left (the mesh keeps the Basis positions). ``basis``: the Basis's positions when the
    caller has just read or written them, nothing written to it since (not read again)."""
    s = obj.larap
    keys = obj.data.shape_keys
    if keys is None:
        s.owned_key_name = ""
        s.created_basis = False
        return
    owned = s.owned_key_name or (s.shape_key if s.bound else "")
    kb = keys.key_blocks.get(owned) if owned else None
    if kb is not None and kb != keys.reference_key:
        obj.shape_key_remove(kb)
    keys = obj.data.shape_keys
    if s.created_basis and keys is not None and len(keys.key_blocks) == 1:
        me = obj.data
        co = block_positions(keys.reference_key, len(me.vertices)) if basis is None else basis
        obj.shape_key_clear()
        set_mesh_positions(me, co)
    s.owned_key_name = ""
    s.created_basis = False
