# SPDX-License-Identifier: GPL-3.0-or-later
# The panel while a handle's target is active, Pose's waiting-for-a-click state, the artist's words,
# and every text of the panels measured against Blender's default sidebar width.
# Run: blender -b --factory-startup --python-exit-code 1 --python tests/blender/run_tests.py -- tests/blender/test_panel_words.py
import os
import types
from unittest import mock

import bpy
import numpy as np
import pytest

from conftest import ADDON, activate, add_group, bar_with_handles, make_bar
from test_pose_modal import event, fake_context, make_operator, screen
from test_safety import push, undo
from test_ui import Recorder, draw


class Tree:
    """A recording layout that keeps the nesting: each row shares its width among its items."""

    def __init__(self, kind="column", parent=None):
        self.kind, self.items, self.children = kind, [], []
        self.use_property_split = False
        self.enabled = True
        self.ops = []
        self.parent = parent

    def _child(self, kind):
        c = Tree(kind, self)
        c.use_property_split = self.use_property_split
        self.items.append(("child", c))
        return c

    def row(self, **kw):
        return self._child("row")

    def column(self, **kw):
        return self._child("column")

    def box(self):
        return self._child("box")

    def label(self, text="", icon="NONE"):
        self.items.append(("label", text, icon))

    def operator(self, idname, text=None, icon="NONE", **kw):
        if text is None:
            text = getattr(bpy.types, idname.split(".")[0].upper() + "_OT_" + idname.split(".")[1]).bl_label
        op = types.SimpleNamespace(idname=idname)
        self.items.append(("operator", text, icon))
        self.ops.append(op)
        self.root().all_ops.append(op)
        return op

    def prop(self, data, name, text=None, icon="NONE", **kw):
        rna = data.bl_rna.properties[name]
        self.items.append(("prop", rna.name if text is None else text, icon, data, name, self.use_property_split))

    def prop_search(self, data, name, *a, text=None, **kw):
        self.prop(data, name, text=text)

    def template_list(self, *a, **kw):
        self.items.append(("list",))

    def separator(self, **kw):
        pass

    def root(self):
        node = self
        while node.parent is not None:
            node = node.parent
        if not hasattr(node, "all_ops"):
            node.all_ops = []
        return node

    def walk(self, width):
        """Yield (text, width available to it, icon, item) for every text drawn."""
        items = self.items
        # In a row an icon-only button takes one unit (24 px); the others share what is left.
        icon_only = [it for it in items if it[0] in ("operator", "prop") and it[1] == ""]
        n = len(items) - len(icon_only)
        share = (width - 24 * len(icon_only)) / max(1, n) if self.kind == "row" else width
        for it in items:
            if it[0] == "child":
                c = it[1]
                yield from c.walk(share - (12 if c.kind == "box" else 0))
            elif it[0] in ("label", "operator"):
                yield it[1], share, it[2], it
            elif it[0] == "prop":
                yield it[1], share * (0.4 if it[5] else 1.0), it[2], it


def drawn(cls, context=None):
    tree = Tree()
    tree.root()
    cls.draw(types.SimpleNamespace(layout=tree), context or bpy.context)
    return tree


def texts(tree):
    return [t for t, *_ in tree.walk(1000)]


def overlong(tree, ui):
    """Texts wider than their share of the default sidebar (icon 22 px, padding 10 px)."""
    bad = []
    for text, width, icon, item in tree.walk(ui.CONTENT_WIDTH):
        if not text:
            continue
        budget = width - (22 if icon not in ("NONE", "BLANK1") else 0) - 10
        if item[0] == "label" and icon == "BLANK1":
            budget = width - 22 - 10
        if ui.text_width(text) > budget:
            bad.append((text, round(ui.text_width(text)), round(budget)))
        if item[0] == "prop" and item[5]:  # property split: the value takes the other 60%
            data, name = item[3], item[4]
            rna = data.bl_rna.properties[name]
            if rna.type == "ENUM":
                for e in rna.enum_items:
                    if ui.text_width(e.name) > width / 0.4 * 0.6 - 30:
                        bad.append((e.name, round(ui.text_width(e.name)), round(width / 0.4 * 0.6 - 30)))
    return bad


# ------------------------------------------------------------------------------------------------
# The panel while a target is active

