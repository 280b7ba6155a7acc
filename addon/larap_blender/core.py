# SPDX-License-Identifier: GPL-3.0-or-later
"""The add-on's real work, as plain functions (no operators, no UI): tests call these directly.

Conventions
-----------
* Positions are object-local and go in and out of Blender as float32 numpy buffers through
  ``foreach_get``/``foreach_set``; nothing loops over vertices in Python.
* Rest positions come from the reference (Basis) shape key, or from the mesh when it has no keys.
* The pose goes to the shape key ``Object.larap.shape_key`` ("LARAP"), relative to Basis.
* User-facing failures raise :class:`LarapError` (operators turn it into a report).
* The engine object (``larap.Deformer``) is runtime-only and lives in ``_RUNTIMES``; it is rebuilt
  lazily from the stored settings (after reloading a .blend, an undo, a settings change, or an edit
  of the rest positions).
"""
import contextlib
import hashlib
import time
import uuid

import bpy
import numpy as np
from mathutils import Matrix, Vector

from .errors import ENGINE_ERRORS, LarapError, TopologyChanged, check_object, engine_errors, require_engine
from .mesh_data import (apply_offsets, array_hash, block_positions, ensure_pose_key, key_positions, mesh_positions,
                        remove_pose_key, rest_positions, restore_pose_key, selected_vertices, set_mesh_positions,
                        topology_arrays, topology_hash, triangles, vertex_group_weights, write_block, write_key,
                        write_pose)
from .targets import (flat, gather, handle_local_transform, membership, record_rest, target_alive, target_matrix,
                      target_names, target_signature)

HANDLE_GROUP_PREFIX = "LARAP_handle_"
TARGET_PREFIX = "LARAP_target_"


# ----------------------------------------------------------------------------------------------
# All or nothing: an operation that fails part-way leaves the object as it was

_SETTING_FIELDS = ("bound", "bind_vertex_count", "bind_topology", "created_basis", "owned_key_name",
                   "shape_key", "runtime_id")
_KEY_FIELDS = ("slider_max", "slider_min", "value", "mute", "vertex_group", "interpolation")
_POINT_FIELDS = ("co", "interpolation", "handle_left_type", "handle_right_type", "handle_left", "handle_right")


def _snapshot(obj):
    me = obj.data
    s = obj.larap
    snap = {"mesh": mesh_positions(me),
            "settings": {f: getattr(s, f) for f in _SETTING_FIELDS},
            "handles": [(tuple(h.rest_matrix), h.has_rest) for h in s.handles],
            "active_shape_key_index": obj.active_shape_key_index,
            "show_only_shape_key": obj.show_only_shape_key,
            "keys": None, "anim": None}
    key0 = s.runtime_id
    snap["runtime"] = (key0, _RUNTIMES.get(key0) if key0 else None)
    keys = me.shape_keys
    if keys is not None:
        n = len(me.vertices)
        snap["use_relative"] = keys.use_relative
        snap["keys"] = [(kb.name, block_positions(kb, n),
                         kb.relative_key.name if kb.relative_key else "",
                         {f: getattr(kb, f) for f in _KEY_FIELDS}) for kb in keys.key_blocks]
        ad = keys.animation_data
        if ad is not None and ad.action is not None:
            snap["anim"] = (ad.action, {(fc.data_path, fc.array_index): [
                {f: (tuple(getattr(kp, f)) if f in ("co", "handle_left", "handle_right") else getattr(kp, f))
                 for f in _POINT_FIELDS} for kp in fc.keyframe_points] for fc in ad.action.fcurves})
    return snap


