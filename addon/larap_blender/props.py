# SPDX-License-Identifier: GPL-3.0-or-later
"""Settings stored in the .blend (``Object.larap``) and the add-on preferences."""
import struct

import bpy
from bpy.props import (BoolProperty, CollectionProperty, EnumProperty, FloatProperty,
                       FloatVectorProperty, IntProperty, PointerProperty, StringProperty)

from . import scene_index

WEIGHT_ITEMS = [  # what the artist sees: the look and the cost, the maths in the tooltip
    ("trilinear", "Fast", "Follows the lattice cell by cell: quickest, may show faint creases at cell borders "
     "(trilinear interpolation)"),
    ("bspline", "Smooth", "Blends each point over its neighbouring cells: no creases, a bit slower "
     "(quadratic B-spline interpolation)"),
]
# Where the documentation lives: the add-on's copy when packaged with it, else the source tree's.
DOC_FILE = "addon.md"
DEVICE_ITEMS = [
    ("DEFAULT", "Default", "Use the device set in the add-on preferences"),
    ("cpu", "CPU", "Solve on the CPU"),
    ("cuda", "CUDA", "Solve on an NVIDIA GPU"),
    ("auto", "Auto", "CUDA when available, else CPU"),
]
PREF_DEVICE_ITEMS = [item for item in DEVICE_ITEMS if item[0] != "DEFAULT"]


# Format of the settings stored on an object. 1 (2026-11-22): Stiffness's default went from 0.1 to
# 0.03, which holds handles (and the parts they pin) two to three times closer to their targets
# (docs/method.md, "Energy and the meaning of γ"). An unset property is not stored in the .blend, so
# an object bound before, whose Stiffness was never changed, would read the new default and pose
# differently: upgrade_settings gives it its old value instead.
SETTINGS_VERSION = 1
GAMMA = 0.03  # the engine's larap.DEFAULT_GAMMA (the engine may be missing here; a test keeps them equal)
GAMMA_BEFORE_1 = 0.1


def id_string(obj, name):
    """A string the add-on keeps in the object's ID property ``name`` (travels with undo steps and
    the .blend, unlike a runtime cache); "" when unset or the object is gone."""
    try:
        return str(obj.get(name, ""))
    except (ReferenceError, TypeError):
        return ""


def set_id_string(obj, name, value):
    """Store ``value`` in the object's ID property ``name``; "" removes it."""
    if value:
        obj[name] = value
    elif name in obj:
        del obj[name]


def upgrade_settings(s):
    """Brings an object's settings (``obj.larap``) to SETTINGS_VERSION without changing how it
    poses, and returns the Stiffness to solve with. Called on load and wherever an engine is given
    the Stiffness (so appended objects are upgraded too), and for the objects a depsgraph update
    or an undo reports; where this context may not write the object (drawing), it still returns
    the value the upgrade would store. Bind stores the Stiffness explicitly, so a later change of
    the default leaves bound objects as they are."""
    if s.settings_version >= SETTINGS_VERSION:
        return float(s.gamma)
    older_default = s.bound and not s.is_property_set("gamma")
    try:
        if older_default:
            s.gamma = GAMMA_BEFORE_1
        s.settings_version = SETTINGS_VERSION
    except (AttributeError, RuntimeError) as exc:
        # a context that may not write data ("Writing to ID classes in this context is not
        # allowed"), or a read-only (linked) object: solve with what the upgrade would store
        if "not allowed" not in str(exc) and "read-only" not in str(exc):
            raise
        if older_default:  # the value as the property would store it (single precision)
            return struct.unpack("f", struct.pack("f", GAMMA_BEFORE_1))[0]
    return float(s.gamma)


def _redraw(self, context):
    # Settings that only matter at the next solve: just redraw the UI.
    screen = getattr(context, "screen", None)
    if screen is not None:
        for area in screen.areas:
            area.tag_redraw()


def _retarget(self, context):
    # Picking another target (or bone) must not move the mesh: record the new target's rest where
    # the handle's vertices are now (targets.retarget_keep_pose). An update callback never raises.
    from . import targets
    targets.on_target_changed(self)


