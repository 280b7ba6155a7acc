# SPDX-License-Identifier: GPL-3.0-or-later
"""Handles and their targets: where each handle's vertices should go now.

A handle (``Object.larap.handles``) is a vertex group that follows a target (an object, or a bone
of an armature) since bind. At bind the target's world matrix is recorded as its rest
(:func:`record_rest`); at each pose :func:`gather` gives the engine one handle group per usable
handle (its vertices, first handle wins where groups overlap; the vertex-group weights as a soft
falloff; the handle's Weight) and one transform per group: the target's motion since bind,
expressed in the mesh's local space. The groups are rebuilt only when the usable handles or
their vertex groups change; a pose costs nothing per handle vertex in Python.
Picking another target for a bound handle keeps the pose (:func:`retarget_keep_pose`): the new
target's rest is recorded where the handle's vertices are now, so nothing jumps. A bone renamed
after it was picked is found again by its rest in the armature (:func:`follow_bone_renames`).
:func:`target_signature` is what a solve was made from, so Live can skip a solve that would give
the same pose.

The runtime (runtime.py) caches the vertex-group membership; this module reads and fills that
cache but never builds or drops a runtime.
"""
import contextlib
import hashlib

import numpy as np
from mathutils import Matrix

from .errors import LarapError
from .mesh_data import vertex_group_weights
from .scene_index import bound_meshes, target_alive  # noqa: F401 (target_alive: part of this module's API)


def flat(m):
    """A 4x4 matrix as 16 floats, row-major (how ``rest_matrix`` stores it)."""
    return [m[i][j] for i in range(4) for j in range(4)]


def _matrix(flat16):
    return Matrix([flat16[0:4], flat16[4:8], flat16[8:12], flat16[12:16]])


def object_matrix(t, bone, label="", overrides=None):
    """World matrix now of the object ``t`` (or its pose bone ``bone``), or raise LarapError.
    ``overrides``: {(target name, bone): world matrix} used instead (a drag in progress)."""
    if not target_alive(t):
        raise LarapError("handle %r has no target (deleted?)" % label)
    key = (t.name_full, bone)
    if overrides and key in overrides:
        return overrides[key]
    if bone:
        if t.type != "ARMATURE" or t.pose is None or bone not in t.pose.bones:
            raise LarapError("handle %r: bone %r not found in %r" % (label, bone, t.name))
        return t.matrix_world @ t.pose.bones[bone].matrix
    return t.matrix_world.copy()


def target_matrix(handle, overrides=None):
    """World matrix of a handle's target now, or raise LarapError (missing target/bone). The bone
    is read by its name (a pose follows renames first: :func:`follow_bone_renames`)."""
    return object_matrix(handle.target, handle.subtarget, handle.vertex_group, overrides)


# ----------------------------------------------------------------------------------------------
# A renamed bone is followed (Blender renames it in constraints and vertex groups, not here)

def _bone_rest(bone):
    m = bone.matrix_local  # row-major, as flat(), then the length
    return np.array((*m[0], *m[1], *m[2], *m[3], bone.length), dtype=np.float32)


def _resolve_bone(handle):
    """(the name of the handle's bone now, whether that bone has the recorded rest); see bone_name."""
    name = handle.subtarget
    t = handle.target
    if (not name or not handle.has_bone_rest or not target_alive(t) or t.type != "ARMATURE"
            or handle.bone_rest_armature != t):
        return name, False
    bones = t.data.bones
    want = np.asarray(handle.bone_rest, dtype=np.float32)
    tol = 1e-6 * max(1.0, float(np.abs(want).max()))
    named = bones.get(name)
    if named is not None and np.abs(_bone_rest(named) - want).max() <= tol:
        return name, True
    found = [b.name for b in bones if np.abs(_bone_rest(b) - want).max() <= tol]
    return (found[0], True) if len(found) == 1 else (name, False)