def _restore(obj, snap):
    me = obj.data
    s = obj.larap
    keys = me.shape_keys
    if snap["keys"] is None:
        if keys is not None:
            obj.shape_key_clear()
    else:
        names = [entry[0] for entry in snap["keys"]]
        if keys is not None:
            for kb in list(keys.key_blocks)[::-1]:
                if kb.name not in names:
                    obj.shape_key_remove(kb)
        for name, co, _rel, _props in snap["keys"]:
            keys = me.shape_keys
            if keys is None or name not in keys.key_blocks:
                obj.shape_key_add(name=name, from_mix=False)
        keys = me.shape_keys
        keys.use_relative = snap["use_relative"]
        for name, co, rel, props in snap["keys"]:
            kb = keys.key_blocks[name]
            write_block(kb, co)
            kb.slider_min = -10.0
            for f in _KEY_FIELDS:
                setattr(kb, f, props[f])
            if rel in keys.key_blocks:
                kb.relative_key = keys.key_blocks[rel]
        ad = keys.animation_data
        if snap["anim"] is None:
            if ad is not None:
                ad.action = None
        else:
            action, curves = snap["anim"]
            if ad is None:
                ad = keys.animation_data_create()
            ad.action = action
            for fc in list(action.fcurves):
                if (fc.data_path, fc.array_index) not in curves:
                    action.fcurves.remove(fc)
            for (path, index), points in curves.items():
                fc = action.fcurves.find(path, index=index) or action.fcurves.new(path, index=index)
                fc.keyframe_points.clear()
                fc.keyframe_points.add(len(points))
                for kp, p in zip(fc.keyframe_points, points):
                    for f in _POINT_FIELDS:
                        setattr(kp, f, p[f])
                fc.update()
    set_mesh_positions(me, snap["mesh"])
    obj.show_only_shape_key = snap["show_only_shape_key"]
    obj.active_shape_key_index = snap["active_shape_key_index"]
    for f, v in snap["settings"].items():
        setattr(s, f, v)
    for h, (m, has) in zip(s.handles, snap["handles"]):
        h.rest_matrix = m
        h.has_rest = has
    key0, rt0 = snap["runtime"]
    for k in [k for k, rt in _RUNTIMES.items() if k == key0 or rt.pointer == obj.as_pointer()]:
        _RUNTIMES.pop(k, None)
    if rt0 is not None:
        rt0.target_sig = None  # what the engine solved last was not kept
        rt0.weights = ""
        rt0.lattice_current = False
        rt0.pose_version += 1
        _RUNTIMES[key0] = rt0
    me.update()


@contextlib.contextmanager
def preserve_on_error(obj):
    """Snapshot the mesh positions, every shape key (data, settings, key animation), the LARAP
    settings and the runtime; restore them if the block raises (then re-raise)."""
    snap = _snapshot(obj)
    try:
        yield snap
    except BaseException:
        try:
            _restore(obj, snap)
        except Exception:  # never mask the original error
            import traceback
            traceback.print_exc()
        raise


# ----------------------------------------------------------------------------------------------
# Runtime cache (engine objects are never stored in the .blend)

class Runtime:
    def __init__(self):
        self.deformer = None
        self.pointer = 0
        self.settings_sig = None
        self.counts = None  # (verts, polys, loops)
        self.topology = ""
        self.rest = None
        self.rest_hash = ""
        self.out = None
        self.membership = {}  # vertex group -> sorted int64 indices (weight > 0)
        self.membership_sig = None
        self.last_ms = 0.0
        self.stats = {}
        self.weights = ""
        self.target_sig = None
        self.pose_version = 0
        self.last_error = ""
        self.warnings = []
        self.validated = False  # False: the next ensure_runtime does a full validation
        self.lattice_current = False  # the engine's lattice is the pose in the pose key (overlay)


# Keyed by Object.larap.runtime_id (a uuid stored in the object, so renames keep the engine) and
# validated against the object pointer (duplicates, which copy the id, get a new one).
_RUNTIMES = {}
_SUSPEND = [0]


def _runtime_key(obj):
    try:
        return obj.larap.runtime_id
    except (ReferenceError, AttributeError):
        return ""


def runtime(obj):
    """The cached runtime of an object, or None (does not build, writes nothing: safe in draw code)."""
    try:
        key = obj.larap.runtime_id
        pointer = obj.as_pointer()
    except (ReferenceError, AttributeError):
        return None
    rt = _RUNTIMES.get(key) if key else None
    if rt is not None and rt.pointer not in (0, pointer):
        return None  # another object's (a duplicate that copied the id)
    return rt


def _claim_key(obj):
    """The object's runtime id, assigning a new one to an object without one and to a duplicate
    (a copy shares the id of its original while the original's runtime is alive)."""
    s = obj.larap
    key = s.runtime_id
    if key:
        rt = _RUNTIMES.get(key)
        pointer = obj.as_pointer()
        if rt is None or rt.pointer in (0, pointer):
            return key
        if not any(o.as_pointer() == rt.pointer and o.larap.runtime_id == key
                   for o in bpy.data.objects if o.type == "MESH"):
            rt.pointer = pointer  # the same object at a new address (undo re-created it): adopt
            rt.validated = False
            return key
    s.runtime_id = uuid.uuid4().hex
    return s.runtime_id


def drop_runtime(obj_or_key=None):
    if obj_or_key is None:
        _RUNTIMES.clear()
        return
    key = obj_or_key if isinstance(obj_or_key, str) else _runtime_key(obj_or_key)
    rt = _RUNTIMES.get(key)
    if rt is not None and not isinstance(obj_or_key, str) and rt.pointer not in (0, obj_or_key.as_pointer()):
        return  # a duplicate's: not this object's
    _RUNTIMES.pop(key, None)


