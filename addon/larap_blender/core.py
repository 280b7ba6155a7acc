# SPDX-License-Identifier: GPL-3.0-or-later
"""The operations the operators call, as plain functions (no operators, no UI): bind, unbind,
back to rest, add and remove a handle, apply. Scripts and tests call these directly.

Each operation that changes data runs inside :func:`transaction.preserve_on_error`, so a failure
part-way leaves the object as it was. The other rooms of the add-on (see their docstrings):
``errors`` (LarapError, checks), ``mesh_data`` (the only writer of positions and keys),
``targets`` (handle targets), ``runtime`` (the engine cache), ``transaction`` (all or nothing),
``solving`` (one solve), ``session`` (dragging a handle), ``handlers`` (live mode), ``bake``
(shape keys from poses, and the bake's aftermath).

The names scripts use (``core.solve``, ``core.runtime``, ``core.PoseSession``,
``core.bake_animation``, ...) are re-exported here from those rooms.
"""
import bpy
import numpy as np
from mathutils import Matrix, Vector

from . import key_edits, preview
from .bake import (AnimationBake, LarapCancelled, bake_animation, bake_shape_key, is_baked, pose_key_hidden,
                   remove_bake)
from .errors import ENGINE_ERRORS, LarapError, TopologyChanged, bound_sharing, check_object, engine_errors
from .handlers import live_suspended, live_update, suspend_live
from .mesh_data import (apply_offsets, ensure_pose_key, key_positions, remove_pose_key, rest_positions,
                        selected_vertices, topology_hash, polygons, vertex_group_weights, write_pose)
from .props import upgrade_settings
from .runtime import (_RUNTIMES, Runtime, after_undo, build_runtime, drop_runtime, ensure_runtime,
                      prune_runtimes, resolve_device, runtime)
from .session import PoseSession, handle_points
from .solving import FINAL_TOLERANCE, SolveResult, current_pose, solve
from .progress import Progress, progress as _progress
from .targets import (flat, follow_bone_renames, gather, handle_local_transform, meshes_driven_by, membership,
                      quiet_retarget, record_rest, retarget_keep_pose, target_alive, target_matrix,
                      target_names, target_signature)
from .transaction import key_positions as snapshot_key, preserve_on_error

__all__ = [
    # this module's operations
    "bind", "unbind", "add_handle", "remove_handle", "apply_pose", "back_to_rest", "posed_meshes", "mesh_for",
    "HANDLE_GROUP_PREFIX", "TARGET_PREFIX", "Progress",
    # re-exported from the rooms below, for scripts and tests that use ``core.<name>``
    "bake_shape_key", "bake_animation", "AnimationBake", "LarapCancelled", "is_baked", "pose_key_hidden",
    "remove_bake",
    "ENGINE_ERRORS", "LarapError", "TopologyChanged", "check_object", "engine_errors",
    "live_suspended", "live_update", "suspend_live",
    "ensure_pose_key", "key_positions", "rest_positions", "selected_vertices", "topology_hash", "polygons",
    "vertex_group_weights", "write_pose",
    "_RUNTIMES", "Runtime", "after_undo", "drop_runtime", "ensure_runtime", "prune_runtimes",
    "resolve_device", "runtime",
    "PoseSession", "handle_points",
    "FINAL_TOLERANCE", "SolveResult", "current_pose", "solve",
    "gather", "handle_local_transform", "meshes_driven_by", "membership", "record_rest",
    "retarget_keep_pose", "target_alive", "target_matrix", "target_names", "target_signature",
    "preserve_on_error",
]

HANDLE_GROUP_PREFIX = "LARAP_handle_"
TARGET_PREFIX = "LARAP_target_"


# ----------------------------------------------------------------------------------------------
# Operations


def bind(obj, *, keep_pose=True, progress=None):
    """Build the lattice + binding from the rest positions and write the pose key.

    First bind: the targets' current transforms are their rest (the mesh shows its rest shape).
    Rebind (already bound) with ``keep_pose``: the rest stays the rest, so the targets keep posing
    the mesh and the Empties stay with their vertices; a handle without a rest yet gets one where
    its vertices are now. ``keep_pose=False``: the current transforms become the rest (the mesh
    returns to its rest shape, the targets stay where they are). ``progress``: a Progress.
    A failure leaves the object as it was (mesh, keys, settings, previous binding)."""
    check_object(obj, bind=True)
    p = _progress(progress, 3)
    with p, preserve_on_error(obj) as snap:
        return _bind(obj, keep_pose, p, snap)


