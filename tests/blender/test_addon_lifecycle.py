# SPDX-License-Identifier: GPL-3.0-or-later
# Run: blender -b --factory-startup --python-exit-code 1 --python tests/blender/run_tests.py -- tests/blender/test_addon_lifecycle.py
import os

import bpy
import pytest

from conftest import ADDON, _our_handlers, activate, disable_addon, enable_addon, make_bar

OPERATORS = ("bind", "unbind", "handle_add", "handle_remove", "solve", "pose", "back_to_rest", "bake_shape_key",
             "bake_animation", "remove_bake", "apply")


def test_enable_registers_everything(addon):
    assert hasattr(bpy.types.Object, "larap")
    for name in OPERATORS:
        assert hasattr(bpy.ops.larap, name), name
        # Stable idnames, findable by F3 (operator search uses the registered idname/label).
        assert getattr(bpy.ops.larap, name).idname() == "LARAP_OT_" + name
    assert hasattr(bpy.types, "VIEW3D_PT_larap")
    assert hasattr(bpy.types, "VIEW3D_MT_larap")
    prefs = bpy.context.preferences.addons[ADDON].preferences
    assert prefs.default_device == "cpu"
    handlers = _our_handlers()
    assert ("depsgraph_update_post", "larap_depsgraph_update_post") in handlers
    assert ("load_post", "larap_load_post") in handlers


def test_object_menu_lists_every_operator(addon):
    from larap_blender import ui
    assert {op for op, _, _ in ui.OPERATORS} == {"larap." + name for name in OPERATORS}


OUR_HANDLERS = {("depsgraph_update_post", "larap_depsgraph_update_post"),
                ("frame_change_post", "larap_frame_change_post"), ("load_post", "larap_load_post"),
                ("undo_pre", "larap_before_swap"), ("redo_pre", "larap_before_swap"),
                ("undo_post", "larap_undo_post"), ("redo_post", "larap_undo_post"),
                ("load_pre", "larap_load_pre"), ("save_pre", "larap_catch_up"), ("render_init", "larap_catch_up"),
                ("render_pre", "larap_catch_up"), ("object_bake_pre", "larap_catch_up")}


def test_disable_removes_handlers_and_reenable_works(addon):
    assert sorted(_our_handlers()) == sorted(OUR_HANDLERS)
    disable_addon()
    assert _our_handlers() == []
    assert not hasattr(bpy.types.Object, "larap")
    assert not hasattr(bpy.types, "VIEW3D_PT_larap")
    enable_addon()
    assert sorted(_our_handlers()) == sorted(OUR_HANDLERS)
    disable_addon()
    enable_addon()
    assert sorted(_our_handlers()) == sorted(OUR_HANDLERS), "handlers duplicated by re-enabling"


def test_overlay_draw_handler_lifecycle(addon):
    """The 3D View draw callback is added once on enable and really removed on disable (removing a
    removed callback raises ValueError in Blender, which proves it is gone). Registered in background
    mode too (it never runs there), so this is tested headless."""
    from larap_blender import overlay
    first = overlay._DRAW_HANDLE
    assert overlay.is_registered() and first is not None
    overlay.register()  # idempotent
    assert overlay._DRAW_HANDLE is first
    disable_addon()
    assert not overlay.is_registered()
    with pytest.raises(ValueError):
        bpy.types.SpaceView3D.draw_handler_remove(first, "WINDOW")
    enable_addon()
    from larap_blender import overlay as overlay2
    second = overlay2._DRAW_HANDLE
    assert second is not None and second is not first
    disable_addon()
    with pytest.raises(ValueError):
        bpy.types.SpaceView3D.draw_handler_remove(second, "WINDOW")
    enable_addon()


def test_overlay_draw_callback_headless(core):
    """The callback itself, with gpu calls stubbed (no GPU context in background mode): it finds a
    renamed object's engine, and after an undo-like invalidation draws the rest lattice (labelled
    so), never the engine's stale pose."""
    from conftest import bar_with_handles
    from larap_blender import overlay
    obj, *_ = bar_with_handles(core)
    obj.larap.show_overlay = True
    obj.name = "Renamed"
    rt = core.runtime(obj)
    assert rt is not None and rt.lattice_current
    import gpu_extras.batch as gb
    made = []
    real = gb.batch_for_shader
    gb.batch_for_shader = lambda shader, kind, data: made.append((kind, len(data["pos"]))) or kind
    try:
        overlay._CACHE.clear()
        lattice, handles = overlay._batches(obj, rt, None, True)
        assert lattice == "LINES" and set(handles.values()) == {"POINTS"} and len(handles) == 2
        assert overlay.lattice_state(obj, rt) == "pose"
        n_edges = made[0][1]
        core.after_undo()  # what undo_post does
        overlay._CACHE.clear()
        made.clear()
        lattice, handles = overlay._batches(obj, core.runtime(obj), None, True)
        # the engine's lattice is no longer the shown pose: the rest lattice, labelled "rest"
        assert overlay.lattice_state(obj, core.runtime(obj)) == "rest"
        assert lattice == "LINES" and made[0][1] == n_edges and set(handles.values()) == {"POINTS"}
    finally:
        gb.batch_for_shader = real


def test_non_mesh_object_reports_error(addon):
    empty = bpy.data.objects.new("E", None)
    bpy.context.scene.collection.objects.link(empty)
    activate(empty)
    for op in (bpy.ops.larap.bind, bpy.ops.larap.solve, bpy.ops.larap.unbind):
        with pytest.raises(RuntimeError, match="works on meshes") as info:
            op()
        assert "Traceback" not in str(info.value)


def test_no_active_object_reports_error(addon):
    bpy.context.view_layer.objects.active = None
    with pytest.raises(RuntimeError, match="No active object"):
        bpy.ops.larap.bind()


def test_missing_engine_message(addon, tmp_path):
    """A package without a compiled module, or one built for another Python, is explained."""
    from larap_blender import engine
    pkg = tmp_path / "larap"
    pkg.mkdir()
    (pkg / "__init__.py").write_text("")
    msg = engine._explain(str(pkg), ImportError("x"))
    assert "not built" in msg
    (pkg / "_core.cpython-39-x86_64-linux-gnu.so").write_bytes(b"")
    msg = engine._explain(str(pkg), ImportError("x"))
    assert "another Python" in msg and "3." in msg


def test_unbound_solve_reports(addon):
    make_bar()
    with pytest.raises(RuntimeError, match="not bound"):
        bpy.ops.larap.solve()


def test_linked_library_object_reports(addon, tmp_path):
    make_bar("LinkedBar")
    path = str(tmp_path / "lib.blend")
    bpy.ops.wm.save_as_mainfile(filepath=path, copy=True)
    bpy.ops.wm.read_factory_settings(use_empty=True)
    enable_addon()
    with bpy.data.libraries.load(path, link=True) as (src, dst):
        dst.objects = ["LinkedBar"]
    obj = dst.objects[0]
    bpy.context.scene.collection.objects.link(obj)
    activate(obj)
    assert obj.library is not None
    with pytest.raises(RuntimeError, match="not editable"):
        bpy.ops.larap.bind()
    assert os.path.exists(path)
