# SPDX-License-Identifier: GPL-3.0-or-later
"""Interactive posing: pick a handle and drag it (the modal operator in modal.py drives a
:class:`PoseSession`; tests drive it directly).

A session moves the handle's target about the handle's current centre, solves with the
interactive weights at each step (the target matrix passed as an override, so the solve does not
wait for the depsgraph), solves with the final weights on confirm, and on cancel restores the
pose key and the target's transform bit-exactly. :func:`handle_points` gives the handle vertices
in the current pose, for picking and for the overlay.
"""
import numpy as np
from mathutils import Matrix, Vector

from .errors import LarapError, check_object
from .mesh_data import key_positions, restore_pose_key
from .runtime import ensure_runtime, runtime
from .solving import solve
from .targets import membership, target_alive, target_matrix


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