def bone_name(handle):
    """The name of the handle's bone now: ``subtarget`` when that bone has the rest (matrix_local
    and length) recorded for it, else the one bone of the same armature that has it (the bone was
    renamed, or names were flipped); ``subtarget`` when none or several match (a bone moved in Edit
    Mode keeps its name). Reads only (safe in draw callbacks)."""
    return _resolve_bone(handle)[0]


def follow_bone_renames(obj):
    """Point every handle of ``obj`` whose bone was renamed at its new name (and record the rest of
    every bone found by name, for a later rename). Returns [(old, new)] of the names changed."""
    renamed = []
    for h in obj.larap.handles:
        t = h.target
        if not h.subtarget or not target_alive(t) or t.type != "ARMATURE":
            continue
        new, matched = _resolve_bone(h)
        if matched and new == h.subtarget:  # the common case, each pose: nothing to write
            continue
        bone = t.data.bones.get(new)
        if bone is None:
            continue
        with quiet_retarget():
            if new != h.subtarget:
                if h.rest_target == t and h.rest_subtarget == h.subtarget:
                    h.rest_subtarget = new
                renamed.append((h.subtarget, new))
                h.subtarget = new
            if not matched:  # first found by name, or moved in Edit Mode: its rest now
                _record_bone(h, bone)
    return renamed


def _record_bone(handle, bone):
    """Record the rest of the handle's bone and its armature (written only when they changed)."""
    rest = _bone_rest(bone)
    if (not handle.has_bone_rest or handle.bone_rest_armature != handle.target
            or not np.array_equal(np.asarray(handle.bone_rest, dtype=np.float32), rest)):
        handle.bone_rest = rest.tolist()
        handle.has_bone_rest = True
        handle.bone_rest_armature = handle.target


def handle_local_transform(obj, handle, overrides=None):
    """Target motion since bind, expressed in the mesh object's local space (4x4 numpy)."""
    now = target_matrix(handle, overrides)
    rest = _matrix(handle.rest_matrix)
    mw = obj.matrix_world
    local = mw.inverted_safe() @ now @ rest.inverted_safe() @ mw
    return np.array(local, dtype=np.float64)


def record_rest(handle, overrides=None, motion=None):
    """Record the handle's rest: its target's world matrix now, or with ``motion`` (the world motion
    the handle's vertices made since rest, a Matrix) the matrix the target had ``motion`` ago."""
    with quiet_retarget():
        if handle.subtarget:  # a bone renamed since its record: point at it first
            handle.subtarget = bone_name(handle)
    now = target_matrix(handle, overrides)
    with quiet_retarget():
        if handle.subtarget:
            _record_bone(handle, handle.target.data.bones[handle.subtarget])
        handle.rest_matrix = flat(now if motion is None else motion.inverted_safe() @ now)
        handle.has_rest = True
        handle.rest_target = handle.target
        handle.rest_subtarget = handle.subtarget


# ----------------------------------------------------------------------------------------------
# Retargeting keeps the pose

_QUIET = [0]


@contextlib.contextmanager
def quiet_retarget():
    """LARAP's own writes of a handle's target (adding a handle, recording a rest) are not an
    artist's retarget: the update callback leaves them alone."""
    _QUIET[0] += 1
    try:
        yield
    finally:
        _QUIET[0] -= 1


def handle_motion(handle):
    """World motion (Matrix) of the handle since its rest: what the target whose matrix the rest
    is (``rest_target``/``rest_subtarget``) did since then; None when that is unknown or gone."""
    if not handle.has_rest or not target_alive(handle.rest_target):
        return None
    try:
        now = object_matrix(handle.rest_target, handle.rest_subtarget, handle.vertex_group)
    except LarapError:
        return None
    return now @ _matrix(handle.rest_matrix).inverted_safe()


