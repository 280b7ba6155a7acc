# SPDX-License-Identifier: GPL-3.0-or-later
"""Operators: thin wrappers over core.py that turn LarapError into reports (the modal drag is in modal.py)."""
import traceback

import bpy
from bpy.props import BoolProperty, IntProperty, StringProperty

from . import core


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


class _LarapOp:
    bl_options = {"REGISTER", "UNDO"}

    @classmethod
    def poll(cls, context):
        # Permissive on purpose: a wrong context gets a report from execute(), not a silent no-op.
        return True

    def execute(self, context):
        obj = context.object
        try:
            return self.run(context, obj) or {"FINISHED"}
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


class LARAP_OT_bind(_LarapOp, bpy.types.Operator):
    """Build the lattice for the active mesh and bind it (rest: Basis key; current target transforms become rest)"""
    bl_idname = "larap.bind"
    bl_label = "LARAP Bind"

    def run(self, context, obj):
        _leave_edit_mode(self, context, obj)
        result = core.bind(obj)
        rt = core.runtime(obj)
        d = rt.deformer
        self.report({"INFO"}, "Bound %r: %d vertices, %d lattice nodes, %d cells on %s (%.1f ms)"
                    % (obj.name, d.num_vertices, d.num_nodes, d.num_cells, d.device, result.ms))
        _report_warnings(self, result)


class LARAP_OT_unbind(_LarapOp, bpy.types.Operator):
    """Unbind: remove the LARAP shape key and forget the lattice (handles and vertex groups are kept)"""
    bl_idname = "larap.unbind"
    bl_label = "LARAP Unbind"

    def run(self, context, obj):
        _leave_edit_mode(self, context, obj)
        core.unbind(obj)
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
        h = core.add_handle(obj, vertex_group=group, from_selection=from_selection, target=target,
                            subtarget=self.bone)
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
    """Solve once from the current target transforms (final weights) and write the LARAP shape key"""
    bl_idname = "larap.solve"
    bl_label = "LARAP Solve"

    def run(self, context, obj):
        _leave_edit_mode(self, context, obj)
        result = core.solve(obj, weights="final")
        _report_warnings(self, result)
        self.report({"INFO"}, "Solved %r: %d handle vertices, %.1f ms (%s)"
                    % (obj.name, result.handles, result.ms, result.weights))


class LARAP_OT_bake_shape_key(_LarapOp, bpy.types.Operator):
    """Store the current pose as a new shape key relative to Basis (value 0)"""
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
    """Solve every frame of a range from the animated targets and store each pose as a shape key keyed on its frame"""
    bl_idname = "larap.bake_animation"
    bl_label = "LARAP Bake Animation"

    frame_start: IntProperty(name="Start", default=-1, description="First frame (-1: scene start)")
    frame_end: IntProperty(name="End", default=-1, description="Last frame (-1: scene end)")
    step: IntProperty(name="Step", default=1, min=1)
    prefix: StringProperty(name="Prefix", default="LARAP_")
    overwrite: BoolProperty(name="Overwrite", default=False,
                            description="Replace existing shape keys of those names (otherwise it is an error)")

    def invoke(self, context, event):
        if self.frame_start < 0:
            self.frame_start = context.scene.frame_start
        if self.frame_end < 0:
            self.frame_end = context.scene.frame_end
        return context.window_manager.invoke_props_dialog(self)

    def run(self, context, obj):
        _leave_edit_mode(self, context, obj)
        scene = context.scene
        start = self.frame_start if self.frame_start >= 0 else scene.frame_start
        end = self.frame_end if self.frame_end >= 0 else scene.frame_end
        names = core.bake_animation(obj, scene, start, end, step=self.step, prefix=self.prefix,
                                    overwrite=self.overwrite)
        self.report({"INFO"}, "Baked %d frames into shape keys %s..%s (the %r key is set to 0)"
                    % (len(names), names[0] if names else "", names[-1] if names else "", obj.larap.shape_key))


class LARAP_OT_apply(_LarapOp, bpy.types.Operator):
    """Write the pose into the mesh (destructive: Basis changes, the LARAP key is removed and the mesh unbound)"""
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
    LARAP_OT_unbind,
    LARAP_OT_handle_add,
    LARAP_OT_handle_remove,
    LARAP_OT_solve,
    LARAP_OT_bake_shape_key,
    LARAP_OT_bake_animation,
    LARAP_OT_apply,
)