def _bound_meshes():
    for obj in bpy.data.objects:
        try:
            if obj.type == "MESH" and obj.larap.bound and obj.larap.runtime_id:
                yield obj
        except ReferenceError:
            continue


def prune_runtimes():
    """Forget runtimes whose object is gone or unbound (cheap; called from handlers)."""
    alive = {obj.larap.runtime_id for obj in _bound_meshes()}
    for key in list(_RUNTIMES):
        if key not in alive:
            _RUNTIMES.pop(key, None)


def after_undo():
    """undo_post/redo_post: the mesh, its keys, the settings and the targets are what the undo step
    stored; the engines must not carry on from the undone state. Each runtime is re-validated in
    full at its next use (rest shape, topology, vertex groups), its warm start is forgotten, its
    lattice is no longer drawn as current, the weights of the restored pose key are unknown (so
    Bake/Apply re-solve), and the restored target matrices are recorded as the ones the restored
    pose key was solved for (so Live does not overwrite what the undo restored)."""
    prune_runtimes()
    for obj in _bound_meshes():
        rt = _RUNTIMES.get(obj.larap.runtime_id)
        if rt is None:
            continue
        rt.pointer = obj.as_pointer()
        rt.validated = False
        rt.membership_sig = None
        rt.lattice_current = False
        rt.weights = ""
        rt.pose_version += 1
        if rt.deformer is not None:
            try:
                rt.deformer.reset()
            except Exception:
                rt.deformer = None
        try:
            rt.target_sig = target_signature(obj)
        except Exception:
            rt.target_sig = None


def resolve_device(settings):
    dev = settings.device
    if dev == "DEFAULT":
        from .props import preferences
        prefs = preferences()
        dev = prefs.default_device if prefs is not None else "cpu"
    return dev


def _settings_sig(s):
    """Settings that need a new lattice (gamma and weights are switched on the live engine)."""
    if s.resolution_mode == "CELLS":
        res = ("cells", int(s.cells))
    elif s.resolution_mode == "SIZE":
        res = ("size", float(s.cell_size))
    else:
        res = ("auto",)
    return res + (resolve_device(s),)


def _build_deformer(obj, rest, tris):
    mod = require_engine()
    s = obj.larap
    kwargs = dict(gamma=float(s.gamma), device=resolve_device(s), weights=s.weights_interactive)
    if s.resolution_mode == "CELLS":
        kwargs["cells"] = int(s.cells)
    elif s.resolution_mode == "SIZE":
        kwargs["cell_size"] = float(s.cell_size)
    faces = tris if len(tris) else np.zeros((0, 3), dtype=np.int32)
    with engine_errors("Bind failed"):
        return mod.Deformer(rest, faces, **kwargs)


def ensure_runtime(obj, validate="full"):
    """Return a usable Runtime for a bound object, (re)building the engine when needed.

    ``validate="full"``: hash the topology (raises TopologyChanged) and the rest positions (rebuild
    when they changed), refresh the vertex-group membership. ``"fast"`` (live updates, drags):
    counts only, unless the object was reloaded/undone (new pointer), then full.
    """
    s = obj.larap
    me = obj.data
    counts = (len(me.vertices), len(me.polygons), len(me.loops))
    if counts[0] != s.bind_vertex_count:
        raise TopologyChanged("%r changed topology since bind (%d vertices, %d at bind); rebind it (LARAP > Bind)"
                              % (obj.name, counts[0], s.bind_vertex_count))
    key = _claim_key(obj)
    rt = _RUNTIMES.get(key)
    sig = _settings_sig(s)
    pointer = obj.as_pointer()
    if (validate == "fast" and rt is not None and rt.deformer is not None and rt.validated
            and rt.pointer == pointer and rt.counts == counts and rt.settings_sig == sig):
        return rt
    arrays = topology_arrays(me)
    topo = topology_hash(me, arrays)
    if topo != s.bind_topology:
        raise TopologyChanged("%r changed topology since bind (faces differ); rebind it (LARAP > Bind)" % obj.name)
    rest = rest_positions(obj)
    rest_hash = array_hash(rest)
    if rt is None or rt.deformer is None or rt.settings_sig != sig or rt.rest_hash != rest_hash or rt.topology != topo:
        new = Runtime()
        new.deformer = _build_deformer(obj, rest, triangles(me, arrays))
        new.weights = s.weights_interactive
        if rt is not None:
            new.pose_version = rt.pose_version + 1
        rt = new
        _RUNTIMES[key] = rt
    rt.validated = True
    rt.pointer = pointer
    rt.counts = counts
    rt.settings_sig = sig
    rt.topology = topo
    rt.rest = rest
    rt.rest_hash = rest_hash
    if rt.out is None or rt.out.shape != rest.shape:
        rt.out = np.empty_like(rest)
    rt.membership_sig = None  # refresh vertex groups on full validation
    return rt


