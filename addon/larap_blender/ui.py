# SPDX-License-Identifier: GPL-3.0-or-later
"""Sidebar panel (3D View > N > LARAP) and menu entries (Object menu, Edit Mode vertex menu).

The panel is there while the artist works: with the mesh active it shows everything; with a
handle's target (an Empty, an armature) active it shows what posing needs (the bound mesh's name,
Live, Lattice, Solve, Pose) for each mesh that target drives. Every text fits Blender's default
sidebar width (220 px at UI scale 1): buttons share a row two at most, long messages are wrapped
to the region's real width.
"""
import bpy

from . import core, engine

# (operator, text, icon): the menu shows each operator under its label without "LARAP ".
OPERATORS = (
    ("larap.bind", "Bind", "MOD_LATTICE"),
    ("larap.unbind", "Unbind", "X"),
    ("larap.handle_add", "Add Handle", "ADD"),
    ("larap.handle_remove", "Remove Handle", "REMOVE"),
    ("larap.solve", "Solve", "FILE_REFRESH"),
    ("larap.pose", "Pose", "VIEW_PAN"),
    ("larap.back_to_rest", "Back to Rest", "LOOP_BACK"),
    ("larap.bake_shape_key", "Bake Shape Key", "SHAPEKEY_DATA"),
    ("larap.bake_animation", "Bake Animation", "RENDER_ANIMATION"),
    ("larap.remove_bake", "Remove Bake", "TRASH"),
    ("larap.apply", "Apply Pose", "CHECKMARK"),
)
TEXT = {idname: (text, icon) for idname, text, icon in OPERATORS}

# Blender's default sidebar width at UI scale 1, and what a panel leaves for its content.
SIDEBAR_WIDTH = 220
CONTENT_WIDTH = SIDEBAR_WIDTH - 36  # panel margins, a box's border
UI_FONT_SIZE = 11  # Blender's widget font, points at 72 dpi


def text_width(text, size=UI_FONT_SIZE):
    """Width in pixels (UI scale 1) of ``text`` in Blender's UI font; a character estimate
    (7 px) where blf cannot measure."""
    try:
        import blf
        blf.size(0, size)
        return blf.dimensions(0, text)[0]
    except Exception:
        return 7.0 * len(text)


def _content_width(context):
    region = getattr(context, "region", None)
    width = getattr(region, "width", 0) or 0
    scale = getattr(getattr(context, "preferences", None), "system", None)
    scale = getattr(scale, "ui_scale", 1.0) or 1.0
    if width > 40:
        return max((width / scale) - 36, 80)
    return CONTENT_WIDTH


def _label_lines(layout, text, icon="ERROR", width=None, context=None):
    """A message wrapped to the panel's width (measured), first line with ``icon``."""
    avail = (width or _content_width(context or bpy.context)) - 48  # icon, padding, a box's border
    words, line, first = text.split(), "", True
    for w in words:
        cand = (line + " " + w).strip()
        if line and text_width(cand) > avail:
            layout.label(text=line, icon=icon if first else "BLANK1")
            line, first = w, False
        else:
            line = cand
    if line:
        layout.label(text=line, icon=icon if first else "BLANK1")


def _op(layout, idname, text=None, **props):
    label, icon = TEXT[idname]
    op = layout.operator(idname, text=text or label, icon=icon)
    for k, v in props.items():
        setattr(op, k, v)
    return op


def _pose_toggles(layout, s):
    row = layout.row(align=True)
    row.prop(s, "live", text="Live", toggle=True, icon="PLAY" if s.live else "PAUSE")
    row.prop(s, "show_overlay", text="Lattice", toggle=True, icon="MOD_LATTICE")
    row.prop(s, "overlay_xray", text="", toggle=True, icon="XRAY")


def _bake_state(layout, obj, context=None):
    """What Bake Animation left: the baked keys play, Live is paused, the pose key is hidden."""
    s = obj.larap
    box = layout.box()
    col = box.column(align=True)
    first, last = s.bake_keys[0].name, s.bake_keys[len(s.bake_keys) - 1].name
    col.label(text="Baked: %d keys" % len(s.bake_keys), icon="RENDER_ANIMATION")
    col.label(text="from %s" % first, icon="BLANK1")
    col.label(text="to %s" % last, icon="BLANK1")
    _label_lines(col, "The baked keys play the animation; the %s key is hidden%s." % (
        s.shape_key, " and Live paused" if not s.live else ""), icon="INFO", context=context)
    _op(box, "larap.remove_bake")


def _pose_key(layout, obj, context=None):
    keys = obj.data.shape_keys
    kb = keys.key_blocks.get(obj.larap.shape_key) if keys is not None else None
    if kb is None:
        return
    if core.is_baked(obj):
        _bake_state(layout, obj, context)
    else:
        layout.prop(kb, "value", text="%s Key" % kb.name, slider=True)