def _bind(obj, keep_pose, p, snap):
    """Bind from the positions the caller's snapshot ``snap`` read (the rest shape, the keys),
    nothing changed since: none of them is read again."""
    s = obj.larap
    me = obj.data
    rebind = s.bound and keep_pose
    p.step(0)
    rt = build_runtime(obj, snap["rest"])  # the long part: the lattice and its factorisation
    p.step(1)
    # Stored explicitly (an unset property is not saved): a later default leaves this bind alone.
    s.gamma = upgrade_settings(s)
    s.bind_vertex_count = len(me.vertices)
    s.bind_topology = rt.topology
    for h in s.handles:
        if not target_alive(h.target):
            h.has_rest = False
            continue
        try:
            if rebind and h.has_rest:
                if h.rest_target is None:  # bound before rest targets were recorded: it is this target's
                    h.rest_target, h.rest_subtarget = h.target, h.subtarget
            elif rebind:  # (the fit to the pose key, pose_fit, reads neither the rest nor the key)
                ids = membership(obj, rt, rt.rest).get(h.vertex_group)
                if not retarget_keep_pose(obj, h, ids, rt.rest, snapshot_key(snap, s.shape_key)):
                    h.has_rest = False
            else:
                record_rest(h)
        except LarapError:
            h.has_rest = False
    had_keys = me.shape_keys is not None
    _, created = ensure_pose_key(obj, s)
    if created and not had_keys:
        s.created_basis = True
    s.bound = True
    p.step(2)
    # The handle groups, read with the rest shape build_runtime read (the Basis made since is a copy
    # of it): the solve finds them read. Its fast validation passes no rest to them, which would
    # then read the Basis again.
    membership(obj, rt, rt.rest)
    # The pose key as the snapshot read it (None when bind has just made it), and the rest shape
    # (rt.rest: a Basis made since is a copy of it): the check for hand edits before the solve
    # writes the key reads neither again.
    kb = key_edits.pose_key(obj)
    result = solve(obj, weights="final", validate="fast", posed=snapshot_key(snap, kb.name) if kb else None,
                   rest=rt.rest)
    p.step(3)
    return result


def back_to_rest(obj):
    """Move every handle's target back to its rest (where it was at bind) and solve: the mesh
    returns to its rest shape and the Empties go back with their vertices. Bones are posed back
    the same way. Animated targets return to their animation at the next frame change."""
    check_object(obj, need_bound=True)
    from mathutils import Matrix as _M
    moved = set()
    warnings = ["handle's bone %r was renamed %r: the handle follows it" % pair for pair in follow_bone_renames(obj)]
    for h in obj.larap.handles:
        if not h.has_rest or not target_alive(h.target):
            continue
        rest = _M([h.rest_matrix[0:4], h.rest_matrix[4:8], h.rest_matrix[8:12], h.rest_matrix[12:16]])
        key = (h.target.name_full, h.subtarget)
        if key in moved:
            warnings.append("%s is the target of several handles; it went to the first one's rest" % key[0])
            continue
        try:
            target_matrix(h)
        except LarapError as exc:
            warnings.append(str(exc))
            continue
        if h.subtarget:
            h.target.pose.bones[h.subtarget].matrix = h.target.matrix_world.inverted_safe() @ rest
        else:
            h.target.matrix_world = rest
        moved.add(key)
    bpy.context.view_layer.update()
    result = solve(obj, weights="final", validate="full")
    result.warnings = warnings + list(result.warnings)
    return result


def mesh_for(context, name=""):
    """The mesh an operator acts on: the object named ``name`` (the panel names it), else the
    active mesh, else the one bound mesh the active target (Empty, armature) drives."""
    if name:
        obj = bpy.data.objects.get(name)
        if obj is None:
            raise LarapError("No object named %r" % name)
        return obj
    obj = getattr(context, "object", None)
    if obj is not None and obj.type != "MESH":
        meshes = posed_meshes(context)
        if len(meshes) == 1:
            return meshes[0]
        if len(meshes) > 1:
            raise LarapError("%r drives several meshes (%s); select the one to use"
                             % (obj.name, ", ".join(m.name for m in meshes)))
    return obj


def posed_meshes(context):
    """The bound meshes the 3D View's tools act on: the active mesh, or, while a handle's target
    (an Empty, an armature) is active, the bound meshes it drives."""
    obj = getattr(context, "object", None)
    if obj is None:
        return []
    try:
        if obj.type == "MESH":
            return [obj]
    except ReferenceError:
        return []
    return meshes_driven_by(obj)


def unbind(obj):
    """Remove what bind made (the pose key LARAP created; the Basis if bind created it and no other
    key is left) and forget the engine. Handles, their vertex groups and targets, other shape keys,
    modifiers and every other object are kept. Hand edits of the pose key are kept in a key of
    their own (key_edits.py), whose name is returned (else None)."""
    check_object(obj)
    preview.stop(obj)
    kept = None
    s = obj.larap
    if bound_sharing(obj):  # the key is also the pose of another bound user of this mesh: it stays
        s.owned_key_name = ""  # and is that user's to remove
        s.created_basis = False
    else:
        kept = key_edits.keep(obj)
        remove_pose_key(obj)
    key_edits.put(obj, "")
    s.bound = False
    drop_runtime(obj)
    return kept


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