# ----------------------------------------------------------------------------------------------
# Operations

class SolveResult:
    def __init__(self, ms, engine_ms, warnings, weights, handles):
        self.ms = ms
        self.engine_ms = engine_ms
        self.warnings = warnings
        self.weights = weights
        self.handles = handles


def _weights_name(s, which):
    if which in ("trilinear", "bspline"):
        return which
    return s.weights_final if which == "final" else s.weights_interactive


FINAL_TOLERANCE = 1e-5  # relative energy decrease at which a final solve stops


def solve(obj, *, weights="final", validate="full", overrides=None, write=True):
    """One solve from the current target transforms; writes the pose key. Returns SolveResult."""
    check_object(obj, need_bound=True)
    s = obj.larap
    t0 = time.perf_counter()
    rt = ensure_runtime(obj, validate)
    d = rt.deformer
    idx, tgt, warnings = gather(obj, rt, overrides)
    wname = _weights_name(s, weights)
    engine_ms = 0.0
    with engine_errors("Solve failed"):
        if len(idx) == 0:
            warnings.append("no usable handles: rest pose written")
            np.copyto(rt.out, rt.rest)
        else:
            current = np.asarray(d.handles)
            if current.shape != idx.shape or not np.array_equal(current, idx):
                d.set_handles(idx)
            if d.weights != wname:
                d.weights = wname
            if abs(float(d.gamma) - float(s.gamma)) > 1e-12 * max(1.0, float(s.gamma)):
                d.gamma = float(s.gamma)
            if weights == "final":
                # The final pose converges (up to 10x the interactive iterations), so solving
                # again from the same targets gives the same pose.
                d.solve(tgt, max(30, 10 * int(s.iterations)), out=rt.out, tol=FINAL_TOLERANCE)
            else:
                d.solve(tgt, int(s.iterations), out=rt.out)
            stats = dict(d.stats)
            rt.stats = stats
            engine_ms = float(stats.get("ms_total", 0.0))
    rt.weights = wname
    rt.lattice_current = True
    if write:
        write_pose(obj, rt.out)
    rt.pose_version += 1
    rt.last_ms = (time.perf_counter() - t0) * 1e3
    rt.last_error = ""
    rt.warnings = warnings
    rt.target_sig = target_signature(obj) if not overrides else None
    return SolveResult(rt.last_ms, engine_ms, warnings, wname, len(idx))


def current_pose(obj):
    """The pose to bake/apply: the pose key as it is when it is up to date (solved with the final
    weights from the current target transforms, so what you see is what you get), else a new solve
    with the final weights. Returns (n,3) float32."""
    check_object(obj, need_bound=True)
    s = obj.larap
    rt = ensure_runtime(obj, "full")
    posed = key_positions(obj, s.shape_key)
    if (posed is not None and rt.target_sig is not None and rt.weights == s.weights_final
            and rt.target_sig == target_signature(obj)):
        return posed
    solve(obj, weights="final", validate="fast")
    return runtime(obj).out.copy()


def bind(obj):
    """Build the lattice + binding from the rest positions, record the targets' rest matrices and
    write the (rest) pose key. Rebinding resets the pose: the current target transforms become rest.
    A failure leaves the object as it was (mesh, keys, settings, previous binding)."""
    check_object(obj)
    with preserve_on_error(obj):
        return _bind(obj)


def _bind(obj):
    s = obj.larap
    me = obj.data
    require_engine()
    key = _claim_key(obj)
    arrays = topology_arrays(me)
    rest = rest_positions(obj)
    rt = Runtime()
    rt.deformer = _build_deformer(obj, rest, triangles(me, arrays))
    rt.weights = s.weights_interactive
    old = _RUNTIMES.get(key)
    if old is not None:
        rt.pose_version = old.pose_version + 1
    rt.pointer = obj.as_pointer()
    rt.counts = (len(me.vertices), len(me.polygons), len(me.loops))
    rt.settings_sig = _settings_sig(s)
    rt.topology = topology_hash(me, arrays)
    rt.rest = rest
    rt.rest_hash = array_hash(rest)
    rt.out = np.empty_like(rest)
    rt.validated = True
    _RUNTIMES[key] = rt
    s.bind_vertex_count = len(me.vertices)
    s.bind_topology = rt.topology
    for h in s.handles:
        if target_alive(h.target):
            try:
                record_rest(h)
            except LarapError:
                h.has_rest = False
        else:
            h.has_rest = False
    had_keys = me.shape_keys is not None
    _, created = ensure_pose_key(obj, s)
    if created and not had_keys:
        s.created_basis = True
    s.bound = True
    return solve(obj, weights="final", validate="fast")


