# SPDX-License-Identifier: GPL-3.0-or-later
"""Operators: thin wrappers over core.py that turn LarapError into reports (the modal drag is in modal.py).

Every label is "LARAP <what it does>" (F3 and the undo history read that); the panel and menus
show the same words without the prefix. Long operations (Bind, Bake Animation) show Blender's
progress indicator and report the whole operation's time.
"""
import traceback

import bpy
import numpy as np
from bpy.props import BoolProperty, IntProperty, StringProperty

from . import core, key_edits
from .progress import Progress


def _mesh_for(context, name=""):
    return core.mesh_for(context, name)


def _windowed(context):
    """A window with an event loop (not background mode): a long operation can run as a modal."""
    return getattr(context, "window", None) is not None and not bpy.app.background


def _seconds(ms):
    return "%.2f s" % (ms / 1e3) if ms >= 1000.0 else "%.0f ms" % ms


def _leave_edit_mode(op, context, obj):
    """Solving needs Object Mode (edit-mode changes are written back on exit and would clobber keys)."""
    if obj is not None and getattr(obj, "type", None) == "MESH" and obj.mode == "EDIT":
        if context.view_layer.objects.active != obj:
            raise core.LarapError("%r is in Edit Mode; switch to Object Mode first" % obj.name)
        bpy.ops.object.mode_set(mode="OBJECT")
        op.report({"INFO"}, "Switched %r to Object Mode" % obj.name)


def _report_warnings(op, result):
    for w in getattr(result, "warnings", ()) or ():
        op.report({"WARNING"}, w)
        getattr(op, "_reported", set()).add(w)


def _report_kept_edits(op):
    """Copies of hand edits of a pose key made during the operator (key_edits.py), once each."""
    reported = getattr(op, "_reported", set())
    for m in key_edits.take_messages():
        if m not in reported:
            op.report({"WARNING"}, m)


class _LarapOp:
    bl_options = {"REGISTER", "UNDO"}

    @classmethod
    def poll(cls, context):
        # Permissive on purpose: a wrong context gets a report from execute(), not a silent no-op.
        return True

    def execute(self, context):
        obj = context.object
        key_edits.take_messages()  # (copies made before this operator were told elsewhere)
        self._reported = set()
        try:
            result = self.run(context, obj) or {"FINISHED"}
            _report_kept_edits(self)
            return result
        except core.LarapError as exc:
            self.report({"ERROR"}, str(exc))
            return {"CANCELLED"}
        except Exception as exc:  # a bug: still a report, with the traceback on the console
            traceback.print_exc()
            self.report({"ERROR"}, "LARAP internal error (%s: %s); details on the console"
                        % (type(exc).__name__, exc))
            return {"CANCELLED"}

    def run(self, context, obj):  # pragma: no cover - overridden
        raise NotImplementedError


LARGE_LATTICE = 100_000  # cells above which Bind from the panel asks first


def estimated_cells(obj):
    """Lattice cells the object's settings ask for: Cells as set; with Cell Size, the cells of
    the grid around the mesh's box (an upper bound: cells outside the mesh are not kept)."""
    s = obj.larap
    if s.resolution_mode == "CELLS":
        return int(s.cells)
    if s.resolution_mode == "SIZE":
        box = np.array(obj.bound_box)  # 8 corners, object space
        per_axis = np.minimum(np.ptp(box, axis=0) / float(s.cell_size), 1e7).astype(np.int64) + 1
        return int(min(np.prod(per_axis, dtype=np.float64), 2**31 - 1))
    return 0  # Auto: about 6,000