def _preview_row(layout, obj):
    """The GPU preview toggle, and what is drawn instead of it when it cannot be used."""
    from . import preview
    s = obj.larap
    row = layout.row(align=True)
    row.prop(s, "preview", toggle=True, icon="SHADING_SOLID")
    reason = preview.blocker(obj) if s.preview and s.bound else ""
    if reason and reason != "background mode":
        _label_lines(layout, "Preview off (%s): posing writes the mesh" % reason, icon="INFO")


class LARAP_UL_handles(bpy.types.UIList):
    bl_idname = "LARAP_UL_handles"

    def draw_item(self, context, layout, data, item, icon, active_data, active_propname, index):
        obj = data.id_data
        row = layout.row(align=True)
        ok = item.vertex_group in obj.vertex_groups and core.target_alive(item.target)
        row.prop(item, "enabled", text="")
        row.label(text=item.vertex_group or "(no group)", icon="GROUP_VERTEX" if ok else "ERROR")
        row.prop(item, "target", text="")


def _status_box(layout, obj, context):
    s = obj.larap
    rt = core.runtime(obj)
    box = layout.box()
    if not s.bound:
        box.label(text="Not bound", icon="UNLINKED")
        return
    n = len(obj.data.vertices)
    if n != s.bind_vertex_count or (rt is not None and "topology" in rt.last_error):
        _label_lines(box, "The mesh changed since bind (%d vertices now, %d then): Rebind keeps the pose"
                     % (n, s.bind_vertex_count), context=context)
        _op(box, "larap.bind", text="Rebind")
    box.label(text="Bound: %d vertices" % s.bind_vertex_count, icon="CHECKMARK")
    if rt is not None and rt.deformer is not None:
        d = rt.deformer
        col = box.column(align=True)
        col.label(text="%d cells of %.3g m" % (d.num_cells, d.cell_size), icon="MOD_LATTICE")
        col.label(text="Last pose: %.0f ms on %s" % (rt.last_ms, d.device.upper()), icon="TIME")
        if rt.last_error:
            _label_lines(col, rt.last_error, context=context)
        for w in rt.warnings[:3]:
            _label_lines(col, w, icon="INFO", context=context)
        keys = obj.data.shape_keys
        if rt.kept_edits and keys is not None and rt.kept_edits in keys.key_blocks \
                and not any(rt.kept_edits in w for w in rt.warnings[:3]):
            _label_lines(col, "Hand edits of the pose key are kept in %r (value 0)" % rt.kept_edits,
                         icon="SHAPEKEY_DATA", context=context)
    else:
        box.label(text="Lattice rebuilt at the next pose", icon="INFO")


def _draw_mesh(layout, context, obj):
    s = obj.larap
    linked = obj.library is not None or obj.data.library is not None
    if linked:
        layout.label(text="Linked data: not editable", icon="LIBRARY_DATA_DIRECT")
    _status_box(layout, obj, context)

    col = layout.column(align=True)
    row = col.row(align=True)
    _op(row, "larap.bind", text="Rebind" if s.bound else "Bind")
    _op(row, "larap.unbind")
    row = col.row(align=True)
    _op(row, "larap.solve")
    _op(row, "larap.pose")
    _pose_toggles(layout, s)
    _preview_row(layout, obj)
    _pose_key(layout, obj, context)
    col = layout.column(align=True)
    _op(col, "larap.back_to_rest")
    _op(col, "larap.bake_shape_key")
    _op(col, "larap.bake_animation")
    col.operator("larap.load_farm_bake", text="Load Farm Bake", icon="FILE_CACHE")
    _op(col, "larap.apply")

    layout.label(text="Handles")
    row = layout.row()
    row.template_list("LARAP_UL_handles", "", s, "handles", s, "active_handle", rows=3)
    sub = row.column(align=True)
    sub.operator("larap.handle_add", text="", icon="ADD")
    sub.operator("larap.handle_remove", text="", icon="REMOVE")
    if 0 <= s.active_handle < len(s.handles):
        h = s.handles[s.active_handle]
        hb = layout.box().column(align=True)
        hb.prop_search(h, "vertex_group", obj, "vertex_groups", text="Group")
        hb.prop(h, "target")
        if h.target is not None and h.target.type == "ARMATURE":
            hb.prop_search(h, "subtarget", h.target.data, "bones", text="Bone")
        hb.prop(h, "weight")
        if h.vertex_group and h.vertex_group not in obj.vertex_groups:
            _label_lines(hb, "Vertex group %r missing (renamed or deleted?): pick it again" % h.vertex_group,
                         context=context)
        if h.target is not None and not core.target_alive(h.target):
            _label_lines(hb, "Target not in any scene: handle skipped", context=context)
        if not h.has_rest and s.bound:
            _label_lines(hb, "Not bound yet: Rebind to use it", icon="INFO", context=context)
        _op(hb, "larap.pose", text="Drag This Handle", handle=s.active_handle)