def unbind(obj):
    """Remove what bind made (the pose key LARAP created; the Basis if bind created it and no other
    key is left) and forget the engine. Handles, their vertex groups and targets, other shape keys,
    modifiers and every other object are kept."""
    check_object(obj)
    remove_pose_key(obj)
    obj.larap.bound = False
    drop_runtime(obj)


def _next_group_name(obj):
    used = set()
    for vg in obj.vertex_groups:
        if vg.name.startswith(HANDLE_GROUP_PREFIX) and vg.name[len(HANDLE_GROUP_PREFIX):].isdigit():
            used.add(int(vg.name[len(HANDLE_GROUP_PREFIX):]))
    n = 1
    while n in used:
        n += 1
    return HANDLE_GROUP_PREFIX + str(n)


def _kabsch(p, q):
    """Rigid 4x4 (numpy) with q ~ R p + t."""
    cp, cq = p.mean(axis=0), q.mean(axis=0)
    h = (p - cp).T @ (q - cq)
    u, _, vt = np.linalg.svd(h)
    dfix = np.sign(np.linalg.det(vt.T @ u.T)) or 1.0
    r = vt.T @ np.diag([1.0, 1.0, dfix]) @ u.T
    m = np.eye(4)
    m[:3, :3] = r
    m[:3, 3] = cq - r @ cp
    return m


def add_handle(obj, *, vertex_group="", from_selection=False, target=None, subtarget="", collection=None):
    """Add a handle group. ``from_selection``: new vertex group LARAP_handle_N from the selected vertices.
    Without a target, an Empty is created at the group's centre (placed on the current pose when
    the mesh is posed, so adding a handle does not make the mesh jump)."""
    check_object(obj, allow_edit_mode=from_selection)
    s = obj.larap
    if from_selection:
        sel = selected_vertices(obj)
        if len(sel) == 0:
            raise LarapError("No vertices selected")
        was_edit = obj.mode == "EDIT"
        if was_edit:
            bpy.ops.object.mode_set(mode="OBJECT")
        try:
            vg = obj.vertex_groups.new(name=_next_group_name(obj))
            vg.add(sel.tolist(), 1.0, "REPLACE")
        finally:
            if was_edit:
                bpy.ops.object.mode_set(mode="EDIT")
        vertex_group = vg.name
    if not vertex_group:
        raise LarapError("Give a vertex group, or select vertices in Edit Mode")
    if vertex_group not in obj.vertex_groups:
        raise LarapError("%r has no vertex group %r" % (obj.name, vertex_group))
    if any(h.vertex_group == vertex_group for h in s.handles):
        raise LarapError("Vertex group %r is already a handle" % vertex_group)
    if obj.mode == "EDIT":
        obj.update_from_editmode()
    idx = np.flatnonzero(vertex_group_weights(obj, [vertex_group])[vertex_group] > 0.0)
    if len(idx) == 0:
        raise LarapError("Vertex group %r has no vertices" % vertex_group)
    if target is not None:
        if target == obj:
            raise LarapError("A mesh cannot be its own handle target")
        if subtarget and (target.type != "ARMATURE" or subtarget not in target.pose.bones):
            raise LarapError("Bone %r not found in %r" % (subtarget, target.name))
    rest = rest_positions(obj)[idx].astype(np.float64)
    fit = np.eye(4)
    rest_matrix = None
    if target is None:
        posed = key_positions(obj, s.shape_key) if s.bound else None
        if posed is not None and len(idx) >= 3:
            q = posed[idx].astype(np.float64)
            if np.abs(q - rest).max() > 0:
                fit = _kabsch(rest, q)
        mw = obj.matrix_world
        centre = rest.mean(axis=0)
        ext = float(np.linalg.norm(rest.max(axis=0) - rest.min(axis=0))) if len(idx) > 1 else 0.0
        name = TARGET_PREFIX + (vertex_group[len(HANDLE_GROUP_PREFIX):] if vertex_group.startswith(HANDLE_GROUP_PREFIX)
                                else vertex_group)
        empty = bpy.data.objects.new(name, None)
        empty.empty_display_type = "SPHERE"
        size = ext * 0.6 if ext > 0 else 0.1 * max(obj.dimensions.length, 1e-3)
        empty.empty_display_size = max(size / max(mw.to_scale().length / 3 ** 0.5, 1e-9), 1e-4)
        rest_world = mw @ Matrix.Translation(Vector(centre))
        coll = collection or (obj.users_collection[0] if obj.users_collection else bpy.context.scene.collection)
        coll.objects.link(empty)
        empty.matrix_world = rest_world
        rest_matrix = rest_world
        empty.matrix_world = mw @ Matrix(fit.tolist()) @ mw.inverted_safe() @ rest_world
        target = empty
    h = s.handles.add()
    h.created_target = target is not None and rest_matrix is not None
    h.vertex_group = vertex_group
    h.target = target
    h.subtarget = subtarget
    if rest_matrix is not None:
        h.rest_matrix = flat(rest_matrix)
        h.has_rest = True
    else:
        record_rest(h)
    s.active_handle = len(s.handles) - 1
    rt = runtime(obj)
    if rt is not None:
        rt.membership_sig = None
    return h


