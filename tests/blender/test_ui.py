# SPDX-License-Identifier: GPL-3.0-or-later
# Run: blender -b --factory-startup --python-exit-code 1 --python tests/blender/run_tests.py -- tests/blender/test_ui.py
# Headless Blender draws no UI, so the draw functions run against a recording layout: every code
# path of the panel (unbound, bound, topology changed, missing target/group, no engine) must run
# without raising and show the expected labels and operators.
import types
from unittest import mock

import bpy

from conftest import ADDON, activate, bar_with_handles, make_bar


class Recorder:
    """Accepts any layout call; remembers labels, operators and props."""

    def __init__(self, log=None):
        self.log = log if log is not None else []

    def __getattr__(self, name):
        def call(*args, **kwargs):
            if name == "label":
                self.log.append(("label", kwargs.get("text", args[0] if args else "")))
            elif name in ("operator", "operator_menu_enum"):
                self.log.append(("operator", args[0] if args else kwargs.get("operator")))
                return mock.MagicMock()
            elif name in ("prop", "prop_search"):
                self.log.append(("prop", args[1] if len(args) > 1 else kwargs.get("property")))
            elif name == "template_list":
                self.log.append(("template_list", args[0]))
            return Recorder(self.log)
        return call

    def __setattr__(self, name, value):
        if name == "log":
            object.__setattr__(self, name, value)

    def labels(self):
        return [v for k, v in self.log if k == "label"]

    def operators(self):
        return [v for k, v in self.log if k == "operator"]


def draw(cls, context=None):
    layout = Recorder()
    cls.draw(types.SimpleNamespace(layout=layout), context or bpy.context)
    return layout


def test_panel_unbound_and_non_mesh(addon):
    empty = bpy.data.objects.new("E", None)
    bpy.context.scene.collection.objects.link(empty)
    activate(empty)
    assert "Select a mesh object" in draw(bpy.types.VIEW3D_PT_larap).labels()
    make_bar()
    out = draw(bpy.types.VIEW3D_PT_larap)
    assert "Not bound" in out.labels()
    assert {"larap.bind", "larap.solve", "larap.pose", "larap.apply", "larap.bake_shape_key",
            "larap.bake_animation", "larap.unbind", "larap.handle_add", "larap.handle_remove"} <= set(out.operators())


def test_panel_bound_shows_stats_and_problems(core):
    obj, rest, left, right, targets = bar_with_handles(core)
    labels = " | ".join(draw(bpy.types.VIEW3D_PT_larap).labels())
    assert "Bound: %d vertices" % len(rest) in labels
    assert "cells of" in labels and "on CPU" in labels and "Last pose" in labels
    draw(bpy.types.VIEW3D_PT_larap_settings)
    obj.vertex_groups.remove(obj.vertex_groups["Right"])
    obj.larap.active_handle = 1
    assert "Vertex group 'Right' missing (renamed or deleted?): pick it again" in " ".join(
        draw(bpy.types.VIEW3D_PT_larap).labels())  # wrapped to the sidebar's width
    bpy.data.objects.remove(targets[0])
    obj.larap.active_handle = 0
    draw(bpy.types.VIEW3D_PT_larap)
    obj.data.vertices.add(1)
    out = draw(bpy.types.VIEW3D_PT_larap)
    assert "The mesh changed since bind" in " ".join(out.labels()) and "larap.bind" in out.operators()
    core.drop_runtime()
    assert "Lattice rebuilt at the next pose" in draw(bpy.types.VIEW3D_PT_larap).labels()


def test_ui_list_menu_and_preferences_draw(core):
    obj, *_ = bar_with_handles(core)
    ul = bpy.types.LARAP_UL_handles
    for i, item in enumerate(obj.larap.handles):
        ul.draw_item(None, bpy.context, Recorder(), obj.larap, item, 0, obj.larap, "active_handle", i)
    out = draw(bpy.types.VIEW3D_MT_larap)
    from larap_blender import ui
    assert out.operators() == [op for op, _, _ in ui.OPERATORS] and len(out.operators()) == 11
    prefs = bpy.context.preferences.addons[ADDON].preferences
    layout = Recorder()
    type(prefs).draw(types.SimpleNamespace(layout=layout, default_device="cpu"), bpy.context)
    assert any("Engine:" in t for t in layout.labels())


def test_panel_without_engine_shows_message(addon):
    from larap_blender import engine
    make_bar()
    with mock.patch.object(engine, "_module", None), mock.patch.object(engine, "_tried", True), \
            mock.patch.object(engine, "_error", "LARAP engine not built: test"):
        labels = " ".join(draw(bpy.types.VIEW3D_PT_larap).labels())
        assert "LARAP engine not built" in labels
        try:
            bpy.ops.larap.bind()
        except RuntimeError as exc:
            assert "LARAP engine not built" in str(exc) and "Traceback" not in str(exc)
        else:
            raise AssertionError("bind without an engine must report an error")


def test_panel_says_where_hand_edits_of_the_pose_key_were_kept(core):
    obj, rest, left, right, targets = bar_with_handles(core)
    bpy.ops.larap.solve()
    obj.data.shape_keys.key_blocks["LARAP"].data[3].co.z += 0.2
    targets[1].location.z += 0.2
    assert core.solve(obj).kept == "LARAP edits"
    core.solve(obj)  # the warning of the solve that kept them is gone; the panel's line stays
    labels = " ".join(draw(bpy.types.VIEW3D_PT_larap).labels())
    assert "Hand edits of the pose key are kept in 'LARAP edits'" in labels, labels
    obj.shape_key_remove(obj.data.shape_keys.key_blocks["LARAP edits"])
    assert "Hand edits" not in " ".join(draw(bpy.types.VIEW3D_PT_larap).labels())
