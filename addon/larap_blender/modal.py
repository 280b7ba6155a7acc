# SPDX-License-Identifier: GPL-3.0-or-later
"""The modal operator ``larap.pose``: drag a handle in the 3D View.

Only the event handling lives here (pick, G/R/S, axis locks, typed values, confirm/cancel); the
posing itself is a :class:`session.PoseSession`, which tests drive without a 3D View.
"""
import math

import bpy
import numpy as np
from bpy.props import IntProperty, StringProperty
from mathutils import Quaternion, Vector

from . import overlay
from .core import mesh_for
from .errors import LarapError, check_object
from .runtime import ensure_runtime
from .session import PoseSession, handle_points

PICK_PROMPT = "LARAP Pose: click a handle (its vertices are shown, the one under the cursor is highlighted) | RMB/Esc cancel"
PICK_MISS = "LARAP Pose: no handle under the cursor; click on or near a highlighted handle vertex | RMB/Esc cancel"
PICK_RADIUS = 75.0  # pixels from a handle vertex that still grab it


_AXES = {"X": Vector((1, 0, 0)), "Y": Vector((0, 1, 0)), "Z": Vector((0, 0, 1))}
_NUM_KEYS = {
    **{k: str(i) for i, k in enumerate(("ZERO", "ONE", "TWO", "THREE", "FOUR", "FIVE", "SIX", "SEVEN", "EIGHT", "NINE"))},
    **{"NUMPAD_%d" % i: str(i) for i in range(10)},
    "PERIOD": ".", "NUMPAD_PERIOD": ".", "MINUS": "-", "NUMPAD_MINUS": "-",
}


def _project(region, rv3d, points):
    """Screen coordinates (k,2) of world points (k,3); rows behind the eye are inf."""
    m = np.array(rv3d.perspective_matrix, dtype=np.float64)
    h = np.c_[points, np.ones(len(points))] @ m.T
    w = h[:, 3:4]
    ok = w[:, 0] > 1e-9
    out = np.full((len(points), 2), np.inf)
    ndc = h[ok, :2] / w[ok]
    out[ok] = (ndc * 0.5 + 0.5) * np.array([region.width, region.height])
    return out


def _status(context, text):
    """The status bar's text (None: Blender's own); nothing where there is no workspace."""
    ws = getattr(context, "workspace", None)
    if ws is not None:
        ws.status_text_set(text)


def _leave_edit_mode(context, obj):
    """Pose, like Bind and Solve, takes the mesh out of Edit Mode (edits are kept)."""
    if obj is not None and getattr(obj, "type", None) == "MESH" and obj.mode == "EDIT":
        if context.view_layer.objects.active != obj:
            raise LarapError("%r is in Edit Mode; switch to Object Mode first" % obj.name)
        bpy.ops.object.mode_set(mode="OBJECT")


def _hover(op, context, mouse):
    """Waiting for a click: highlight the handle under the cursor."""
    hovered = op._pick(context, mouse, quiet=True)
    if overlay.picking(op.obj) != hovered:
        overlay.set_picking(op.obj, hovered)
        context.area.tag_redraw()
    return hovered


def _end_picking(op, context):
    overlay.clear_picking(getattr(op, "obj", None))
    _status(context, None)