def remove_handle(obj, index, *, delete_target=False, delete_group=False):
    check_object(obj, allow_edit_mode=True)
    s = obj.larap
    if not (0 <= index < len(s.handles)):
        raise LarapError("No handle %d" % index)
    h = s.handles[index]
    target, group, created = h.target, h.vertex_group, h.created_target
    s.handles.remove(index)
    s.active_handle = max(0, min(s.active_handle, len(s.handles) - 1))
    # Only an Empty that LARAP created for this handle, and only when asked; never a user object.
    if delete_target and created and target is not None and target_alive(target) and target.type == "EMPTY":
        if not any(o.target == target for o in s.handles):
            bpy.data.objects.remove(target)
    if delete_group and group in obj.vertex_groups and obj.mode != "EDIT":
        obj.vertex_groups.remove(obj.vertex_groups[group])
    rt = runtime(obj)
    if rt is not None:
        rt.membership_sig = None


def bake_shape_key(obj, name="LARAP_pose", *, overwrite=False):
    """Store the current pose (see current_pose) as a new key (value 0) relative to Basis.
    An existing key of that name is replaced only with ``overwrite``."""
    check_object(obj, need_bound=True)
    keys = obj.data.shape_keys
    if not name:
        raise LarapError("Give the baked shape key a name")
    if name == obj.larap.shape_key or (keys is not None and keys.reference_key and name == keys.reference_key.name):
        raise LarapError("Choose a name other than %r" % name)
    if keys is not None and name in keys.key_blocks and not overwrite:
        raise LarapError("Shape key %r exists; choose another name or enable Overwrite" % name)
    with preserve_on_error(obj):
        kb = write_key(obj, name, current_pose(obj))
        kb.value = 0.0
    return kb


@contextlib.contextmanager
def suspend_live():
    _SUSPEND[0] += 1
    try:
        yield
    finally:
        _SUSPEND[0] -= 1


def live_suspended():
    return _SUSPEND[0] > 0


def _set_linear(key, data_path):
    ad = key.animation_data
    if ad is None or ad.action is None:
        return
    fc = ad.action.fcurves.find(data_path)
    if fc is not None:
        for kp in fc.keyframe_points:
            kp.interpolation = "LINEAR"


def bake_animation(obj, scene, frame_start, frame_end, *, step=1, prefix="LARAP_", overwrite=False):
    """One solve per frame from the animated targets (warm-started), each pose a key named
    ``<prefix><frame:04d>`` keyed to 1 on its frame and 0 on the neighbouring baked frames.
    The live pose key is set to 0 afterwards so it does not add to the baked keys. Existing keys of
    those names are replaced only with ``overwrite``; a failure part-way leaves the keys as they were."""
    check_object(obj, need_bound=True)
    if frame_end < frame_start:
        raise LarapError("Frame range is empty (%d..%d)" % (frame_start, frame_end))
    step = max(1, int(step))
    frames = list(range(int(frame_start), int(frame_end) + 1, step))
    keys = obj.data.shape_keys
    wanted = ["%s%04d" % (prefix, f) for f in frames]
    if keys is not None:
        taken = [nm for nm in wanted if nm in keys.key_blocks]
        protected = {obj.larap.shape_key, keys.reference_key.name if keys.reference_key else ""}
        if any(nm in protected for nm in wanted):
            raise LarapError("The prefix %r would overwrite the Basis or pose key; choose another" % prefix)
        if taken and not overwrite:
            raise LarapError("Shape keys %s exist; choose another prefix or enable Overwrite"
                             % ", ".join(repr(nm) for nm in taken[:3]) + (" ..." if len(taken) > 3 else ""))
    with preserve_on_error(obj):
        return _bake_animation(obj, scene, frames, step, prefix)


