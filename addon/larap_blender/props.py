# SPDX-License-Identifier: GPL-3.0-or-later
"""Settings stored in the .blend (``Object.larap``) and the add-on preferences."""
import bpy
from bpy.props import (BoolProperty, CollectionProperty, EnumProperty, FloatProperty,
                       FloatVectorProperty, IntProperty, PointerProperty, StringProperty)

WEIGHT_ITEMS = [
    ("trilinear", "Trilinear", "Trilinear interpolation of the lattice nodes (fast, C0 across cells)"),
    ("bspline", "B-Spline", "Quadratic B-spline interpolation over 27 nodes (C1 across cells, a bit slower)"),
]
DEVICE_ITEMS = [
    ("DEFAULT", "Default", "Use the device set in the add-on preferences"),
    ("cpu", "CPU", "Solve on the CPU"),
    ("cuda", "CUDA", "Solve on an NVIDIA GPU"),
    ("auto", "Auto", "CUDA when available, else CPU"),
]
PREF_DEVICE_ITEMS = [item for item in DEVICE_ITEMS if item[0] != "DEFAULT"]


def _redraw(self, context):
    # Settings that only matter at the next solve: just redraw the UI.
    screen = getattr(context, "screen", None)
    if screen is not None:
        for area in screen.areas:
            area.tag_redraw()


def _poll_target(self, obj):
    # Any object may drive a handle (Empties and armatures are the usual ones), but not the mesh itself.
    return obj != self.id_data


class LARAP_PG_handle(bpy.types.PropertyGroup):
    """A handle: the vertices of a vertex group follow a target (object or bone) since bind."""
    vertex_group: StringProperty(name="Vertex Group", description="Vertices that follow the target")
    target: PointerProperty(name="Target", type=bpy.types.Object, poll=_poll_target,
                            description="Object (Empty) or armature whose motion since bind moves the vertices")
    subtarget: StringProperty(name="Bone", description="Bone of an armature target (empty: the object itself)")
    rest_matrix: FloatVectorProperty(name="Rest Matrix", size=16, subtype="NONE",  # row-major 4x4
                                     default=(1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1),
                                     description="World matrix of the target when the handle was bound")
    has_rest: BoolProperty(name="Has Rest", default=False,
                           description="The rest matrix was recorded (bind or handle creation)")
    enabled: BoolProperty(name="Enabled", default=True, description="Use this handle when solving")
    weight: FloatProperty(name="Weight", default=1.0, min=0.0, soft_max=10.0, update=_redraw,
                          description="How hard this handle pulls its vertices to their target, against the "
                          "other handles: 1 pulls as hard as any other handle, however many vertices "
                          "either has; 2 twice as hard")
    created_target: BoolProperty(default=False, description="LARAP created the target Empty (only such an Empty "
                                 "is ever deleted by LARAP, and only when asked)")


class LARAP_PG_settings(bpy.types.PropertyGroup):
    bound: BoolProperty(name="Bound", default=False)
    resolution_mode: EnumProperty(
        name="Resolution",
        items=[("AUTO", "Auto", "The engine's default lattice resolution (about 6000 cells)"),
               ("CELLS", "Cells", "Approximate number of lattice cells"),
               ("SIZE", "Cell Size", "Edge length of a lattice cell in object units")],
        default="AUTO", update=_redraw)
    cells: IntProperty(name="Cells", default=6000, min=1, soft_max=200000, update=_redraw,
                       description="Approximate number of lattice cells (more: finer, slower)")
    cell_size: FloatProperty(name="Cell Size", default=0.1, min=1e-6, soft_min=1e-3, subtype="DISTANCE",
                             update=_redraw, description="Edge length of a lattice cell (object units)")
    weights_interactive: EnumProperty(name="Interactive Weights", items=WEIGHT_ITEMS, default="trilinear",
                                      description="Interpolation used while dragging and for live updates")
    weights_final: EnumProperty(name="Final Weights", items=WEIGHT_ITEMS, default="bspline",
                                description="Interpolation used by Solve, Bake, Apply and when a drag is confirmed")
    gamma: FloatProperty(name="Gamma", default=0.1, min=1e-6, soft_max=10.0, update=_redraw,
                         description="Rigidity (scale-free; larger is stiffer, handles are soft constraints)")
    iterations: IntProperty(name="Iterations", default=5, min=1, soft_max=50, max=1000,
                            description="Local/global iterations per solve (warm-started)")
    device: EnumProperty(name="Device", items=DEVICE_ITEMS, default="DEFAULT")
    live: BoolProperty(name="Live", default=False,
                       description="Solve again whenever a handle target moves (G/R/S on the Empties poses the mesh)")
    show_overlay: BoolProperty(name="Show Lattice", default=False, update=_redraw,
                               description="Draw the deformed lattice and the handle vertices in the 3D View")
    shape_key: StringProperty(name="Shape Key", default="LARAP",
                              description="Shape key that receives the pose")
    handles: CollectionProperty(type=LARAP_PG_handle)
    active_handle: IntProperty(name="Active Handle", default=0, min=0)
    # Recorded at bind: detects a topology change.
    bind_vertex_count: IntProperty(default=0)
    bind_topology: StringProperty(default="", description="Hash of the face topology at bind")
    created_basis: BoolProperty(default=False, description="Bind created the Basis shape key")
    owned_key_name: StringProperty(default="", description="Name of the pose shape key LARAP created (LARAP never "
                                   "writes or removes a key it did not create)")
    runtime_id: StringProperty(default="", description="Identifies the object's runtime engine cache (stable "
                               "across renames, undo and reloads)")


class LARAP_AddonPreferences(bpy.types.AddonPreferences):
    bl_idname = __package__

    default_device: EnumProperty(name="Default Device", items=PREF_DEVICE_ITEMS, default="cpu",
                                 description="Device for objects whose device is 'Default'")

    def draw(self, context):
        from . import engine
        layout = self.layout
        layout.prop(self, "default_device")
        mod = engine.get()
        if mod is None:
            layout.label(text=engine.error(), icon="ERROR")
        else:
            layout.label(text="Engine: %s" % engine.location(), icon="CHECKMARK")
            layout.label(text="Devices: %s" % ", ".join(engine.available_devices()))


def preferences(context=None):
    context = context or bpy.context
    addon = context.preferences.addons.get(__package__)
    return addon.preferences if addon is not None else None


classes = (LARAP_PG_handle, LARAP_PG_settings, LARAP_AddonPreferences)


def register_properties():
    bpy.types.Object.larap = PointerProperty(type=LARAP_PG_settings)


def unregister_properties():
    del bpy.types.Object.larap