def _write_when_off(prop):
    """Live or Preview turned off: the mesh data catches up with what was shown (catchup.py)."""
    def update(self, context):
        if not getattr(self, prop):
            from . import catchup
            catchup.setting_turned_off(self.id_data)
    return update


def _poll_target(self, obj):
    # Any object may drive a handle (Empties and armatures are the usual ones), but not the mesh itself.
    return obj != self.id_data


class LARAP_PG_name(bpy.types.PropertyGroup):
    """A name in a list (a shape key made by Bake Animation)."""


class LARAP_PG_handle(bpy.types.PropertyGroup):
    """A handle: the vertices of a vertex group follow a target (object or bone) since bind."""
    vertex_group: StringProperty(name="Vertex Group", description="Vertices that follow the target")
    target: PointerProperty(name="Target", type=bpy.types.Object, poll=_poll_target, update=_retarget,
                            description="Object (Empty) or armature that moves these vertices. Changing it keeps "
                            "the pose: the new target takes over from where the vertices are now")
    subtarget: StringProperty(name="Bone", update=_retarget,
                              description="Bone of an armature target (empty: the armature object itself)")
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
    # Whose world matrix ``rest_matrix`` is (a pointer follows renames): retargeting reads the old
    # target's motion from it, so the new target takes over without a jump.
    rest_target: PointerProperty(type=bpy.types.Object, options={"HIDDEN"})
    rest_subtarget: StringProperty(options={"HIDDEN"})
    # The bone's rest in its armature (matrix_local, row-major, then its length) when the handle
    # last found it by name: a renamed bone is found again by it (targets.follow_bone_renames).
    bone_rest: FloatVectorProperty(size=17, options={"HIDDEN"})
    has_bone_rest: BoolProperty(default=False, options={"HIDDEN"})
    bone_rest_armature: PointerProperty(type=bpy.types.Object, options={"HIDDEN"})  # whose bone that was


class LARAP_PG_settings(bpy.types.PropertyGroup):
    # Bound meshes are kept between updates (scene_index): binding or unbinding, by the add-on or
    # a script, makes it look again.
    bound: BoolProperty(name="Bound", default=False, update=lambda _self, _context: scene_index.invalidate())
    resolution_mode: EnumProperty(
        name="Resolution",
        description="How fine the lattice that carries the mesh is (finer: follows thin parts better, slower)",
        items=[("AUTO", "Auto", "About 6000 cells around the mesh (the cell size is shown once bound)"),
               ("CELLS", "Cells", "Approximate number of lattice cells"),
               ("SIZE", "Cell Size", "Edge length of a lattice cell in object units")],
        default="AUTO", update=_redraw)
    cells: IntProperty(name="Cells", default=6000, min=1, soft_max=200000, update=_redraw,
                       description="Approximate number of lattice cells (more: finer, slower)")
    cell_size: FloatProperty(name="Cell Size", default=0.1, min=1e-6, soft_min=1e-3, subtype="DISTANCE",
                             update=_redraw, description="Edge length of a lattice cell (object units)")
    split_cells: BoolProperty(name="Parts Apart", default=True, update=_redraw,
                              description="Parts that pass close through one lattice cell (fingers, an eye and "
                              "its lid) get their own copy of the cell, so moving one does not drag the other "
                              "through it. Off: one cell for everything inside it (the lattice of older versions)")
    weights_interactive: EnumProperty(name="Dragging", items=WEIGHT_ITEMS, default="trilinear",
                                      description="How the mesh follows the lattice while you drag and in Live "
                                      "mode (Fast keeps dragging responsive)")
    weights_final: EnumProperty(name="Final", items=WEIGHT_ITEMS, default="bspline",
                                description="How the mesh follows the lattice for the result: Solve, a confirmed "
                                "drag, Bake and Apply (Smooth has no creases)")
    gamma: FloatProperty(name="Stiffness", default=GAMMA, min=1e-6, max=1e8, soft_max=10.0, update=_redraw,
                         description="How much the mesh resists bending and stretching against the pull of the "
                         "handles. Higher: stiffer, handles lag behind their targets; lower: handles are "
                         "followed closely and the rest bends more. Does not depend on the mesh's size")
    iterations: IntProperty(name="Iterations", default=5, min=1, soft_max=50, max=1000,
                            description="Refinement steps per update while dragging and in Live mode (more: closer "
                            "to the final shape, slower). Solve refines until the shape settles")
    device: EnumProperty(name="Device", items=DEVICE_ITEMS, default="DEFAULT")
    live: BoolProperty(name="Live", default=False, update=_write_when_off("live"),
                       description="Pose the mesh whenever a handle's target moves (G/R/S on the Empties, "
                       "bones, animation playback)")
    show_overlay: BoolProperty(name="Show Lattice", default=False, update=_redraw,
                               description="Draw the lattice that carries the mesh and the handle vertices in the "
                               "3D View")
    overlay_xray: BoolProperty(name="Lattice X-Ray", default=False, update=_redraw,
                               description="Draw the whole lattice through the mesh (off: only what is in front of "
                               "the mesh, like Blender's wireframe overlay)")
    # Bake Animation's aftermath: its keys, which only Remove Bake removes, and what it paused.
    bake_keys: CollectionProperty(type=LARAP_PG_name)
    bake_paused_live: BoolProperty(default=False, description="Live was on before the bake and was paused by it")
    bake_created_action: StringProperty(default="", description="Name of the shape-key action the bake created "
                                        "(removed with the bake when nothing else is left in it)")
    shape_key: StringProperty(name="Shape Key", default="LARAP",
                              description="Shape key that receives the pose")
    handles: CollectionProperty(type=LARAP_PG_handle)
    active_handle: IntProperty(name="Active Handle", default=0, min=0)
    # Recorded at bind: detects a topology change.
    settings_version: IntProperty(default=0, options={"HIDDEN"},
                                  description="Format of these settings (upgrade_settings); 0: older than 1")
    bind_vertex_count: IntProperty(default=0)
    bind_topology: StringProperty(default="", description="Hash of the face topology at bind")
    created_basis: BoolProperty(default=False, description="Bind created the Basis shape key")
    owned_key_name: StringProperty(default="", description="Name of the pose shape key LARAP created (LARAP never "
                                   "writes or removes a key it did not create)")
    runtime_id: StringProperty(default="", description="Identifies the object's runtime engine cache (stable "
                               "across renames, undo and reloads)")
    preview: BoolProperty(name="Preview", default=True, update=_write_when_off("preview"),
                          description="While posing (drag, Live, playback) draw the posed mesh on the GPU from the "
                          "lattice and write the mesh once the moves pause (ignored in background mode; meshes "
                          "with modifiers or mixed shape keys are written at each move instead)")