class LARAP_OT_pose(bpy.types.Operator):
    """Drag a handle in the 3D View (click near a handle vertex); G/R/S move/rotate/scale, X/Y/Z lock axis, Shift precision, type a value, LMB/Enter confirm, RMB/Esc cancel"""
    bl_idname = "larap.pose"
    bl_label = "LARAP Pose"
    bl_options = {"UNDO", "BLOCKING"}

    handle: IntProperty(name="Handle", default=-1, description="Handle to drag (-1: click one)")
    mesh: StringProperty(name="Mesh", options={"HIDDEN", "SKIP_SAVE"},
                         description="Mesh to pose (empty: the active mesh, or the one the active target drives)")

    def invoke(self, context, event):
        try:
            obj = mesh_for(context, getattr(self, "mesh", ""))
            _leave_edit_mode(context, obj)
            check_object(obj, need_bound=True)
            if context.area is None or context.area.type != "VIEW_3D" or context.region_data is None:
                raise LarapError("Pose needs a 3D View (hover it and use F3)")
            ensure_runtime(obj, "full")
        except LarapError as exc:
            self.report({"ERROR"}, str(exc))
            return {"CANCELLED"}
        self.obj = obj
        self.session = None
        self.mode = "MOVE"
        self.axis = None  # None | ("AXIS", "X") | ("PLANE", "X")
        self.numeric = ""
        self.confirm_on_release = False
        self.mouse = Vector((event.mouse_region_x, event.mouse_region_y))
        if self.handle >= 0:
            if not self._start(context, self.handle, self.mouse):
                return {"CANCELLED"}
        else:
            self.state = "PICK"
            if len(handle_points(obj)[0]) == 0:
                self.report({"ERROR"}, "No handles with vertices and targets to grab")
                return {"CANCELLED"}
            context.area.header_text_set(PICK_PROMPT)
            _status(context, PICK_PROMPT)
            overlay.set_picking(obj, None)
            _hover(self, context, self.mouse)
        context.window_manager.modal_handler_add(self)
        return {"RUNNING_MODAL"}

    def execute(self, context):
        self.report({"ERROR"}, "LARAP Pose is interactive: run it from a 3D View")
        return {"CANCELLED"}

    # -- helpers
    def _start(self, context, handle, mouse):
        try:
            self.session = PoseSession(self.obj, handle).begin()
        except LarapError as exc:
            self.report({"ERROR"}, str(exc))
            return False
        self.state = "DRAG"
        self.start_mouse = mouse.copy()
        self.eff_mouse = mouse.copy()
        self.prev_mouse = mouse.copy()
        self._update(context)
        return True

    def _pick(self, context, mouse, quiet=False):
        pts, owner = handle_points(self.obj, refresh=not quiet)
        if len(pts) == 0:
            if not quiet:
                self.report({"ERROR"}, "No handles with vertices and targets to grab")
            return None
        # Projected once per pose and view (pts is the same array while the pose is): hovering
        # costs one distance per handle vertex, nothing read from the mesh.
        view = (tuple(map(tuple, context.region_data.perspective_matrix)), context.region.width, context.region.height)
        cached = getattr(self, "_screen", None)
        if cached is None or cached[0] is not pts or cached[1] != view:
            self._screen = cached = (pts, view, _project(context.region, context.region_data, pts))
        scr = cached[2]
        dist = np.linalg.norm(scr - np.array(mouse), axis=1)
        i = int(np.argmin(dist))
        if not np.isfinite(dist[i]) or dist[i] > PICK_RADIUS:
            return None
        return int(owner[i])

    def _pivot_2d(self, context):
        from bpy_extras.view3d_utils import location_3d_to_region_2d
        p = location_3d_to_region_2d(context.region, context.region_data, self.session.pivot)
        return p if p is not None else Vector((context.region.width / 2, context.region.height / 2))

    def _numeric_value(self):
        try:
            return float(self.numeric) if self.numeric not in ("", "-", ".", "-.") else None
        except ValueError:
            return None

    def _axis_vec(self):
        return _AXES[self.axis[1]] if self.axis else None

    def _compute(self, context):
        from bpy_extras.view3d_utils import region_2d_to_location_3d
        region, rv3d = context.region, context.region_data
        value = self._numeric_value()
        pivot = self.session.pivot
        view_axis = (rv3d.view_rotation @ Vector((0.0, 0.0, -1.0))).normalized()
        if self.mode == "MOVE":
            if value is not None:
                axis = self._axis_vec() if self.axis and self.axis[0] == "AXIS" else Vector((1, 0, 0))
                return dict(translation=axis * value), "(%.4f)" % value
            a = region_2d_to_location_3d(region, rv3d, self.start_mouse, pivot)
            b = region_2d_to_location_3d(region, rv3d, self.eff_mouse, pivot)
            t = b - a
            if self.axis:
                ax = self._axis_vec()
                t = ax * t.dot(ax) if self.axis[0] == "AXIS" else t - ax * t.dot(ax)
            return dict(translation=t), "(%.4f, %.4f, %.4f)" % tuple(t)
        if self.mode == "ROTATE":
            axis = self._axis_vec() if self.axis else view_axis
            if value is not None:
                angle = math.radians(value)
            else:
                c = self._pivot_2d(context)
                v0, v1 = self.start_mouse - c, self.eff_mouse - c
                angle = math.atan2(v0.x * v1.y - v0.y * v1.x, v0.dot(v1)) if v0.length and v1.length else 0.0
                if self.axis and axis.dot(view_axis) > 0:
                    angle = -angle
                elif not self.axis:
                    angle = -angle
            return dict(rotation=Quaternion(axis, angle)), "%.2f\u00b0" % math.degrees(angle)
        # SCALE
        if value is not None:
            f = value
        else:
            c = self._pivot_2d(context)
            d0 = (self.start_mouse - c).length
            f = (self.eff_mouse - c).length / d0 if d0 > 1e-6 else 1.0
        if self.axis and self.axis[0] == "AXIS":
            s = [1.0, 1.0, 1.0]
            s["XYZ".index(self.axis[1])] = f
        elif self.axis:
            s = [f, f, f]
            s["XYZ".index(self.axis[1])] = 1.0
        else:
            s = [f, f, f]
        return dict(scale=s), "(%.4f, %.4f, %.4f)" % tuple(s)

    def _update(self, context):
        kwargs, text = self._compute(context)
        try:
            result = self.session.update(**kwargs)
        except LarapError as exc:
            self.report({"ERROR"}, str(exc))
            return False
        axis = ("" if not self.axis else (" along %s" % self.axis[1] if self.axis[0] == "AXIS"
                                          else " not %s" % self.axis[1]))
        num = (" [%s]" % self.numeric) if self.numeric else ""
        context.area.header_text_set(
            "LARAP %s%s %s%s | %.1f ms | G/R/S mode, X/Y/Z axis (Shift: plane), Shift precision, "
            "type a value, LMB/Enter confirm, RMB/Esc cancel" % (self.mode.title(), axis, text, num, result.ms))
        return True

    def _finish(self, context, ok):
        context.area.header_text_set(None)
        _end_picking(self, context)
        if self.session is not None and self.session.active:
            try:
                if ok:
                    result = self.session.confirm()
                    self.report({"INFO"}, "Posed %r (%.1f ms)" % (self.obj.name, result.ms))
                else:
                    self.session.cancel()
            except LarapError as exc:
                self.session.cancel()
                self.report({"ERROR"}, str(exc))
                ok = False
        context.area.tag_redraw()
        return {"FINISHED"} if ok else {"CANCELLED"}

    # -- events
    def modal(self, context, event):
        context.area.tag_redraw()
        mouse = Vector((event.mouse_region_x, event.mouse_region_y))
        if event.type in {"RIGHTMOUSE", "ESC"} and event.value == "PRESS":
            return self._finish(context, False)
        if self.state == "PICK":
            if event.type == "MOUSEMOVE":
                _hover(self, context, mouse)
            if event.type == "LEFTMOUSE" and event.value == "PRESS":
                handle = self._pick(context, mouse)
                if handle is None:
                    context.area.header_text_set(PICK_MISS)
                    _status(context, PICK_MISS)
                    return {"RUNNING_MODAL"}
                _end_picking(self, context)
                self.confirm_on_release = True
                if not self._start(context, handle, mouse):
                    return self._finish(context, False)
                return {"RUNNING_MODAL"}
            return {"PASS_THROUGH"} if event.type in {"MIDDLEMOUSE", "WHEELUPMOUSE", "WHEELDOWNMOUSE",
                                                       "TRACKPADPAN", "TRACKPADZOOM"} else {"RUNNING_MODAL"}
        # DRAG
        changed = False
        if event.type == "MOUSEMOVE":
            delta = mouse - self.prev_mouse
            self.eff_mouse += delta * (0.1 if event.shift else 1.0)
            self.prev_mouse = mouse
            changed = not self.numeric
        elif event.type == "LEFTMOUSE":
            if event.value == "RELEASE" and self.confirm_on_release:
                return self._finish(context, True)
            if event.value == "PRESS" and not self.confirm_on_release:
                return self._finish(context, True)
        elif event.type in {"RET", "NUMPAD_ENTER", "SPACE"} and event.value == "PRESS":
            return self._finish(context, True)
        elif event.value == "PRESS" and event.type in {"G", "R", "S"}:
            self.mode = {"G": "MOVE", "R": "ROTATE", "S": "SCALE"}[event.type]
            self.start_mouse = self.eff_mouse.copy()
            self.numeric = ""
            changed = True
        elif event.value == "PRESS" and event.type in {"X", "Y", "Z"}:
            kind = "PLANE" if event.shift else "AXIS"
            self.axis = None if self.axis == (kind, event.type) else (kind, event.type)
            changed = True
        elif event.value == "PRESS" and event.type in _NUM_KEYS:
            ch = _NUM_KEYS[event.type]
            if ch == "-":
                self.numeric = self.numeric[1:] if self.numeric.startswith("-") else "-" + self.numeric
            elif not (ch == "." and "." in self.numeric):
                self.numeric += ch
            changed = True
        elif event.value == "PRESS" and event.type == "BACK_SPACE":
            self.numeric = self.numeric[:-1]
            changed = True
        if changed and not self._update(context):
            return self._finish(context, False)
        return {"RUNNING_MODAL"}

    def cancel(self, context):
        # Blender aborts the modal (e.g. file load): restore.
        if getattr(self, "session", None) is not None and self.session.active:
            self.session.cancel()
        _end_picking(self, context)
        if context.area is not None:
            context.area.header_text_set(None)


classes = (LARAP_OT_pose,)