def _bake_animation(obj, scene, frames, step, prefix):
    old_frame, old_sub = scene.frame_current, scene.frame_subframe
    names = []
    with suspend_live():
        try:
            first = True
            for f in frames:
                scene.frame_set(f)
                solve(obj, weights="final", validate="full" if first else "fast")
                first = False
                name = "%s%04d" % (prefix, f)
                kb = write_key(obj, name, runtime(obj).out)
                keys = obj.data.shape_keys
                path = 'key_blocks["%s"].value' % name
                ad = keys.animation_data
                if ad is not None and ad.action is not None:
                    fc = ad.action.fcurves.find(path)
                    if fc is not None:
                        ad.action.fcurves.remove(fc)
                for frame, value in ((f - step, 0.0), (f, 1.0), (f + step, 0.0)):
                    kb.value = value
                    kb.keyframe_insert("value", frame=frame)
                _set_linear(keys, path)
                names.append(name)
        finally:
            scene.frame_set(old_frame, subframe=old_sub)
    pose = obj.data.shape_keys.key_blocks.get(obj.larap.shape_key)
    if pose is not None:
        pose.value = 0.0
    obj.data.update_tag()
    return names


def apply_pose(obj):
    """Write the current pose (see current_pose) into the mesh (Basis and every other key move
    along, keeping their offsets), remove the pose key and unbind. Destructive: the operator asks
    first. A failure leaves the object as it was."""
    check_object(obj, need_bound=True)
    with preserve_on_error(obj):
        return _apply_pose(obj)


def _apply_pose(obj):
    pose = current_pose(obj)
    rt = runtime(obj)
    me = obj.data
    s = obj.larap
    apply_offsets(obj, pose, rt.rest, skip=s.shape_key)
    remove_pose_key(obj)
    for h in s.handles:
        h.has_rest = False
    s.bound = False
    drop_runtime(obj)
    me.update()
    return pose


# ----------------------------------------------------------------------------------------------
# Live updates (called from handlers.py)

def live_update(scene, updated_names=None):
    """Re-solve every live, bound mesh of ``scene`` whose targets moved. ``updated_names``: the
    objects the depsgraph reported (None: check all). Never raises; errors land in rt.last_error."""
    if live_suspended():
        return 0
    solved = 0
    with suspend_live():
        for obj in list(scene.objects):
            try:
                if obj.type != "MESH" or not obj.larap.bound or not obj.larap.live:
                    continue
            except ReferenceError:
                continue
            targets = target_names(obj)
            if updated_names is not None and not (targets & updated_names):
                continue
            rt = runtime(obj)
            if rt is not None and rt.target_sig is not None and rt.target_sig == target_signature(obj):
                continue
            try:
                if obj.mode == "EDIT":
                    continue
                solve(obj, weights="interactive", validate="fast")
                solved += 1
            except Exception as exc:  # a handler must never raise; LarapError is the expected kind
                msg = str(exc) if isinstance(exc, LarapError) else "internal error: %s: %s" % (
                    type(exc).__name__, exc)
                rt = runtime(obj)
                if rt is None:
                    rt = _RUNTIMES.setdefault(_claim_key(obj), Runtime())
                    rt.pointer = obj.as_pointer()
                if rt.last_error != msg:
                    print("LARAP live update of %r: %s" % (obj.name, msg))
                    if not isinstance(exc, LarapError):
                        import traceback
                        traceback.print_exc()
                rt.last_error = msg
                try:
                    rt.target_sig = target_signature(obj)
                except Exception:
                    rt.target_sig = None
    return solved


# ----------------------------------------------------------------------------------------------
# Interactive posing (the modal operator drives this; tests drive it directly)

def handle_points(obj, refresh=True):
    """(world positions (k,3), handle index per point) of the handle vertices in the current pose.
    ``refresh=False`` (draw callbacks): use the cached vertex-group membership, never touch data."""
    rt = runtime(obj)
    s = obj.larap
    if rt is None or rt.rest is None:
        return np.zeros((0, 3)), np.zeros(0, dtype=np.int64)
    posed = key_positions(obj, s.shape_key)
    if posed is None:
        posed = rt.rest
    groups = membership(obj, rt) if refresh else rt.membership
    pts, owner = [], []
    for i, h in enumerate(s.handles):
        idx = groups.get(h.vertex_group)
        if idx is None or len(idx) == 0 or not h.enabled:
            continue
        pts.append(posed[idx])
        owner.append(np.full(len(idx), i, dtype=np.int64))
    if not pts:
        return np.zeros((0, 3)), np.zeros(0, dtype=np.int64)
    p = np.concatenate(pts).astype(np.float64)
    mw = np.array(obj.matrix_world)
    return p @ mw[:3, :3].T + mw[:3, 3], np.concatenate(owner)


_TRANSFORM_ATTRS = ("location", "rotation_euler", "rotation_quaternion", "rotation_axis_angle", "scale")


