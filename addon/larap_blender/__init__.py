# SPDX-License-Identifier: GPL-3.0-or-later
"""LARAP: as-rigid-as-possible mesh posing through a volumetric lattice (Blender add-on).

Registration only; the work is in core.py (plain functions), the UI in ui.py, settings in
props.py, operators in operators.py, the overlay in overlay.py and app handlers in handlers.py.
"""
bl_info = {
    "name": "LARAP Deform",
    "author": "LARAP developers",
    "version": (0, 1, 0),
    "blender": (3, 4, 0),
    "location": "View3D > Sidebar > LARAP; Object > LARAP",
    "description": "As-rigid-as-possible posing of meshes through a volumetric lattice (Zollhoefer et al. 2012)",
    "category": "Mesh",
}

if "bpy" in locals():
    import importlib
    for _mod in (engine, props, core, operators, farm, ui, overlay, handlers):  # noqa: F821
        importlib.reload(_mod)
else:
    from . import engine, props, core, operators, farm, ui, overlay, handlers

import bpy

_register_classes, _unregister_classes = bpy.utils.register_classes_factory(
    props.classes + operators.classes + farm.classes + ui.classes)


def register():
    _register_classes()
    props.register_properties()
    ui.register_menus()
    handlers.register()
    overlay.register()
    if engine.load() is None:
        print("LARAP:", engine.error())


def unregister():
    overlay.unregister()
    handlers.unregister()
    ui.unregister_menus()
    props.unregister_properties()
    _unregister_classes()
    core.drop_runtime()