class LARAP_OT_bind(_LarapOp, bpy.types.Operator):
    """Build the lattice that carries the mesh (from its rest shape, the Basis key). Rebinding after an edit keeps the current pose"""
    bl_idname = "larap.bind"
    bl_label = "LARAP Bind"

    keep_pose: BoolProperty(name="Keep Pose", default=True,
                            description="When already bound: the targets keep posing the mesh (off: their current "
                            "places become the rest and the mesh returns to its rest shape)")
    estimate: IntProperty(options={"HIDDEN", "SKIP_SAVE"})  # lattice cells, when the dialog asks

    def invoke(self, context, event):
        """From the panel: a lattice large enough to take minutes is bound only once confirmed
        (binding cannot be interrupted; a 160,000-cell lattice took 73 s on a 2-core machine and
        each pose 4 s, a finer one did not end in 5 minutes)."""
        obj = context.object
        self.estimate = estimated_cells(obj) if obj is not None and obj.type == "MESH" else 0
        if self.estimate > LARGE_LATTICE:
            return context.window_manager.invoke_props_dialog(self, width=460)
        return self.execute(context)

    def draw(self, context):
        col = self.layout.column()
        if self.estimate > LARGE_LATTICE:
            col.label(text="Up to %s lattice cells: binding may take minutes, and cannot" % format(self.estimate, ","),
                      icon="ERROR")
            col.label(text="be interrupted; every pose will be slow. Fewer Cells or a larger")
            col.label(text="Cell Size bind in seconds. Bind anyway?")
        if context.object is not None and context.object.type == "MESH" and context.object.larap.bound:
            col.prop(self, "keep_pose")

    def run(self, context, obj):
        _leave_edit_mode(self, context, obj)
        was_bound = obj is not None and obj.type == "MESH" and obj.larap.bound
        p = Progress(context.window_manager)
        result = core.bind(obj, keep_pose=self.keep_pose, progress=p)
        rt = core.runtime(obj)
        d = rt.deformer
        self.report({"INFO"}, "%s %r in %s: %d vertices, lattice of %d cells (%d nodes) on %s%s"
                    % ("Rebound" if was_bound else "Bound", obj.name, _seconds(p.ms), d.num_vertices,
                       d.num_cells, d.num_nodes, d.device, ", pose kept" if was_bound and self.keep_pose else ""))
        _report_warnings(self, result)


class LARAP_OT_back_to_rest(_LarapOp, bpy.types.Operator):
    """Move every handle's target back to where it was at bind: the mesh returns to its rest shape and the Empties go back with it"""
    bl_idname = "larap.back_to_rest"
    bl_label = "LARAP Back to Rest"

    def run(self, context, obj):
        obj = _mesh_for(context)
        _leave_edit_mode(self, context, obj)
        result = core.back_to_rest(obj)
        _report_warnings(self, result)
        self.report({"INFO"}, "%r is back at rest (its targets moved back)" % obj.name)


class LARAP_OT_unbind(_LarapOp, bpy.types.Operator):
    """Remove the LARAP shape key and forget the lattice (handles, vertex groups and targets are kept)"""
    bl_idname = "larap.unbind"
    bl_label = "LARAP Unbind"

    def run(self, context, obj):
        core.check_object(obj, allow_edit_mode=True)
        if not obj.larap.bound:  # nothing to undo either: no step in the undo history
            self.report({"INFO"}, "%r is not bound" % obj.name)
            return {"CANCELLED"}
        _leave_edit_mode(self, context, obj)
        core.unbind(obj)  # (a copy of hand edits of its pose key is reported by execute)
        self.report({"INFO"}, "Unbound %r" % obj.name)


class LARAP_OT_handle_add(_LarapOp, bpy.types.Operator):
    """Add a handle: the selected vertices (Edit Mode; creates vertex group LARAP_handle_N) or a vertex group, following a target (an Empty is created when none is given)"""
    bl_idname = "larap.handle_add"
    bl_label = "LARAP Add Handle"

    vertex_group: StringProperty(name="Vertex Group",
                                 description="Existing vertex group (empty: selection in Edit Mode, else the active group)")
    target: StringProperty(name="Target", description="Object that drives the handle (empty: create an Empty)")
    bone: StringProperty(name="Bone", description="Bone of an armature target")

    def run(self, context, obj):
        core.check_object(obj, allow_edit_mode=True)
        target = None
        if self.target:
            target = bpy.data.objects.get(self.target)
            if target is None:
                raise core.LarapError("No object named %r" % self.target)
        group = self.vertex_group
        from_selection = False
        if not group:
            if obj.mode == "EDIT":
                from_selection = True
            elif obj.vertex_groups.active is not None:
                group = obj.vertex_groups.active.name
            else:
                raise core.LarapError("Select vertices in Edit Mode or give a vertex group")
        rv3d = getattr(context, "region_data", None)
        h = core.add_handle(obj, vertex_group=group, from_selection=from_selection, target=target,
                            subtarget=self.bone, view_distance=getattr(rv3d, "view_distance", None))
        self.report({"INFO"}, "Handle %r -> %s" % (h.vertex_group, h.target.name if h.target else "?"))