def test_panel_with_a_handle_empty_active_shows_posing_for_its_mesh(core):
    obj, rest, left, right, targets = bar_with_handles(core)
    activate(targets[1])
    assert core.posed_meshes(bpy.context) == [obj]
    tree = drawn(bpy.types.VIEW3D_PT_larap)
    t = texts(tree)
    assert "Bar" in t and "Moves Right" in t and "Live" in t and "Lattice" in t
    ops = {op.idname: op for op in tree.root().all_ops}
    assert ops["larap.solve"].mesh == "Bar" and ops["larap.pose"].mesh == "Bar"
    assert not bpy.types.VIEW3D_PT_larap_settings.poll(bpy.context)  # the mesh's settings: with the mesh
    # The operators act on the driven mesh with the Empty active, as the panel's buttons do.
    targets[1].location.z += 0.5
    assert bpy.ops.larap.solve() == {"FINISHED"}
    assert core.runtime(obj).target_sig == core.target_signature(obj)
    assert bpy.context.object == targets[1]  # the selection is left alone


def test_panel_with_an_armature_active(core):
    obj = make_bar()
    rest = np.array([v.co for v in obj.data.vertices])
    add_group(obj, "Right", np.flatnonzero(rest[:, 0] > 1.8))
    arm = bpy.data.objects.new("Rig", bpy.data.armatures.new("Rig"))
    bpy.context.scene.collection.objects.link(arm)
    activate(arm)
    bpy.ops.object.mode_set(mode="EDIT")
    b = arm.data.edit_bones.new("Hand")
    b.head, b.tail = (2.0, 0.0, 0.0), (2.5, 0.0, 0.0)
    bpy.ops.object.mode_set(mode="OBJECT")
    activate(obj)
    bpy.ops.larap.handle_add(vertex_group="Right", target="Rig", bone="Hand")
    obj.larap.resolution_mode, obj.larap.cells = "CELLS", 1000
    bpy.ops.larap.bind()
    activate(arm)
    bpy.ops.object.mode_set(mode="POSE")  # the artist poses the rig
    t = texts(drawn(bpy.types.VIEW3D_PT_larap))
    assert "Bar" in t and "Moves Right" in t
    bpy.ops.object.mode_set(mode="OBJECT")
    # An object that drives nothing: the plain hint.
    other = bpy.data.objects.new("Lonely", None)
    bpy.context.scene.collection.objects.link(other)
    activate(other)
    assert "Select a mesh object" in texts(drawn(bpy.types.VIEW3D_PT_larap))


def test_a_target_driving_two_meshes_lists_both_and_solve_asks(core):
    obj, rest, left, right, targets = bar_with_handles(core)
    obj2 = make_bar("Bar2")
    add_group(obj2, "R2", np.flatnonzero(rest[:, 0] > 1.8))
    bpy.ops.larap.handle_add(vertex_group="R2", target=targets[1].name)
    obj2.larap.resolution_mode, obj2.larap.cells = "CELLS", 1000
    bpy.ops.larap.bind()
    activate(targets[1])
    t = texts(drawn(bpy.types.VIEW3D_PT_larap))
    assert "Bar" in t and "Bar2" in t
    with pytest.raises(RuntimeError, match="drives several meshes"):
        bpy.ops.larap.solve()
    assert bpy.ops.larap.solve(mesh="Bar2") == {"FINISHED"}


# ------------------------------------------------------------------------------------------------
# Pose waits for a click: handles shown, the one under the cursor highlighted, a miss said