def _draw_target(layout, context, target, meshes):
    """A handle's target is active: what posing needs, for each mesh it drives."""
    for obj in meshes:
        s = obj.larap
        box = layout.box()
        box.label(text=obj.name, icon="MESH_DATA")
        handles = [h.vertex_group for h in s.handles if h.target == target]
        if handles:
            box.label(text="Moves %s" % ", ".join(handles[:2]) + (" ..." if len(handles) > 2 else ""),
                      icon="GROUP_VERTEX")
        _pose_toggles(box, s)
        row = box.row(align=True)
        _op(row, "larap.solve", mesh=obj.name)
        _op(row, "larap.pose", mesh=obj.name)
        if core.is_baked(obj):
            _label_lines(box, "Baked animation plays: select %s to remove the bake" % obj.name, icon="INFO",
                         context=context)


class VIEW3D_PT_larap(bpy.types.Panel):
    bl_space_type = "VIEW_3D"
    bl_region_type = "UI"
    bl_category = "LARAP"
    bl_label = "LARAP"

    def draw(self, context):
        layout = self.layout
        obj = context.object
        if engine.get() is None:
            box = layout.box()
            _label_lines(box, engine.error(), context=context)
        if obj is not None and obj.type == "MESH":
            _draw_mesh(layout, context, obj)
            return
        meshes = core.posed_meshes(context)
        if meshes:
            _draw_target(layout, context, obj, meshes)
            return
        layout.label(text="Select a mesh object", icon="INFO")
        layout.label(text="or a handle's target", icon="BLANK1")


class VIEW3D_PT_larap_settings(bpy.types.Panel):
    bl_space_type = "VIEW_3D"
    bl_region_type = "UI"
    bl_category = "LARAP"
    bl_label = "Settings"
    bl_parent_id = "VIEW3D_PT_larap"
    bl_options = {"DEFAULT_CLOSED"}

    @classmethod
    def poll(cls, context):
        return context.object is not None and context.object.type == "MESH"

    def draw(self, context):
        obj = context.object
        s = obj.larap
        layout = self.layout
        layout.use_property_split = True
        layout.use_property_decorate = False
        layout.prop(s, "resolution_mode")
        if s.resolution_mode == "CELLS":
            layout.prop(s, "cells")
        elif s.resolution_mode == "SIZE":
            layout.prop(s, "cell_size")
        else:  # Auto: the real cell, once there is a lattice
            rt = core.runtime(obj)
            row = layout.row()
            row.enabled = False
            if rt is not None and rt.deformer is not None:
                row.label(text="%.3g m" % rt.deformer.cell_size)
            else:
                row.label(text="set at bind")
        layout.prop(s, "split_cells")
        layout.prop(s, "gamma")
        layout.prop(s, "iterations")
        layout.prop(s, "weights_interactive")
        layout.prop(s, "weights_final")
        layout.prop(s, "device")
        layout.prop(s, "shape_key")
        if s.bound:
            _label_lines(layout, "Resolution and device apply at the next pose (the lattice is rebuilt)",
                         icon="INFO", context=context)


class VIEW3D_MT_larap(bpy.types.Menu):
    bl_label = "LARAP"
    bl_idname = "VIEW3D_MT_larap"

    def draw(self, context):
        layout = self.layout
        for idname, text, icon in OPERATORS:
            layout.operator(idname, text=text, icon=icon)


def _object_menu(self, context):
    self.layout.separator()
    self.layout.menu(VIEW3D_MT_larap.bl_idname, icon="MOD_LATTICE")


def _edit_menu(self, context):
    self.layout.separator()
    self.layout.operator("larap.handle_add", text="LARAP: Add Handle from Selection", icon="ADD")


classes = (LARAP_UL_handles, VIEW3D_PT_larap, VIEW3D_PT_larap_settings, VIEW3D_MT_larap)


def register_menus():
    bpy.types.VIEW3D_MT_object.append(_object_menu)
    bpy.types.VIEW3D_MT_edit_mesh.append(_object_menu)
    bpy.types.VIEW3D_MT_edit_mesh_vertices.append(_edit_menu)


def unregister_menus():
    bpy.types.VIEW3D_MT_edit_mesh_vertices.remove(_edit_menu)
    bpy.types.VIEW3D_MT_edit_mesh.remove(_object_menu)
    bpy.types.VIEW3D_MT_object.remove(_object_menu)
