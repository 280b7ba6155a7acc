# SPDX-License-Identifier: GPL-3.0-or-later
"""Interactive posing: pick a handle and drag it (the modal operator in modal.py drives a
:class:`PoseSession`; tests drive it directly).

A session moves the handle's target about the handle's current centre and solves once per step
with the interactive weights (the target matrix passed as an override, so the solve does not wait
for the depsgraph; Live leaves a mesh being dragged alone, see :func:`dragging`). With the
preview (preview.py) a step poses only the lattice and the preview draws it; without it, the
pose key is written. Confirm evaluates the moved target and writes the final pose of it (one
pose per set of targets, as Live's catch-up would; when that solve fails, confirm restores as
cancel does and re-raises); cancel restores the pose key, the target's
transform and what the pose key was recorded as (and removes a copy of hand edits of the pose key
that a step made: key_edits.py), bit-exactly, and the engine's lattice as it was
when the drag began (when the engine held the shown pose; else it starts from rest, and the
overlay shows the rest lattice, labelled); nothing solves again. While a drag runs, neither Live
nor the catch-up (catchup.py) writes its mesh.
:func:`handle_points` gives the handle vertices in the pose shown (the preview's while it shows the
mesh), for picking and the overlay.
"""
import bpy
import numpy as np
from mathutils import Matrix, Vector

from . import catchup, key_edits, preview
from .errors import LarapError, check_object
from .mesh_data import key_positions, remove_keys, restore_pose_key
from .runtime import ensure_runtime, runtime
from .solving import set_stored_signature, solve, stored_signature
from .targets import flat, follow_bone_renames, membership, target_alive, target_matrix, target_signature

_DRAGGING = set()  # runtime ids of meshes with an active PoseSession


def dragging(obj):
    """A PoseSession drags a handle of ``obj`` (Live leaves it to the drag)."""
    try:
        return obj.larap.runtime_id in _DRAGGING
    except ReferenceError:
        return False


def _evaluate_targets():
    """Evaluate the scene with Live held off, so the targets' matrices read back as the
    depsgraph computes them (the pose is then recorded for the targets as they will stay)."""
    from .handlers import suspend_live
    with suspend_live():
        bpy.context.view_layer.update()


def handle_points(obj, refresh=True):
    """(world positions (k,3), handle index per point) of the handle vertices in the current pose.
    ``refresh=False`` (draw callbacks, hover): use the cached vertex-group membership, never touch
    data. Cached in the runtime per pose (``rt.pose_version``), handle groups and object matrix, so
    hovering reads the pose key once, not at each mouse move; the arrays are read-only."""
    rt = runtime(obj)
    s = obj.larap
    if rt is None or rt.rest is None:
        return np.zeros((0, 3)), np.zeros(0, dtype=np.int64)
    groups = membership(obj, rt) if refresh else rt.membership
    key = (rt.pose_version, rt.membership_hash, s.shape_key, tuple(flat(obj.matrix_world)),
           tuple((h.vertex_group, h.enabled) for h in s.handles), preview.showing(obj))
    cached = rt.handle_points
    if cached is not None and cached[0] == key:
        return cached[1], cached[2]
    pts, owner = _handle_points(obj, rt, groups)
    pts.setflags(write=False)
    owner.setflags(write=False)
    rt.handle_points = (key, pts, owner)
    return pts, owner


def _handle_points(obj, rt, groups):
    """Handle vertices where they are shown: where the preview draws them while it shows the
    object (the pose key is behind then), else in the pose key (else at rest)."""
    s = obj.larap
    ids, owner = [], []
    for i, h in enumerate(s.handles):
        idx = groups.get(h.vertex_group)
        if idx is None or len(idx) == 0 or not h.enabled:
            continue
        ids.append(idx)
        owner.append(np.full(len(idx), i, dtype=np.int64))
    if not ids:
        return np.zeros((0, 3)), np.zeros(0, dtype=np.int64)
    ids = np.concatenate(ids)
    if preview.showing(obj) and rt.lattice_nodes is not None and rt.deformer is not None:
        p = _lattice_points(rt, ids)
    else:
        posed = key_positions(obj, s.shape_key)
        p = (posed if posed is not None else rt.rest)[ids].astype(np.float64)
    mw = np.array(obj.matrix_world)
    return p @ mw[:3, :3].T + mw[:3, 3], np.concatenate(owner)


