# SPDX-License-Identifier: GPL-3.0-or-later
"""Application handlers: live re-solve when a handle target moves, cache reset on file load."""
import bpy
from bpy.app.handlers import persistent

from . import core


@persistent
def larap_depsgraph_update_post(scene, depsgraph=None):
    """Live mode: a target moved (G/R/S, drivers, constraints) -> solve the meshes it drives.

    Our own writes only tag the mesh (never a target), and live_update skips meshes whose target
    matrices did not change, so this does not recurse. Deleted objects raise ReferenceError and are
    skipped."""
    if core.live_suspended() or depsgraph is None:
        return
    updated = set()
    try:
        for update in depsgraph.updates:
            try:
                idd = update.id
                if isinstance(idd, bpy.types.Object):
                    updated.add(idd.original.name_full)
            except ReferenceError:
                continue
    except ReferenceError:
        return
    if updated:
        core.live_update(scene, updated)


@persistent
def larap_frame_change_post(scene, depsgraph=None):
    """Animated targets: depsgraph_update_post does not fire on frame changes."""
    if not core.live_suspended():
        core.live_update(scene, None)


@persistent
def larap_load_post(*_args):
    """A new file: pointers and data changed; engines are rebuilt lazily from the stored settings."""
    core.drop_runtime()


@persistent
def larap_undo_post(*_args):
    """Undo/redo replaced the mesh, keys, settings and targets with a stored state: the cached
    engines re-validate, forget their warm start, and Live does not overwrite the restored pose."""
    core.after_undo()


_HANDLERS = (
    ("depsgraph_update_post", larap_depsgraph_update_post),
    ("frame_change_post", larap_frame_change_post),
    ("load_post", larap_load_post),
    ("undo_post", larap_undo_post),
    ("redo_post", larap_undo_post),
)


def _remove_ours(handler_list, func):
    # Identity, plus name+module: also drops copies left by an older load of this module.
    for h in list(handler_list):
        if h is func or (getattr(h, "__name__", None) == func.__name__
                         and getattr(h, "__module__", None) == func.__module__):
            handler_list.remove(h)


def register():
    for attr, func in _HANDLERS:
        handler_list = getattr(bpy.app.handlers, attr)
        _remove_ours(handler_list, func)
        handler_list.append(func)


def unregister():
    for attr, func in _HANDLERS:
        _remove_ours(getattr(bpy.app.handlers, attr), func)
