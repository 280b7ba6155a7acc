# SPDX-License-Identifier: GPL-3.0-or-later
"""Sidebar panel (3D View > N > LARAP) and menu entries (Object menu, Edit Mode vertex menu)."""
import bpy

from . import core, engine

OPERATORS = (
    ("larap.bind", "Bind", "MOD_LATTICE"),
    ("larap.unbind", "Unbind", "X"),
    ("larap.handle_add", "Add Handle", "ADD"),
    ("larap.handle_remove", "Remove Handle", "REMOVE"),
    ("larap.solve", "Solve", "FILE_REFRESH"),
    ("larap.pose", "Pose (Drag Handle)", "VIEW_PAN"),
    ("larap.bake_shape_key", "Bake Shape Key", "SHAPEKEY_DATA"),
    ("larap.bake_animation", "Bake Animation", "RENDER_ANIMATION"),
    ("larap.apply", "Apply Pose", "CHECKMARK"),
)


def _label_lines(layout, text, icon="ERROR", width=48):
    words, line, first = text.split(), "", True
    for w in words:
        if line and len(line) + 1 + len(w) > width:
            layout.label(text=line, icon=icon if first else "BLANK1")
            line, first = w, False
        else:
            line = (line + " " + w).strip()
    if line:
        layout.label(text=line, icon=icon if first else "BLANK1")


class LARAP_UL_handles(bpy.types.UIList):
    bl_idname = "LARAP_UL_handles"

    def draw_item(self, context, layout, data, item, icon, active_data, active_propname, index):
        obj = data.id_data
        row = layout.row(align=True)
        ok = item.vertex_group in obj.vertex_groups and core.target_alive(item.target)
        row.prop(item, "enabled", text="")
        row.label(text=item.vertex_group or "(no group)", icon="GROUP_VERTEX" if ok else "ERROR")
        row.prop(item, "target", text="")


class VIEW3D_PT_larap(bpy.types.Panel):
    bl_space_type = "VIEW_3D"
    bl_region_type = "UI"
    bl_category = "LARAP"
    bl_label = "LARAP Deform"

    def draw(self, context):
        layout = self.layout
        obj = context.object
        if engine.get() is None:
            box = layout.box()
            _label_lines(box, engine.error())
        if obj is None or obj.type != "MESH":
            layout.label(text="Select a mesh object", icon="INFO")
            return
        s = obj.larap
        rt = core.runtime(obj)
        linked = obj.library is not None or obj.data.library is not None
        if linked:
            layout.label(text="Linked data: not editable", icon="LIBRARY_DATA_DIRECT")

        box = layout.box()
        if s.bound:
            n = len(obj.data.vertices)
            if n != s.bind_vertex_count or (rt is not None and "topology" in rt.last_error):
                _label_lines(box, "Topology changed since bind (%d vertices now, %d at bind)"
                             % (n, s.bind_vertex_count))
                box.operator("larap.bind", text="Rebind", icon="FILE_REFRESH")
            box.label(text="Bound (%d vertices)" % s.bind_vertex_count, icon="CHECKMARK")
            if rt is not None and rt.deformer is not None:
                d = rt.deformer
                col = box.column(align=True)
                col.label(text="Lattice: %d nodes, %d cells (cell %.4g)" % (d.num_nodes, d.num_cells, d.cell_size))
                col.label(text="Device: %s" % d.device)
                engine_ms = rt.stats.get("ms_total") if rt.stats else None
                col.label(text="Last solve: %.1f ms%s (%s)" % (
                    rt.last_ms, (" (engine %.1f)" % engine_ms) if engine_ms is not None else "", rt.weights or "-"))
                if rt.last_error:
                    _label_lines(col, rt.last_error)
                for w in rt.warnings[:3]:
                    _label_lines(col, w, icon="INFO")
            else:
                box.label(text="Engine rebuilt at the next solve", icon="INFO")
        else:
            box.label(text="Not bound", icon="UNLINKED")

        col = layout.column(align=True)
        row = col.row(align=True)
        row.operator("larap.bind", text="Rebind" if s.bound else "Bind", icon="MOD_LATTICE")
        row.operator("larap.unbind", text="Unbind", icon="X")
        row = col.row(align=True)
        row.operator("larap.solve", icon="FILE_REFRESH")
        row.operator("larap.pose", text="Pose", icon="VIEW_PAN")
        row = col.row(align=True)
        row.operator("larap.bake_shape_key", text="Bake Key", icon="SHAPEKEY_DATA")
        row.operator("larap.bake_animation", text="Bake Anim", icon="RENDER_ANIMATION")
        col.operator("larap.apply", text="Apply Pose", icon="CHECKMARK")
        col.operator("larap.load_farm_bake", text="Load Farm Bake", icon="FILE_CACHE")
        keys = obj.data.shape_keys
        kb = keys.key_blocks.get(s.shape_key) if keys is not None else None
        if kb is not None:
            layout.prop(kb, "value", text="%s Key" % kb.name, slider=True)
        row = layout.row(align=True)
        row.prop(s, "live", toggle=True, icon="PLAY" if s.live else "PAUSE")
        row.prop(s, "show_overlay", toggle=True, icon="MOD_LATTICE")

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
                hb.label(text="Vertex group %r missing (renamed or deleted?): pick it again" % h.vertex_group,
                         icon="ERROR")
            if h.target is not None and not core.target_alive(h.target):
                hb.label(text="Target not in any scene: handle skipped", icon="ERROR")
            if not h.has_rest:
                hb.label(text="Not bound yet: rebind to use it", icon="INFO")
            op = hb.operator("larap.pose", text="Drag This Handle", icon="VIEW_PAN")
            op.handle = s.active_handle


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
        s = context.object.larap
        layout = self.layout
        layout.use_property_split = True
        layout.use_property_decorate = False
        layout.prop(s, "resolution_mode")
        layout.prop(s, "cells" if s.resolution_mode == "CELLS" else "cell_size")
        layout.prop(s, "gamma")
        layout.prop(s, "iterations")
        layout.prop(s, "weights_interactive", text="Interactive")
        layout.prop(s, "weights_final", text="Final")
        layout.prop(s, "device")
        layout.prop(s, "shape_key")
        if s.bound:
            layout.label(text="Lattice settings apply at the next solve (rebuild)", icon="INFO")


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