def _transform_snapshot(target, bone):
    holder = target.pose.bones[bone] if bone else target
    snap = {attr: tuple(getattr(holder, attr)) for attr in _TRANSFORM_ATTRS}
    snap["rotation_mode"] = holder.rotation_mode
    snap["matrix_world"] = None if bone else target.matrix_world.copy()
    return snap


def _transform_restore(target, bone, snap):
    """Exact restore: the world matrix first (so it is right before the next depsgraph update),
    then the loc/rot/scale channels it was decomposed from, as they were (no round-off)."""
    holder = target.pose.bones[bone] if bone else target
    if snap["matrix_world"] is not None:
        target.matrix_world = snap["matrix_world"]
    holder.rotation_mode = snap["rotation_mode"]
    for attr in _TRANSFORM_ATTRS:
        setattr(holder, attr, snap[attr])


class PoseSession:
    """Drag one handle: move/rotate/scale its target about the handle's current centre.

    begin() snapshots the pose key and the target's transform; update() solves with the interactive
    weights and writes only the pose key; confirm() re-solves with the final weights; cancel()
    restores the snapshot bit-exactly.
    """

    def __init__(self, obj, handle_index):
        self.obj = obj
        self.handle_index = handle_index
        self.active = False
        self.last = None

    @property
    def handle(self):
        return self.obj.larap.handles[self.handle_index]

    def begin(self):
        obj = self.obj
        check_object(obj, need_bound=True)
        s = obj.larap
        if not (0 <= self.handle_index < len(s.handles)):
            raise LarapError("No handle %d" % self.handle_index)
        h = self.handle
        if not target_alive(h.target):
            raise LarapError("Handle %r has no target" % h.vertex_group)
        self.target = h.target
        self.bone = h.subtarget
        if self.bone and (self.target.type != "ARMATURE" or self.bone not in self.target.pose.bones):
            raise LarapError("Bone %r not found in %r" % (self.bone, self.target.name))
        rt = ensure_runtime(obj, "full")
        self.key_existed = bool(obj.data.shape_keys and obj.data.shape_keys.key_blocks.get(s.shape_key))
        self.snapshot = key_positions(obj, s.shape_key) if self.key_existed else None
        self.transform = _transform_snapshot(self.target, self.bone)
        self.start_matrix = target_matrix(h)
        idx = membership(obj, rt).get(h.vertex_group)
        if idx is None or len(idx) == 0:
            raise LarapError("Handle %r has no vertices" % h.vertex_group)
        posed = self.snapshot if self.snapshot is not None else rt.rest
        centre = posed[idx].astype(np.float64).mean(axis=0)
        self.pivot = obj.matrix_world @ Vector(centre)
        self.overrides_key = (self.target.name_full, self.bone)
        self.active = True
        return self

    def delta_matrix(self, translation=(0.0, 0.0, 0.0), rotation=None, scale=None):
        """World delta: rotate/scale about the pivot, then translate."""
        pivot = Matrix.Translation(self.pivot)
        m = Matrix.Identity(4)
        if scale is not None:
            m = Matrix.Diagonal(Vector((scale[0], scale[1], scale[2], 1.0))) @ m
        if rotation is not None:
            rot = rotation.to_matrix() if hasattr(rotation, "to_matrix") else Matrix(rotation)
            m = rot.to_4x4() @ m
        return Matrix.Translation(Vector(translation)) @ pivot @ m @ pivot.inverted()

    def set_target_matrix(self, world):
        if self.bone:
            arm = self.target
            arm.pose.bones[self.bone].matrix = arm.matrix_world.inverted_safe() @ world
        else:
            self.target.matrix_world = world

    def update(self, translation=(0.0, 0.0, 0.0), rotation=None, scale=None, weights="interactive"):
        if not self.active:
            raise LarapError("Pose session is not active")
        world = self.delta_matrix(translation, rotation, scale) @ self.start_matrix
        self.set_target_matrix(world)
        self.world = world
        self.last = solve(self.obj, weights=weights, validate="fast", overrides={self.overrides_key: world})
        return self.last

    def confirm(self):
        if not self.active:
            return self.last
        overrides = {self.overrides_key: self.world} if hasattr(self, "world") else None
        self.last = solve(self.obj, weights="final", validate="fast", overrides=overrides)
        rt = runtime(self.obj)
        if rt is not None:
            rt.target_sig = None
        self.active = False
        return self.last

    def cancel(self):
        if not self.active:
            return
        obj = self.obj
        _transform_restore(self.target, self.bone, self.transform)
        restore_pose_key(obj, self.snapshot)
        rt = runtime(obj)
        if rt is not None:
            rt.target_sig = None
            rt.lattice_current = False
            rt.pose_version += 1
        self.active = False
