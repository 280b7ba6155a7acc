# SPDX-License-Identifier: GPL-3.0-or-later
"""The operations the operators call, as plain functions (no operators, no UI): bind, unbind,
add and remove a handle, bake, apply. Scripts and tests call these directly.

Each operation that changes data runs inside :func:`transaction.preserve_on_error`, so a failure
part-way leaves the object as it was. The other rooms of the add-on (see their docstrings):
``errors`` (LarapError, checks), ``mesh_data`` (the only writer of positions and keys),
``targets`` (handle targets), ``runtime`` (the engine cache), ``transaction`` (all or nothing),
``solving`` (one solve), ``session`` (dragging a handle), ``handlers`` (live mode).

The names scripts use (``core.solve``, ``core.runtime``, ``core.PoseSession``, ...) are
re-exported here from those rooms.
"""
import bpy
import numpy as np
from mathutils import Matrix, Vector

from .errors import ENGINE_ERRORS, LarapError, TopologyChanged, check_object, engine_errors
from .handlers import live_suspended, live_update, suspend_live
from .mesh_data import (apply_offsets, ensure_pose_key, key_positions, remove_pose_key, rest_positions,
                        selected_vertices, topology_hash, polygons, vertex_group_weights, write_key, write_pose)
from .runtime import (_RUNTIMES, Runtime, after_undo, build_runtime, drop_runtime, ensure_runtime,
                      prune_runtimes, resolve_device, runtime)
from .session import PoseSession, handle_points
from .solving import FINAL_TOLERANCE, SolveResult, current_pose, solve
from .targets import (flat, gather, handle_local_transform, membership, record_rest, target_alive,
                      target_matrix, target_names, target_signature)
from .transaction import preserve_on_error

__all__ = [
    # this module's operations
    "bind", "unbind", "add_handle", "remove_handle", "bake_shape_key", "bake_animation", "apply_pose",
    "HANDLE_GROUP_PREFIX", "TARGET_PREFIX",
    # re-exported from the rooms below, for scripts and tests that use ``core.<name>``
    "ENGINE_ERRORS", "LarapError", "TopologyChanged", "check_object", "engine_errors",
    "live_suspended", "live_update", "suspend_live",
    "ensure_pose_key", "key_positions", "rest_positions", "selected_vertices", "topology_hash", "polygons",
    "vertex_group_weights", "write_pose",
    "_RUNTIMES", "Runtime", "after_undo", "drop_runtime", "ensure_runtime", "prune_runtimes",
    "resolve_device", "runtime",
    "PoseSession", "handle_points",
    "FINAL_TOLERANCE", "SolveResult", "current_pose", "solve",
    "gather", "handle_local_transform", "membership", "record_rest", "target_alive", "target_matrix",
    "target_names", "target_signature",
    "preserve_on_error",
]

HANDLE_GROUP_PREFIX = "LARAP_handle_"
TARGET_PREFIX = "LARAP_target_"


# ----------------------------------------------------------------------------------------------
# Operations


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
    rt = build_runtime(obj)
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
