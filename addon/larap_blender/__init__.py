# SPDX-License-Identifier: GPL-3.0-or-later
"""LARAP: as-rigid-as-possible mesh posing through a volumetric lattice (Blender add-on).

Registration only. The add-on's rooms, each one concept (imports point down this list):

* ``engine.py``: finds and imports the compiled ``larap`` engine; ``errors.py``: LarapError,
  object checks, engine exceptions translated once.
* ``mesh_data.py``: the only writer of vertex positions and shape keys (numpy buffers);
  ``key_edits.py``: hand edits of the pose key are copied before LARAP overwrites them.
* ``targets.py``: handle targets (rest matrices, where handle vertices go, signatures).
* ``runtime.py``: the runtime-only engine cache and what each engine was told.
* ``progress.py``: Blender's progress indicator and the whole time of a long operation.
* ``preview.py``: the GPU preview (the posed mesh drawn from the lattice while posing).
* ``solving.py``: one solve, targets -> engine -> pose key (or lattice only, for the preview);
  ``transaction.py``: all or nothing (snapshot, restore on error);
  ``catchup.py``: when the mesh data catches up with the preview; ``session.py``: dragging a handle.
* ``handlers.py``: live mode and the app handlers; ``bake.py``: shape keys from poses (one pose,
  an animation) and the bake's aftermath (Remove Bake); ``core.py``: bind/unbind, back to rest,
  handles, apply (and the names scripts use); ``farm.py``: Load Farm Bake (a farm's PC2 cache played by Mesh Cache).
* ``props.py`` settings, ``operators.py`` and ``modal.py`` operators, ``ui.py`` panels and menus,
  ``overlay.py`` the 3D View drawing.
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

if "bpy" in locals():  # F8 / re-enable: reload the rooms bottom-up, each after what it imports
    import importlib
    for _mod in _MODULES:  # noqa: F821 (set by the first load)
        importlib.reload(_mod)
else:
    from . import (engine, scene_index, props, errors, progress, mesh_data, key_edits, targets, runtime, preview,
                   transaction, solving, catchup, session, handlers, bake, core, operators, modal, farm, ui,
                   overlay)

import bpy

# Every module of the add-on, each after the modules it imports (the reload order).
_MODULES = (engine, scene_index, props, errors, progress, mesh_data, key_edits, targets, runtime, preview,
            solving, transaction, catchup, session, handlers, bake, core, operators, modal, farm, ui, overlay)
# Modules with a ``classes`` tuple, registered in this order and unregistered in reverse.
_CLASS_MODULES = (props, operators, modal, farm, ui)

_register_classes, _unregister_classes = bpy.utils.register_classes_factory(
    tuple(cls for mod in _CLASS_MODULES for cls in mod.classes))


def register():
    _register_classes()
    props.register_properties()
    ui.register_menus()
    handlers.register()
    overlay.register()
    preview.register()
    if engine.load() is None:
        print("LARAP:", engine.error())


def unregister():
    preview.unregister()
    overlay.unregister()
    handlers.unregister()
    ui.unregister_menus()
    props.unregister_properties()
    _unregister_classes()
    runtime.drop_runtime()