def test_pose_waiting_shows_handles_highlights_and_reports_a_miss(core):
    from larap_blender import modal, overlay
    obj, rest, left, right, targets = bar_with_handles(core)
    assert not obj.larap.show_overlay
    ctx, headers = fake_context(obj)
    status = []
    ctx.workspace = types.SimpleNamespace(status_text_set=status.append)
    op = make_operator()
    assert op.invoke(ctx, event("MOUSEMOVE", pos=(10, 10))) == {"RUNNING_MODAL"}
    assert headers[-1] == modal.PICK_PROMPT and status[-1] == modal.PICK_PROMPT
    assert overlay.picking(obj) is None  # waiting, nothing under the cursor
    # The overlay draws this mesh's handle vertices although Show Lattice is off.
    drawn_objs = list(overlay._drawn_objects(types.SimpleNamespace(visible_objects=[obj])))
    assert [(o, show, pick) for o, _rt, show, pick in drawn_objs] == [(obj, False, True)]
    # Hovering the right end highlights the Right handle (index 1); the left end, Left.
    op.modal(ctx, event("MOUSEMOVE", "NOTHING", pos=screen(2.0, 0.1)))
    assert overlay.picking(obj) == 1
    op.modal(ctx, event("MOUSEMOVE", "NOTHING", pos=screen(-2.0, 0.0)))
    assert overlay.picking(obj) == 0
    # A click on nothing: said in the header and the status bar, still waiting.
    assert op.modal(ctx, event("LEFTMOUSE", pos=screen(0.0, 3.5))) == {"RUNNING_MODAL"}
    assert op.state == "PICK" and headers[-1] == modal.PICK_MISS and status[-1] == modal.PICK_MISS
    # A click on a handle grabs it: the waiting display ends.
    op.modal(ctx, event("LEFTMOUSE", pos=screen(2.0, 0.0)))
    assert op.state == "DRAG" and overlay.picking(obj) == -2 and status[-1] is None
    assert op.modal(ctx, event("ESC")) == {"CANCELLED"}
    assert list(overlay._drawn_objects(types.SimpleNamespace(visible_objects=[obj]))) == []


def test_pose_from_a_target_poses_its_mesh(core):
    obj, rest, left, right, targets = bar_with_handles(core)
    ctx, headers = fake_context(targets[1])
    op = make_operator(handle=1)
    assert op.invoke(ctx, event("MOUSEMOVE", pos=(600, 400))) == {"RUNNING_MODAL"}
    assert op.obj == obj
    op.modal(ctx, event("ESC"))


# ------------------------------------------------------------------------------------------------
# Warnings after undo, the overlay after undo, Empties' size

def test_warnings_refreshed_after_undo(core):
    obj, rest, left, right, targets = bar_with_handles(core)
    push("fine")
    obj.vertex_groups["Right"].name = "Renamed"
    push("renamed")
    bpy.ops.larap.solve("EXEC_DEFAULT", True)
    assert any("'Right'" in w for w in core.runtime(obj).warnings)
    undo()  # the solve
    undo()  # the rename: the cause is gone, so is the warning
    obj = bpy.data.objects["Bar"]
    assert "Right" in obj.vertex_groups
    assert core.runtime(obj).warnings == [] and core.runtime(obj).last_error == ""


def test_overlay_after_undo_is_the_rest_lattice_labelled(core):
    from larap_blender import overlay
    obj, rest, left, right, targets = bar_with_handles(core)
    obj.larap.show_overlay = True
    push("before")
    targets[1].location.z += 0.5
    bpy.ops.larap.solve("EXEC_DEFAULT", True)
    assert overlay.lattice_state(obj, core.runtime(obj)) == "pose"
    undo()
    obj = bpy.data.objects["Bar"]
    assert overlay.lattice_state(obj, core.runtime(obj)) == "rest"
    assert "rest lattice" in overlay.REST_LABEL
    # Dense lattices are drawn fainter (readable at 5k+ cells); X-Ray switches the depth test off.
    assert overlay.lattice_alpha(1000) > overlay.lattice_alpha(5000) >= 0.12
    assert overlay.lattice_alpha(5000) <= 0.3
    assert overlay.depth_tested(obj)
    obj.larap.overlay_xray = True
    assert not overlay.depth_tested(obj)
    obj.larap.overlay_xray = False
    xray_view = types.SimpleNamespace(shading=types.SimpleNamespace(show_xray=True))
    assert not overlay.depth_tested(obj, xray_view)


