# SPDX-License-Identifier: GPL-3.0-or-later
"""The runtime cache: each bound object's engine (``larap.Deformer``) and what it was told.

Engine objects are never stored in the .blend. A :class:`Runtime` is keyed by
``Object.larap.runtime_id`` (a uuid stored in the object, so renames keep the engine) and checked
against the object's pointer (a duplicate, which copies the id, gets a new one). It is built
lazily by :func:`ensure_runtime` from the stored settings: after bind, reloading a .blend, an
undo, a settings change, or an edit of the rest positions.

The Runtime also keeps, on the Python side, what the engine holds: the handle ids, the weights
and gamma it was last given (``engine_handles``, ``engine_weights``, ``engine_gamma``).
:meth:`Runtime.set_engine_state` calls the engine only when one of them changed, so a solve never
reads the engine's state back to compare.
"""
import uuid

import bpy
import numpy as np

from . import scene_index
from .errors import TopologyChanged, engine_errors, require_engine
from .mesh_data import (array_hash, loose_edge_count, polygons, read_only, rest_positions, topology_arrays,
                        topology_hash)
from .props import upgrade_settings
from .targets import target_signature


class Runtime:
    def __init__(self):
        self.deformer = None
        self.pointer = 0
        self.settings_sig = None
        self.counts = None  # (verts, polys, loops, edges)
        self.loose_edges = 0  # edges on no face (the GPU preview, which draws faces, steps aside)
        self.topology = ""
        self.rest = None  # (n,3) float32 rest positions the engine was built on, read only (_refresh)
        self.rest_hash = ""
        self.out = None
        self.membership = {}  # vertex group -> sorted int64 indices (weight > 0)
        self.membership_weights = {}  # vertex group -> their weights, aligned with membership
        self.membership_sig = None
        self.membership_hash = ""  # content of the membership (ids and weights)
        self.group_cache = None  # (key, disjoint groups, their vertex weights): targets.gather
        self.last_ms = 0.0
        self.stats = {}
        self.weights = ""  # weights the pose key was solved with ("": unknown)
        self.target_sig = None
        self.pose_version = 0
        self.last_error = ""
        self.warnings = []
        self.kept_edits = ""  # the key the last hand edits of the pose key were kept in (key_edits.py)
        self.validated = False  # False: the next ensure_runtime does a full validation
        self.lattice_current = False  # the engine's lattice is the pose in the pose key (overlay)
        self.handle_points = None  # (key, points, owner): session.handle_points of the last pose
        self.handle_binding = None  # the handle vertices' lattice cells and weights (session.py)
        # Preview and catch-up (preview.py, catchup.py): the lattice of the last interactive pose,
        # whether the pose key is behind what is shown, when the targets last moved, and how
        # many times the engine solved (tests count them).
        self.lattice_nodes = None
        self.needs_catchup = False
        self.last_move = 0.0
        self.engine_calls = 0
        # What the engine holds (None: unknown, set it again before the next solve).
        self.engine_handles = None
        self.engine_weights = None
        self.engine_gamma = None

    def set_engine_state(self, pose, weights, gamma):
        """Give the engine the handle groups of ``pose`` (targets.HandlePose), the weights and
        gamma, calling it only for what changed. A call that raises leaves that entry unknown, so
        the next solve sets it again."""
        d = self.deformer
        groups_key = (pose.key, pose.weights)
        if self.engine_handles != groups_key:
            self.engine_handles = None
            d.set_handle_groups(pose.groups, weights=list(pose.weights), vertex_weights=pose.vertex_weights)
            self.engine_handles = groups_key
        if self.engine_weights != weights:
            self.engine_weights = None
            d.weights = weights
            self.engine_weights = weights
        if self.engine_gamma != gamma:
            self.engine_gamma = None
            d.gamma = gamma
            self.engine_gamma = gamma


_RUNTIMES = {}


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


def claim_key(obj):
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


def runtime_or_placeholder(obj):
    """The object's runtime, or a new one without an engine (to hold an error for the panel)."""
    rt = runtime(obj)
    if rt is None:
        rt = _RUNTIMES.setdefault(claim_key(obj), Runtime())
        rt.pointer = obj.as_pointer()
    return rt


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
    for obj in scene_index.bound_meshes(None):
        try:
            if obj.larap.bound and obj.larap.runtime_id:
                yield obj
        except ReferenceError:
            continue


def prune_runtimes():
    """Forget runtimes whose object is gone or unbound (cheap; called from handlers). The file is
    read now, not taken from scene_index's kept list: what is missing is dropped."""
    scene_index.invalidate()
    alive = {obj.larap.runtime_id for obj in _bound_meshes()}
    for key in list(_RUNTIMES):
        if key not in alive:
            _RUNTIMES.pop(key, None)


def after_undo():
    """undo_post/redo_post: the mesh, its keys, the settings and the targets are what the undo step
    stored; the engines must not carry on from the undone state. Each runtime is re-validated in
    full at its next use (rest shape, topology, vertex groups), its warm start is forgotten, its
    lattice is no longer drawn as current, the weights it records for the restored pose key are
    unknown (``rt.weights``, which nothing decides by: Bake/Apply go by the pose signature the
    undo step restored with the object, solving.key_up_to_date), and the restored target matrices
    are recorded as the ones the restored pose key was solved for (so Live does not overwrite
    what the undo restored)."""
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
        rt.needs_catchup = False
        rt.lattice_nodes = None
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


# ----------------------------------------------------------------------------------------------
# Kept across an operation that may fail (transaction.py puts it back)

