# SPDX-License-Identifier: GPL-3.0-or-later
"""Handles and their targets: where each handle's vertices should go now.

A handle (``Object.larap.handles``) is a vertex group that follows a target (an object, or a bone
of an armature) since bind. At bind the target's world matrix is recorded as its rest
(:func:`record_rest`); at each pose :func:`gather` gives the engine one handle group per usable
handle (its vertices, first handle wins where groups overlap; the vertex-group weights as a soft
falloff; the handle's Weight) and one transform per group: the target's motion since bind,
expressed in the mesh's local space. The groups are rebuilt only when the usable handles or
their vertex groups change; a pose costs nothing per handle vertex in Python.
:func:`target_signature` is what a solve was made from, so Live can skip a solve that would give
the same pose.

The runtime (runtime.py) caches the vertex-group membership; this module reads and fills that
cache but never builds or drops a runtime.
"""
import hashlib

import numpy as np
from mathutils import Matrix

from .errors import LarapError
from .mesh_data import vertex_group_weights


def flat(m):
    """A 4x4 matrix as 16 floats, row-major (how ``rest_matrix`` stores it)."""
    return [m[i][j] for i in range(4) for j in range(4)]


def _matrix(flat16):
    return Matrix([flat16[0:4], flat16[4:8], flat16[8:12], flat16[12:16]])


def target_alive(target):
    if target is None:
        return False
    try:
        return len(target.users_scene) > 0
    except ReferenceError:
        return False


def target_matrix(handle, overrides=None):
    """World matrix of a handle's target now, or raise LarapError (missing target/bone).
    ``overrides``: {(target name, bone): world matrix} used instead (a drag in progress)."""
    t = handle.target
    if not target_alive(t):
        raise LarapError("handle %r has no target (deleted?)" % handle.vertex_group)
    key = (t.name_full, handle.subtarget)
    if overrides and key in overrides:
        return overrides[key]
    if handle.subtarget:
        if t.type != "ARMATURE" or t.pose is None or handle.subtarget not in t.pose.bones:
            raise LarapError("handle %r: bone %r not found in %r" % (handle.vertex_group, handle.subtarget, t.name))
        return t.matrix_world @ t.pose.bones[handle.subtarget].matrix
    return t.matrix_world.copy()


def handle_local_transform(obj, handle, overrides=None):
    """Target motion since bind, expressed in the mesh object's local space (4x4 numpy)."""
    now = target_matrix(handle, overrides)
    rest = _matrix(handle.rest_matrix)
    mw = obj.matrix_world
    local = mw.inverted_safe() @ now @ rest.inverted_safe() @ mw
    return np.array(local, dtype=np.float64)


def record_rest(handle, overrides=None):
    handle.rest_matrix = flat(target_matrix(handle, overrides))
    handle.has_rest = True


def membership(obj, rt):
    """{vertex group: sorted int64 vertex ids (weight > 0)} of the enabled handles, cached in the
    runtime ``rt`` until the set of handle groups changes (or the runtime asks for a refresh);
    ``rt.membership_weights`` holds their weights, aligned with the ids."""
    s = obj.larap
    names = tuple(h.vertex_group for h in s.handles if h.enabled and h.vertex_group)
    available = tuple(nm for nm in names if nm in obj.vertex_groups)
    if rt.membership_sig != available:
        weights = vertex_group_weights(obj, available)
        rt.membership = {nm: np.flatnonzero(w > 0.0) for nm, w in weights.items()}
        rt.membership_weights = {nm: weights[nm][rt.membership[nm]].astype(np.float64) for nm in weights}
        rt.membership_sig = available
        h = hashlib.blake2b(digest_size=16)
        for nm in available:
            h.update(nm.encode())
            h.update(rt.membership[nm].tobytes())
            h.update(rt.membership_weights[nm].tobytes())
        rt.membership_hash = h.hexdigest()  # what the groups hold: same content, same engine groups
    return rt.membership


class HandlePose:
    """What one pose gives the engine: handle groups (rebuilt only when ``key`` changes) and one
    4x4 transform per group."""

    def __init__(self, key, groups, vertex_weights, weights, transforms, warnings):
        self.key = key                        # identifies groups + vertex_weights
        self.groups = groups                  # list of int64 vertex-id arrays, disjoint
        self.vertex_weights = vertex_weights  # list of float64 arrays aligned with groups
        self.weights = weights                # tuple of the handles' Weight
        self.transforms = transforms          # (G, 4, 4) float64, mesh-local
        self.warnings = warnings

    @property
    def count(self):
        """Handle vertices that pull (all groups)."""
        return int(sum(len(g) for g in self.groups))


def _resolve_groups(rt, names, n):
    """Disjoint groups for the handles' vertex groups `names` (in order; the first handle wins a
    vertex two groups share), with their vertex-group weights."""
    taken = np.zeros(n, dtype=bool)
    groups, vweights = [], []
    for nm in names:
        ids, w = rt.membership[nm], rt.membership_weights[nm]
        free = ~taken[ids]
        groups.append(np.ascontiguousarray(ids[free]))
        vweights.append(np.ascontiguousarray(w[free]))
        taken[ids] = True
    return groups, vweights


def gather(obj, rt, overrides=None):
    """The HandlePose of the object's usable handles now; warnings name the skipped ones."""
    s = obj.larap
    groups = membership(obj, rt)
    warnings = []
    names, weights, maps = [], [], []
    for h in s.handles:
        if not h.enabled:
            continue
        label = h.vertex_group or "(no group)"
        if h.vertex_group not in obj.vertex_groups:
            warnings.append("handle %r skipped: vertex group not found (renamed or deleted? pick the group "
                            "again in the handle's settings)" % label)
            continue
        idx = groups.get(h.vertex_group)
        if idx is None or len(idx) == 0:
            warnings.append("handle %r skipped: vertex group is empty" % label)
            continue
        if not h.has_rest:
            warnings.append("handle %r skipped: not bound (rebind)" % label)
            continue
        try:
            local = handle_local_transform(obj, h, overrides)
        except LarapError as exc:
            warnings.append("%s; skipped" % exc)
            continue
        if not np.isfinite(local).all() or abs(np.linalg.det(local[:3, :3])) < 1e-12:
            warnings.append("handle %r skipped: its target is scaled to zero" % label)
            continue
        names.append(h.vertex_group)
        weights.append(float(h.weight))
        maps.append(local)
    key = (rt.membership_hash, tuple(names))
    if getattr(rt, "group_cache", None) is None or rt.group_cache[0] != key:
        rt.group_cache = (key,) + _resolve_groups(rt, names, len(rt.rest))
    _, gr, vw = rt.group_cache
    T = np.stack(maps) if maps else np.zeros((0, 4, 4))
    return HandlePose(key, gr, vw, tuple(weights), T, warnings)


def target_signature(obj):
    """Current target matrices of an object's handles (to skip redundant live solves)."""
    sig = [tuple(obj.matrix_world.col[3]) + tuple(obj.matrix_world.col[0]) + tuple(obj.matrix_world.col[1])
           + tuple(obj.matrix_world.col[2])]
    for h in obj.larap.handles:
        try:
            m = target_matrix(h)
            sig.append(tuple(flat(m)))
        except LarapError:
            sig.append(None)
    return tuple(sig)


def target_names(obj):
    names = set()
    for h in obj.larap.handles:
        t = h.target
        try:
            if t is not None:
                names.add(t.name_full)
        except ReferenceError:
            pass
    return names