def test_empty_size_never_bigger_than_the_part(core):
    rng = np.random.default_rng(3)
    cap = rng.uniform((-0.6, -0.5, 0.0), (0.6, 0.5, 0.25), size=(200, 3))  # a head's top: flat
    foot = rng.uniform((0.0, 0.0, 0.0), (0.3, 0.5, 0.2), size=(100, 3))
    feet = np.r_[foot - (0.8, 0, 0), foot + (0.5, 0, 0)]  # two feet 1.6 apart
    for pts in (cap, feet):
        ext = np.sort(pts.max(axis=0) - pts.min(axis=0))
        r = core.empty_size(pts, mesh_size=3.0)
        assert r <= 0.5 * ext[1] + 1e-12  # never bigger than the part it moves
        assert r >= 0.3 * ext[1] - 1e-12
        assert r < 0.6 * np.linalg.norm(ext) / 2  # far smaller than the old 0.6 x extent
    assert core.empty_size(feet, 3.0) <= 0.25  # a foot's length, not the span between the feet
    # The view sets a floor (readable), the part still caps it.
    cap_part = np.sort(cap.max(axis=0) - cap.min(axis=0))[1]
    assert core.empty_size(cap, 3.0, view_distance=100.0) == pytest.approx(0.5 * cap_part)
    assert core.empty_size(np.zeros((1, 3)), 3.0) == pytest.approx(0.12)
    # Through add_handle: the created Empty's sphere fits the group.
    obj, rest, left, right, targets = bar_with_handles(core)
    ext = np.sort(rest[right].max(axis=0) - rest[right].min(axis=0))
    assert targets[1].empty_display_size <= 0.5 * ext[1] + 1e-6


# ------------------------------------------------------------------------------------------------
# Words and widths

def test_artists_words(addon):
    s = bpy.types.Object.bl_rna.properties["larap"].fixed_type.bl_rna.properties
    assert s["gamma"].name == "Stiffness" and "resists bending" in s["gamma"].description
    assert s["weights_interactive"].name == "Dragging" and s["weights_final"].name == "Final"
    assert [e.name for e in s["weights_final"].enum_items] == ["Fast", "Smooth"]
    assert "B-spline" in s["weights_final"].enum_items["bspline"].description  # the maths in the tooltip
    from larap_blender import ui
    for idname, text, icon in ui.OPERATORS:
        mod, name = idname.split(".")
        label = getattr(bpy.types, "LARAP_OT_" + name).bl_label
        assert label == "LARAP " + text, (idname, label, text)  # F3/undo: "LARAP Solve"; menu/panel: "Solve"


def test_preferences_link_the_documentation(addon):
    from larap_blender import props
    prefs = bpy.context.preferences.addons[ADDON].preferences
    tree = Tree()
    tree.root()
    type(prefs).draw(types.SimpleNamespace(layout=tree, default_device="cpu", bl_rna=prefs.bl_rna), bpy.context)
    url = [op for op in tree.root().all_ops if op.idname == "wm.url_open"][0].url
    assert url.startswith("file://") and url.endswith("docs/addon.md") and os.path.isfile(url[len("file://"):])
    assert url == props.documentation_url()


def test_auto_resolution_shows_the_real_cell(core):
    obj, rest, left, right, targets = bar_with_handles(core)
    obj.larap.resolution_mode = "AUTO"
    bpy.ops.larap.solve()
    t = texts(drawn(bpy.types.VIEW3D_PT_larap_settings))
    assert "%.3g m" % core.runtime(obj).deformer.cell_size in t
    assert "Cell Size" not in t  # not the (unused) manual cell size


def test_every_text_fits_the_default_sidebar(core):
    """Measured with blf in Blender's UI font at UI scale 1 (headless blf measures text); the
    panel's content is 184 px of the default 220 px sidebar, a row shares it among its buttons."""
    from larap_blender import ui
    assert ui.text_width("Show Lattice") > 40  # blf really measures here (not the fallback)
    obj, rest, left, right, targets = bar_with_handles(core)
    obj.larap.active_handle = 1
    bad = overlong(drawn(bpy.types.VIEW3D_PT_larap), ui) + overlong(drawn(bpy.types.VIEW3D_PT_larap_settings), ui)
    # Bake aftermath and the target panel, too.
    e = targets[1]
    e.keyframe_insert("location", frame=1)
    e.location.z += 1
    e.keyframe_insert("location", frame=3)
    bpy.ops.larap.bake_animation(frame_start=1, frame_end=3)
    bad += overlong(drawn(bpy.types.VIEW3D_PT_larap), ui)
    obj.vertex_groups["Right"].name = "SomeRenamedGroup"  # a long warning: wrapped, so it fits
    bpy.ops.larap.solve()
    bad += overlong(drawn(bpy.types.VIEW3D_PT_larap), ui)
    activate(e)
    bad += overlong(drawn(bpy.types.VIEW3D_PT_larap), ui)
    assert bad == [], "\n".join(map(str, bad))