def _fit(p, q):
    """4x4 numpy map with q ~ M p: affine when the points span 3-D, else rigid (3+ points not on a
    line), else a translation."""
    cp, cq = p.mean(axis=0), q.mean(axis=0)
    a, b = p - cp, q - cq
    m = np.eye(4)
    sv = np.linalg.svd(a, compute_uv=False) if len(p) >= 3 else np.zeros(1)
    if len(p) >= 4 and sv[-1] > 1e-6 * max(sv[0], 1e-30):
        m[:3, :3] = np.linalg.lstsq(a, b, rcond=None)[0].T
    elif len(p) >= 3 and sv[min(1, len(sv) - 1)] > 1e-6 * max(sv[0], 1e-30):
        u, _, vt = np.linalg.svd(a.T @ b)
        d = np.sign(np.linalg.det(vt.T @ u.T)) or 1.0
        m[:3, :3] = vt.T @ np.diag([1.0, 1.0, d]) @ u.T
    m[:3, 3] = cq - m[:3, :3] @ cp
    return m


def pose_fit(obj, handle, ids=None, rest=None, posed=None):
    """World motion (Matrix) that best carries the handle's vertices from rest to where the pose
    key shows them now; None without a pose key or vertices. ``ids``: the group's vertex ids
    (read from the vertex group when not given). ``rest``, ``posed``: the rest positions
    (``mesh_data.rest_positions``) and the pose key's (``mesh_data.key_positions`` of
    ``shape_key``) when the caller has just read them, nothing changed since (not read again)."""
    from .mesh_data import key_positions, rest_positions
    if posed is None:
        posed = key_positions(obj, obj.larap.shape_key)
    if posed is None or handle.vertex_group not in obj.vertex_groups:
        return None
    if ids is None:
        weights = vertex_group_weights(obj, [handle.vertex_group], rest)
        ids = np.flatnonzero(weights[handle.vertex_group] > 0.0)
    if len(ids) == 0:
        return None
    if rest is None:
        rest = rest_positions(obj)
    local = _fit(rest[ids].astype(np.float64), posed[ids].astype(np.float64))
    mw = obj.matrix_world
    return mw @ Matrix(local.tolist()) @ mw.inverted_safe()


def retarget_keep_pose(obj, handle, ids=None, rest=None, posed=None):
    """The handle's target (or bone) was changed: record the new target's rest so the handle's
    vertices stay where they are now. The motion they made comes from the previous target (exact),
    else from the pose key (a fit: :func:`pose_fit`, which takes ``ids``, ``rest`` and ``posed``),
    else there is none (not posed). Returns True when a rest was recorded; False when the handle
    cannot pose yet (no target, no bone picked)."""
    t = handle.target
    if not target_alive(t):
        return False
    if handle.subtarget and t.type != "ARMATURE":
        with quiet_retarget():
            handle.subtarget = ""  # a bone name means nothing on an Empty
    try:
        target_matrix(handle)
    except LarapError:
        return False  # e.g. an armature whose bone is not picked yet: wait for it
    motion = handle_motion(handle)
    if motion is None:
        motion = pose_fit(obj, handle, ids, rest, posed)
    record_rest(handle, motion=motion)
    return True


def on_target_changed(handle):
    """Update callback of ``target``/``subtarget``: keep the pose of a bound mesh. Never raises."""
    if _QUIET[0]:
        return
    try:
        handle.has_bone_rest = False  # the artist picked this bone (or target): its rest is recorded anew
        obj = handle.id_data
        if obj is None or obj.type != "MESH" or not obj.larap.bound:
            return
        from .runtime import runtime  # here: runtime.py imports this module
        rt = runtime(obj)
        ids = rt.membership.get(handle.vertex_group) if rt is not None and rt.membership_sig is not None else None
        retarget_keep_pose(obj, handle, ids)
    except Exception as exc:  # an update callback must not raise into Blender's UI
        print("LARAP: retargeting %r: %s: %s" % (getattr(handle, "vertex_group", "?"), type(exc).__name__, exc))