class LARAP_OT_handle_remove(_LarapOp, bpy.types.Operator):
    """Remove a handle (by default keeps its vertex group and target)"""
    bl_idname = "larap.handle_remove"
    bl_label = "LARAP Remove Handle"

    index: IntProperty(name="Index", default=-1, description="Handle index (-1: the active one)")
    delete_target: BoolProperty(name="Delete Target", default=False,
                                description="Also delete the Empty that LARAP created for it")
    delete_group: BoolProperty(name="Delete Vertex Group", default=False)

    def run(self, context, obj):
        core.check_object(obj, allow_edit_mode=True)
        index = self.index if self.index >= 0 else obj.larap.active_handle
        core.remove_handle(obj, index, delete_target=self.delete_target, delete_group=self.delete_group)


class LARAP_OT_solve(_LarapOp, bpy.types.Operator):
    """Pose the mesh once from where its handles' targets are now (the final, smooth result)"""
    bl_idname = "larap.solve"
    bl_label = "LARAP Solve"

    mesh: StringProperty(name="Mesh", options={"HIDDEN", "SKIP_SAVE"},
                         description="Mesh to pose (empty: the active mesh, or the one the active target drives)")

    def run(self, context, obj):
        obj = _mesh_for(context, self.mesh)
        _leave_edit_mode(self, context, obj)
        result = core.solve(obj, weights="final")
        _report_warnings(self, result)
        hidden = " (the LARAP key is off while the baked animation plays: Remove Bake to see it)" \
            if core.pose_key_hidden(obj) else ""
        self.report({"INFO"}, "Posed %r in %s: %d handle vertices%s"
                    % (obj.name, _seconds(result.ms), result.handles, hidden))


class LARAP_OT_bake_shape_key(_LarapOp, bpy.types.Operator):
    """Store the current pose as a new shape key (relative to Basis, value 0)"""
    bl_idname = "larap.bake_shape_key"
    bl_label = "LARAP Bake Shape Key"

    name: StringProperty(name="Name", default="LARAP_pose")
    overwrite: BoolProperty(name="Overwrite", default=False,
                            description="Replace an existing shape key of that name (otherwise it is an error)")

    def invoke(self, context, event):
        return context.window_manager.invoke_props_dialog(self)

    def run(self, context, obj):
        _leave_edit_mode(self, context, obj)
        kb = core.bake_shape_key(obj, self.name, overwrite=self.overwrite)
        self.report({"INFO"}, "Baked pose into shape key %r" % kb.name)