class LARAP_AddonPreferences(bpy.types.AddonPreferences):
    bl_idname = __package__

    default_device: EnumProperty(name="Default Device", items=PREF_DEVICE_ITEMS, default="cpu",
                                 description="Device for objects whose device is 'Default'")

    def draw(self, context):
        from . import engine
        layout = self.layout
        row = layout.row()
        row.prop(self, "default_device")
        url = documentation_url()
        if url:
            row.operator("wm.url_open", text="Documentation", icon="HELP").url = url
        else:
            row.label(text="Documentation: docs/addon.md in the LARAP sources", icon="HELP")
        mod = engine.get()
        if mod is None:
            layout.label(text=engine.error(), icon="ERROR")
        else:
            layout.label(text="Engine: %s" % engine.location(), icon="CHECKMARK")
            layout.label(text="Devices: %s" % ", ".join(engine.available_devices()))


def documentation_url():
    """file:// URL of the add-on's manual (docs/addon.md): the copy packaged inside the add-on, else
    the one in the source tree the add-on runs from; "" when neither is there."""
    import os
    here = os.path.dirname(os.path.abspath(__file__))
    for path in (os.path.join(here, "docs", DOC_FILE), os.path.join(here, os.pardir, os.pardir, "docs", DOC_FILE)):
        if os.path.isfile(path):
            return "file://" + os.path.realpath(path)
    return ""


def preferences(context=None):
    context = context or bpy.context
    addon = context.preferences.addons.get(__package__)
    return addon.preferences if addon is not None else None


classes = (LARAP_PG_name, LARAP_PG_handle, LARAP_PG_settings, LARAP_AddonPreferences)


def register_properties():
    bpy.types.Object.larap = PointerProperty(type=LARAP_PG_settings)


def unregister_properties():
    del bpy.types.Object.larap