def membership(obj, rt, rest=None):
    """{vertex group: sorted int64 vertex ids (weight > 0)} of the enabled handles, cached in the
    runtime ``rt`` until the set of handle groups changes (or the runtime asks for a refresh);
    ``rt.membership_weights`` holds their weights, aligned with the ids. ``rest``: the rest
    positions when the caller has just read them (see :func:`mesh_data.vertex_group_weights`)."""
    s = obj.larap
    names = tuple(h.vertex_group for h in s.handles if h.enabled and h.vertex_group)
    available = tuple(nm for nm in names if nm in obj.vertex_groups)
    if rt.membership_sig != available:
        weights = vertex_group_weights(obj, available, rest)
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


def singular(a):
    """The engine's test for a handle map it rejects: |det A| <= 1e-9 (||A||_F / sqrt 3)^3, relative
    to the map's size (a target flattened to scale (1, 1, 1e-10) is singular; a uniform 1e-5 is not)."""
    norm = np.linalg.norm(a) / np.sqrt(3.0)
    return not abs(np.linalg.det(a)) > 1e-9 * norm ** 3


def gather(obj, rt, overrides=None, rest=None):
    """The HandlePose of the object's usable handles now; warnings name the skipped ones.
    ``rest``: the rest positions when the caller has just read them (:func:`membership`)."""
    s = obj.larap
    groups = membership(obj, rt, rest)
    warnings = ["handle's bone %r was renamed %r: the handle follows it" % pair for pair in follow_bone_renames(obj)]
    names, weights, maps = [], [], []
    for h in s.handles:
        if not h.enabled:
            continue
        reason = _skip_reason(obj, h, groups)
        if reason:
            warnings.append(reason)
            continue
        try:
            local = handle_local_transform(obj, h, overrides)
        except LarapError as exc:
            warnings.append("%s; skipped" % exc)
            continue
        if not np.isfinite(local).all():
            warnings.append("handle %r skipped: its target's transform is not a number (NaN or infinite "
                            "location, rotation or scale)" % (h.vertex_group or "(no group)"))
            continue
        if singular(local[:3, :3]):
            warnings.append("handle %r skipped: its target is scaled to zero (or flat)"
                            % (h.vertex_group or "(no group)"))
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


def handle_problems(obj):
    """What would make a solve skip a handle, read from the settings alone (no data is written:
    safe in handlers): missing vertex group, missing target or bone, not bound yet."""
    problems = []
    for h in obj.larap.handles:
        if not h.enabled:
            continue
        reason = _skip_reason(obj, h)
        if reason:
            problems.append(reason)
            continue
        try:  # (a renamed bone is not a problem: the next pose follows it)
            object_matrix(h.target, bone_name(h), h.vertex_group)
        except LarapError as exc:
            problems.append("%s; skipped" % exc)
    return problems


def _skip_reason(obj, h, groups=None):
    """Why a solve skips the enabled handle ``h``, read from its settings (and, given ``groups``,
    the vertex groups' members: an empty group); "" when nothing there stops it. The one wording
    of these warnings, for the solve (:func:`gather`) and the panel (:func:`handle_problems`)."""
    label = h.vertex_group or "(no group)"
    if h.vertex_group not in obj.vertex_groups:
        return ("handle %r skipped: vertex group not found (renamed or deleted? pick the group "
                "again in the handle's settings)" % label)
    if groups is not None and len(groups.get(h.vertex_group, ())) == 0:
        return "handle %r skipped: vertex group is empty" % label
    if not h.has_rest:
        if not target_alive(h.target):  # (a rebind cannot record a rest for a deleted target)
            return "handle %r skipped: it has no target (deleted?); pick one in the handle's settings" % label
        return "handle %r skipped: not bound (rebind)" % label
    return ""


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


def meshes_driven_by(obj):
    """Bound meshes with a handle whose target is ``obj`` (an Empty, an armature), in name order:
    the panel and the operators pose these while a target is the active object."""
    if obj is None:
        return []
    found = []
    for ob in bound_meshes(None):
        try:
            if ob.larap.bound and any(h.target == obj for h in ob.larap.handles):
                found.append(ob)
        except ReferenceError:
            continue
    return sorted(found, key=lambda o: o.name_full)