def snapshot_entry(obj):
    key0 = obj.larap.runtime_id
    return key0, (_RUNTIMES.get(key0) if key0 else None)


def restore_entry(obj, entry):
    """Put back the runtime ``snapshot_entry`` saw (dropping any made since), not trusting what
    its engine solved last."""
    key0, rt0 = entry
    for k in [k for k, rt in _RUNTIMES.items() if k == key0 or rt.pointer == obj.as_pointer()]:
        _RUNTIMES.pop(k, None)
    if rt0 is not None:
        rt0.target_sig = None  # what the engine solved last was not kept
        rt0.weights = ""
        rt0.lattice_current = False
        rt0.pose_version += 1
        _RUNTIMES[key0] = rt0


# ----------------------------------------------------------------------------------------------
# Building the engine

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
    return res + (resolve_device(s), bool(s.split_cells))


def _new_runtime(obj, rest, faces):
    """A Runtime holding a new engine for the rest shape ``rest`` (what the engine was given
    recorded), not yet registered."""
    mod = require_engine()
    s = obj.larap
    gamma, weights = upgrade_settings(s), s.weights_interactive
    kwargs = dict(gamma=gamma, device=resolve_device(s), weights=weights)
    if s.resolution_mode == "CELLS":
        kwargs["cells"] = int(s.cells)
    elif s.resolution_mode == "SIZE":
        kwargs["cell_size"] = float(s.cell_size)
    kwargs["split_cells"] = bool(s.split_cells)
    ids, offsets = faces
    rt = Runtime()
    with engine_errors("Bind failed"):
        rt.deformer = mod.Deformer(rest, ids, face_offsets=offsets, **kwargs)
    rt.engine_weights, rt.engine_gamma = weights, gamma
    rt.weights = weights
    return rt


def _refresh(obj, key, arrays, topo, rebuild, rest=None):
    """Fill the object's runtime from its rest shape as it is now (``rest``: its positions, when
    the caller has just read them); a new engine when ``rebuild``, or when the settings, rest
    positions or topology differ from what the cached one was built on. ``rt.rest`` is read only:
    the caller's array when it is (a snapshot's, which the solves read too), else a copy, so that a
    caller's own array is neither frozen nor shared."""
    s = obj.larap
    me = obj.data
    sig = _settings_sig(s)
    if rest is None:
        rest = read_only(rest_positions(obj))
    elif rest.flags.writeable:
        rest = read_only(rest.copy())
    rest_hash = array_hash(rest)
    rt = _RUNTIMES.get(key)
    if (rebuild or rt is None or rt.deformer is None or rt.settings_sig != sig or rt.rest_hash != rest_hash
            or rt.topology != topo):
        new = _new_runtime(obj, rest, polygons(me, arrays))
        if rt is not None:
            new.pose_version = rt.pose_version + 1
        rt = new
        _RUNTIMES[key] = rt
    rt.validated = True
    rt.pointer = obj.as_pointer()
    rt.counts = _counts(me)
    rt.loose_edges = loose_edge_count(me)
    rt.settings_sig = sig
    rt.topology = topo
    rt.rest = rest
    rt.rest_hash = rest_hash
    if rt.out is None or rt.out.shape != rest.shape:
        rt.out = np.empty_like(rest)
    rt.membership_sig = None  # refresh vertex groups on full validation
    return rt


def _counts(me):
    """What a fast validation compares: a change of any of these counts is checked in full."""
    return len(me.vertices), len(me.polygons), len(me.loops), len(me.edges)


def build_runtime(obj, rest=None):
    """Bind: a new engine from the rest shape as it is now, replacing the cached one. ``rest``: the
    rest positions (``mesh_data.rest_positions``) when the caller has just read them."""
    require_engine()
    key = claim_key(obj)
    me = obj.data
    arrays = topology_arrays(me)
    return _refresh(obj, key, arrays, topology_hash(me, arrays), rebuild=True, rest=rest)


def ensure_runtime(obj, validate="full", rest=None):
    """Return a usable Runtime for a bound object, (re)building the engine when needed.

    ``validate="full"``: hash the topology (raises TopologyChanged) and the rest positions (rebuild
    when they changed), refresh the vertex-group membership. ``"fast"`` (live updates, drags):
    counts only, unless the object was reloaded/undone (new pointer), then full.

    ``rest``: the rest positions (``mesh_data.rest_positions``) when the caller has just read them,
    nothing written to the rest shape since (Bake and Apply: their snapshot's): a full validation
    takes them, as ``Runtime.rest`` (read only), instead of reading the rest shape again.
    """
    s = obj.larap
    me = obj.data
    counts = _counts(me)
    if counts[0] != s.bind_vertex_count:
        raise TopologyChanged("%r changed topology since bind (%d vertices, %d at bind); rebind it (LARAP > Bind)"
                              % (obj.name, counts[0], s.bind_vertex_count))
    key = claim_key(obj)
    rt = _RUNTIMES.get(key)
    if (validate == "fast" and rt is not None and rt.deformer is not None and rt.validated
            and rt.pointer == obj.as_pointer() and rt.counts == counts and rt.settings_sig == _settings_sig(s)):
        return rt
    arrays = topology_arrays(me)
    topo = topology_hash(me, arrays)
    if topo != s.bind_topology:
        raise TopologyChanged("%r changed topology since bind (faces or wire edges differ); rebind it (LARAP > Bind)" % obj.name)
    return _refresh(obj, key, arrays, topo, rebuild=False, rest=rest)