class LARAP_OT_bake_animation(_LarapOp, bpy.types.Operator):
    """Pose every frame of a range from the animated targets and store each pose as a shape key keyed on its frame (Esc cancels). Afterwards the baked keys play; Live is paused and the LARAP key hidden until Remove Bake"""
    bl_idname = "larap.bake_animation"
    bl_label = "LARAP Bake Animation"
    _timer = None

    frame_start: IntProperty(name="Start", default=-1, description="First frame (-1: scene start)")
    frame_end: IntProperty(name="End", default=-1, description="Last frame (-1: scene end)")
    step: IntProperty(name="Step", default=1, min=1)
    prefix: StringProperty(name="Prefix", default="LARAP_")
    overwrite: BoolProperty(name="Overwrite", default=False,
                            description="Replace existing shape keys of those names (otherwise it is an error)")
    interactive: BoolProperty(default=False, options={"HIDDEN", "SKIP_SAVE"})

    def invoke(self, context, event):
        if self.frame_start < 0:
            self.frame_start = context.scene.frame_start
        if self.frame_end < 0:
            self.frame_end = context.scene.frame_end
        self.interactive = True  # after the dialog: bake frame by frame in a modal, Esc cancels
        return context.window_manager.invoke_props_dialog(self)

    def run(self, context, obj):
        _leave_edit_mode(self, context, obj)
        scene = context.scene
        start = self.frame_start if self.frame_start >= 0 else scene.frame_start
        end = self.frame_end if self.frame_end >= 0 else scene.frame_end
        self.p = Progress(context.window_manager)
        if self.interactive and _windowed(context):
            self.job = core.AnimationBake(obj, scene, start, end, step=self.step, prefix=self.prefix,
                                          overwrite=self.overwrite)
            self.p.begin(len(self.job.frames))
            self.job.begin()
            self._timer = context.window_manager.event_timer_add(0.001, window=context.window)
            context.window_manager.modal_handler_add(self)
            context.workspace.status_text_set("LARAP Bake Animation: %d frames | Esc cancel" % len(self.job.frames))
            return {"RUNNING_MODAL"}
        names = core.bake_animation(obj, scene, start, end, step=self.step, prefix=self.prefix,
                                    overwrite=self.overwrite, progress=self.p)
        self._report_done(obj, names)

    def _report_done(self, obj, names):
        self.report({"INFO"}, "Baked %d frames in %s into shape keys %s..%s; they play now (Live paused, the %r key "
                    "hidden; Remove Bake to pose again)" % (len(names), _seconds(self.p.ms), names[0] if names else "",
                                                             names[-1] if names else "", obj.larap.shape_key))

    def _stop(self, context):
        if self._timer is not None:
            context.window_manager.event_timer_remove(self._timer)
            self._timer = None
        self.p.end()
        if getattr(context, "workspace", None) is not None:
            context.workspace.status_text_set(None)

    def modal(self, context, event):
        if event.type == "ESC" and event.value == "PRESS":
            self.job.cancel()
            self._stop(context)
            self.report({"WARNING"}, "Bake cancelled after %d of %d frames; nothing was changed"
                        % (self.job.done, len(self.job.frames)))
            return {"CANCELLED"}
        if event.type != "TIMER" or event.timer is not self._timer:
            return {"RUNNING_MODAL"}  # blocking: the bake owns the UI until it ends
        try:
            finished = self.job.step()
            self.p.step(self.job.done)
            if not finished:
                return {"RUNNING_MODAL"}
            names = self.job.finish()
        except core.LarapError as exc:
            self._stop(context)
            self.report({"ERROR"}, str(exc))
            return {"CANCELLED"}
        except Exception as exc:
            traceback.print_exc()
            self._stop(context)
            self.report({"ERROR"}, "LARAP internal error (%s: %s); details on the console" % (type(exc).__name__, exc))
            return {"CANCELLED"}
        self._stop(context)
        self._report_done(self.job.obj, names)
        return {"FINISHED"}

    def cancel(self, context):  # Blender ends the modal (file load, window closed): put everything back
        if getattr(self, "job", None) is not None:
            self.job.cancel()
        self._stop(context)


class LARAP_OT_remove_bake(_LarapOp, bpy.types.Operator):
    """Remove the shape keys Bake Animation made and their animation, show the LARAP key again and resume Live (one undo step)"""
    bl_idname = "larap.remove_bake"
    bl_label = "LARAP Remove Bake"

    def run(self, context, obj):
        obj = _mesh_for(context)
        _leave_edit_mode(self, context, obj)
        core.check_object(obj)
        live = obj.larap.bake_paused_live
        n = core.remove_bake(obj)
        self.report({"INFO"}, "Removed %d baked shape keys and their animation from %r%s"
                    % (n, obj.name, "; Live resumed" if live else ""))


class LARAP_OT_apply(_LarapOp, bpy.types.Operator):
    """Make the pose the mesh's shape (destructive: Basis changes, the LARAP key is removed and the mesh unbound)"""
    bl_idname = "larap.apply"
    bl_label = "LARAP Apply Pose"

    def invoke(self, context, event):
        # Destructive (Basis changes): always ask. Only a script calling it with EXEC skips this.
        return context.window_manager.invoke_confirm(self, event)

    def run(self, context, obj):
        _leave_edit_mode(self, context, obj)
        core.apply_pose(obj)
        self.report({"INFO"}, "Applied the pose to %r (unbound)" % obj.name)


classes = (
    LARAP_OT_bind,
    LARAP_OT_back_to_rest,
    LARAP_OT_unbind,
    LARAP_OT_handle_add,
    LARAP_OT_handle_remove,
    LARAP_OT_solve,
    LARAP_OT_bake_shape_key,
    LARAP_OT_bake_animation,
    LARAP_OT_remove_bake,
    LARAP_OT_apply,
)
