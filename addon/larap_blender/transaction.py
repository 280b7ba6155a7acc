# SPDX-License-Identifier: GPL-3.0-or-later
"""All or nothing: an operation that fails part-way leaves the object as it was.

:func:`preserve_on_error` snapshots what an operation may change (the mesh positions, every shape
key with its settings and key animation, the LARAP settings, the pose key's records in the object,
the handles' rest matrices and bones, and the runtime) and restores it if the block raises, then
re-raises. Bind, Bake and Apply run inside it.
"""
import contextlib

from .key_edits import RECORD_PROP
from .mesh_data import block_positions, mesh_positions, read_only, set_mesh_positions, write_block
from .props import id_string, set_id_string
from .runtime import restore_entry, snapshot_entry
from .solving import POSE_SIGNATURE_PROP
from .targets import quiet_retarget

_SETTING_FIELDS = ("bound", "bind_vertex_count", "bind_topology", "created_basis", "owned_key_name",
                   "shape_key", "runtime_id")
# The object's ID properties that describe the pose key: what it was solved for, what LARAP wrote.
_ID_PROPS = (POSE_SIGNATURE_PROP, RECORD_PROP)
_KEY_FIELDS = ("slider_max", "slider_min", "value", "mute", "vertex_group", "interpolation")
# Keyframe points of the shape keys' f-curves (their "co" is (frame, value), not a vertex position).
_POINT_VECTORS = ("co", "handle_left", "handle_right")
_POINT_FIELDS = _POINT_VECTORS + ("interpolation", "handle_left_type", "handle_right_type")


def _snapshot(obj):
    me = obj.data
    s = obj.larap
    # The positions are read only: the operation reads them too (the rest shape, the pose key).
    snap = {"mesh": read_only(mesh_positions(me)),
            "settings": {f: getattr(s, f) for f in _SETTING_FIELDS},
            "handles": [(tuple(h.rest_matrix), h.has_rest, h.rest_target, h.rest_subtarget, h.subtarget,
                         tuple(h.bone_rest), h.has_bone_rest, h.bone_rest_armature) for h in s.handles],
            "active_shape_key_index": obj.active_shape_key_index,
            "show_only_shape_key": obj.show_only_shape_key,
            "id_props": {p: id_string(obj, p) for p in _ID_PROPS},
            "keys": None, "anim": None}
    snap["runtime"] = snapshot_entry(obj)
    snap["rest"] = snap["mesh"]  # what mesh_data.rest_positions reads: the mesh, or the Basis key
    keys = me.shape_keys
    if keys is not None:
        n = len(me.vertices)
        snap["use_relative"] = keys.use_relative
        snap["keys"] = [(kb.name, read_only(block_positions(kb, n)),
                         kb.relative_key.name if kb.relative_key else "",
                         {f: getattr(kb, f) for f in _KEY_FIELDS}) for kb in keys.key_blocks]
        for kb, entry in zip(keys.key_blocks, snap["keys"]):
            if kb == keys.reference_key:
                snap["rest"] = entry[1]
        ad = keys.animation_data
        if ad is not None and ad.action is not None:
            snap["anim"] = (ad.action, {(fc.data_path, fc.array_index): [
                {f: (tuple(getattr(kp, f)) if f in _POINT_VECTORS else getattr(kp, f))
                 for f in _POINT_FIELDS} for kp in fc.keyframe_points] for fc in ad.action.fcurves})
    return snap


def key_positions(snap, name):
    """The positions of the shape key ``name`` as the snapshot read them (read only), or None when
    the object had no such key (as ``mesh_data.key_positions`` then)."""
    for key_name, co, _rel, _props in snap["keys"] or ():
        if key_name == name:
            return co
    return None


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
    for p, v in snap["id_props"].items():
        set_id_string(obj, p, v)
    for h, entry in zip(s.handles, snap["handles"]):
        m, has, rest_target, rest_subtarget, bone, bone_rest, has_bone, bone_arm = entry
        h.rest_matrix = m
        h.has_rest = has
        h.rest_target, h.rest_subtarget = rest_target, rest_subtarget
        with quiet_retarget():  # (a renamed bone followed part-way: put back, not a retarget)
            h.subtarget = bone
        h.bone_rest, h.has_bone_rest, h.bone_rest_armature = bone_rest, has_bone, bone_arm
    restore_entry(obj, snap["runtime"])
    me.update()


@contextlib.contextmanager
def preserve_on_error(obj):
    """Snapshot the mesh positions, every shape key (data, settings, key animation), the LARAP
    settings and the runtime; restore them if the block raises (then re-raise). Yields the
    snapshot, whose ``"rest"`` is the rest positions as read now (``mesh_data.rest_positions``;
    shared with the snapshot: read only, as every position it holds; :func:`key_positions` gives
    a key's)."""
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