def _lattice_points(rt, ids):
    """Local positions (k,3) of the vertices ``ids`` as the preview draws them from
    ``rt.lattice_nodes``: the rest position plus the trilinear blend of the displacements of the
    8 corners of the vertex's cell (corner c's bits are its x, y, z sides), as in the shader. The
    binding of ``ids`` is kept in ``rt.handle_binding`` while the engine and ``ids`` stay."""
    d = rt.deformer
    b = rt.handle_binding
    if b is None or b[0] is not d or not np.array_equal(b[1], ids):
        cid, frac = d.trilinear_binding()
        cid = np.asarray(cid)[ids].astype(np.int64)
        frac = np.asarray(frac, dtype=np.float64)[ids]
        corners = np.asarray(d.cell_nodes(), dtype=np.int64).reshape(-1, 8)[cid]
        w = np.ones((len(ids), 8))
        for c in range(8):
            for axis in range(3):
                w[:, c] *= frac[:, axis] if (c >> axis) & 1 else 1.0 - frac[:, axis]
        b = rt.handle_binding = (d, ids.copy(), corners, w, np.asarray(d.lattice_rest(), dtype=np.float64))
    _, _, corners, w, rest_nodes = b
    disp = np.asarray(rt.lattice_nodes, dtype=np.float64) - rest_nodes
    return rt.rest[ids].astype(np.float64) + np.einsum("kc,kcx->kx", w, disp[corners])


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

    begin() snapshots the pose key, the target's transform and the engine's lattice state; update()
    solves with the interactive weights and writes only the pose key; confirm() re-solves with the
    final weights; cancel() restores the snapshot bit-exactly and the lattice state.
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
        follow_bone_renames(obj)
        h = self.handle
        if not target_alive(h.target):
            raise LarapError("Handle %r has no target" % h.vertex_group)
        self.target = h.target
        self.bone = h.subtarget
        if self.bone and (self.target.type != "ARMATURE" or self.bone not in self.target.pose.bones):
            raise LarapError("Bone %r not found in %r" % (self.bone, self.target.name))
        rt = ensure_runtime(obj, "full")
        catchup.catch_up(obj)  # start from the mesh holding what is shown
        rt = ensure_runtime(obj, "fast")
        # The engine's lattice of the shown pose, when it holds it: a cancel puts it back, so the
        # overlay keeps showing the pose's lattice and the next solve starts where this one did.
        self.engine, self.lattice_state = rt.deformer, None
        if rt.lattice_current and rt.deformer is not None:
            try:
                self.lattice_state = rt.deformer.lattice_state()
            except Exception:  # then a cancel starts the engine from rest, as without it
                self.lattice_state = None
        self.stored = stored_signature(obj)
        self.key_record = key_edits.get(obj)
        self.kept = []  # keys made during the drag to keep hand edits of the pose key (cancel removes them)
        self.wrote = False
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
        # What begin wrote or tagged (the catch-up, a read of the vertex groups) evaluated now and
        # the faces' shading read at the click, if at all (preview.face_shading): the drag's
        # steps see no mesh change and read nothing per face.
        _evaluate_targets()
        preview.blocker(obj)
        self.key = obj.larap.runtime_id
        _DRAGGING.add(self.key)
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
        _evaluate_targets()  # targets parented under the dragged one (bones, Empties) follow it now
        overrides = {self.overrides_key: world}
        obj = self.obj
        if weights == "interactive" and not preview.blocker(obj):
            self.last = solve(obj, weights=weights, validate="fast", overrides=overrides, lattice_only=True)
            if self.last.handles == 0:  # the rest pose was written: nothing to draw instead
                self.wrote = True
                if self.last.kept:
                    self.kept.append(self.last.kept)
                return self.last
            if preview.show(obj):
                return self.last
        self.wrote = True
        self.last = solve(obj, weights=weights, validate="fast", overrides=overrides)
        if self.last.kept:
            self.kept.append(self.last.kept)
        return self.last

    def _end(self):
        _DRAGGING.discard(self.key)
        self.active = False
        self.engine = self.lattice_state = None  # an operator that lives on keeps no engine alive

    def confirm(self):
        """Write the final pose of the targets where the drag left them (evaluated first, so
        Live and the recorded signature see the same matrices: nothing solves again later)."""
        if not self.active:
            return self.last
        try:
            _evaluate_targets()
            self.last = solve(self.obj, weights="final", validate="fast")
        except BaseException:
            self._restore()  # a failed confirm is a cancel (the session is inactive afterwards)
            raise
        finally:
            self._end()
        return self.last

    def cancel(self):
        """Bit-exact restore of the pose key, the target and the pose key's record, and the engine's
        lattice when begin() took it; the preview ends and nothing solves (Live sees the targets
        it last saw)."""
        if not self.active:
            return
        try:
            self._restore()
        finally:
            self._end()

    def _restore(self):
        """What cancel undoes (the session still active)."""
        obj = self.obj
        _transform_restore(self.target, self.bone, self.transform)
        if self.wrote:
            restore_pose_key(obj, self.snapshot)
            remove_keys(obj, self.kept)  # the hand edits are back in the pose key
        set_stored_signature(obj, self.stored)
        key_edits.put(obj, self.key_record)
        preview.stop(obj)
        _evaluate_targets()
        rt = runtime(obj)
        if rt is not None:
            rt.needs_catchup = False
            rt.lattice_nodes = None
            rt.lattice_current = False
            rt.pose_version += 1
            rt.target_sig = target_signature(obj)
            if rt.deformer is not None:
                if not self._put_lattice_back(rt):
                    rt.deformer.reset()

    def _put_lattice_back(self, rt):
        """The engine's lattice as it was at begin(), if it was the shown pose's then and the
        engine is the same one; False (nothing changed) otherwise or if the engine refuses it."""
        if self.lattice_state is None or rt.deformer is not self.engine:
            return False
        try:
            rt.deformer.set_lattice_state(self.lattice_state)
        except Exception:
            return False
        rt.lattice_current = True
        return True
