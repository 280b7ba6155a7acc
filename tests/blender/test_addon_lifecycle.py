# SPDX-License-Identifier: GPL-3.0-or-later
# Run: blender -b --factory-startup --python-exit-code 1 --python tests/blender/run_tests.py -- tests/blender/test_addon_lifecycle.py
import os

import bpy
import pytest

from conftest import ADDON, _our_handlers, activate, disable_addon, enable_addon, make_bar

OPERATORS = ("bind", "unbind", "handle_add", "handle_remove", "solve", "pose", "bake_shape_key",
             "bake_animation", "apply")


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


def test_disable_removes_handlers_and_reenable_works(addon):
    disable_addon()
    assert _our_handlers() == []
    assert not hasattr(bpy.types.Object, "larap")
    assert not hasattr(bpy.types, "VIEW3D_PT_larap")
    enable_addon()
    assert len(_our_handlers()) == 3
    disable_addon()
    enable_addon()
    assert len(_our_handlers()) == 3, "handlers duplicated by re-enabling"


def test_overlay_not_registered_in_background(addon):
    from larap_blender import overlay
    assert bpy.app.background
    assert not overlay.is_registered()


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