def empty_size(points, mesh_size, view_distance=None):
    """Display size (radius, in the mesh's local units) of a handle's Empty for a group of
    ``points`` (k,3 local): about a third of the part's middle extent (for a flat cap, its width;
    for two feet, a foot's length, not the span between them), at least a readable size in the view
    (2% of ``view_distance``, local units), and never more than half the part."""
    ext = np.sort(points.max(axis=0) - points.min(axis=0)) if len(points) > 1 else np.zeros(3)
    part = float(ext[1])
    seen = 0.02 * view_distance if view_distance else 0.02 * 2.0 * mesh_size
    if part <= 0.0:
        return max(min(seen, 0.05 * mesh_size), 1e-4)
    return max(min(max(0.35 * part, seen), 0.5 * part), 1e-4)


def add_handle(obj, *, vertex_group="", from_selection=False, target=None, subtarget="", collection=None,
               view_distance=None):
    """Add a handle group. ``from_selection``: new vertex group LARAP_handle_N from the selected vertices.
    Without a target, an Empty is created at the group's centre (placed on the current pose when
    the mesh is posed, so adding a handle does not make the mesh jump), sized by
    :func:`empty_size` (``view_distance``: the 3D View's, in world units, when there is one)."""
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
    mesh_pts = rest_positions(obj)  # read once: the group's weights, its rest and the mesh's size
    idx = np.flatnonzero(vertex_group_weights(obj, [vertex_group], mesh_pts)[vertex_group] > 0.0)
    if len(idx) == 0:
        raise LarapError("Vertex group %r has no vertices" % vertex_group)
    if target is not None:
        if target == obj:
            raise LarapError("A mesh cannot be its own handle target")
        if subtarget and (target.type != "ARMATURE" or subtarget not in target.pose.bones):
            raise LarapError("Bone %r not found in %r" % (subtarget, target.name))
    rest = mesh_pts[idx].astype(np.float64)
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
        scale = max(mw.to_scale().length / 3 ** 0.5, 1e-9)
        mesh_size = float(np.linalg.norm(mesh_pts.max(axis=0) - mesh_pts.min(axis=0))) if len(mesh_pts) else 1.0
        radius = empty_size(rest, max(mesh_size, 1e-3), view_distance / scale if view_distance else None)
        name = TARGET_PREFIX + (vertex_group[len(HANDLE_GROUP_PREFIX):] if vertex_group.startswith(HANDLE_GROUP_PREFIX)
                                else vertex_group)
        empty = bpy.data.objects.new(name, None)
        empty.empty_display_type = "SPHERE"
        empty.empty_display_size = radius  # the Empty's matrix carries the mesh's scale
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
    with quiet_retarget():
        h.target = target
        h.subtarget = subtarget
    if rest_matrix is not None:
        h.rest_matrix = flat(rest_matrix)
        h.has_rest = True
        h.rest_target, h.rest_subtarget = target, ""
    elif s.bound:
        retarget_keep_pose(obj, h, idx, mesh_pts)  # a posed mesh does not jump: the target takes over
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


def apply_pose(obj):
    """Write the current pose (see current_pose) into the mesh (Basis and every other key move
    along, keeping their offsets), remove the pose key and unbind. Destructive: the operator asks
    first. A failure leaves the object as it was."""
    check_object(obj, need_bound=True)
    with preserve_on_error(obj) as snap:
        return _apply_pose(obj, snap)


def _apply_pose(obj, snap):
    """Apply from the positions the caller's snapshot ``snap`` read, nothing written since but
    what this writes: current_pose and its solve take its pose key and rest shape, the move of the
    keys its keys (a copy of hand edits made meanwhile is read), and the removal of a Basis bind
    created takes the moved Basis as written."""
    s = obj.larap
    pose = current_pose(obj, snapshot_key(snap, s.shape_key), snap["rest"])
    rt = runtime(obj)
    me = obj.data
    # rt.rest: the rest shape as it still is (current_pose), which the Basis is moved from. The
    # other keys are as the snapshot read them: since, the solve wrote the pose key only (skipped).
    known = {name: co for name, co, _rel, _props in snap["keys"] or ()}
    moved = apply_offsets(obj, pose, rt.rest, skip=s.shape_key, known=known)
    remove_pose_key(obj, basis=moved)  # the Basis as apply_offsets wrote it
    key_edits.put(obj, "")
    for h in s.handles:
        h.has_rest = False
    s.bound = False
    drop_runtime(obj)
    me.update()
    return pose.copy()  # (the snapshot's own array when the key was up to date: read only)
