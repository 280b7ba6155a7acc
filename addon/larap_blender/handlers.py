# SPDX-License-Identifier: GPL-3.0-or-later
"""Live mode and the application handlers.

Live: when a handle target moves (G/R/S, drivers, constraints, animation), the meshes it drives
solve again with the interactive weights (:func:`live_update`, from ``depsgraph_update_post`` and
``frame_change_post``). :func:`suspend_live` holds it off while LARAP itself steps frames or
writes (bake). The other handlers keep the runtime cache true to the file: ``load_post`` drops it,
``undo_post``/``redo_post`` make it re-validate (runtime.after_undo).
"""
import contextlib

import bpy
from bpy.app.handlers import persistent

from .errors import LarapError
from .runtime import after_undo, drop_runtime, runtime, runtime_or_placeholder
from .solving import solve
from .targets import target_names, target_signature

_SUSPEND = [0]


@contextlib.contextmanager
def suspend_live():
    _SUSPEND[0] += 1
    try:
        yield
    finally:
        _SUSPEND[0] -= 1


def live_suspended():
    return _SUSPEND[0] > 0


def live_update(scene, updated_names=None):
    """Re-solve every live, bound mesh of ``scene`` whose targets moved. ``updated_names``: the
    objects the depsgraph reported (None: check all). Never raises; errors land in rt.last_error."""
    if live_suspended():
        return 0
    solved = 0
    with suspend_live():
        for obj in list(scene.objects):
            try:
                if obj.type != "MESH" or not obj.larap.bound or not obj.larap.live:
                    continue
            except ReferenceError:
                continue
            targets = target_names(obj)
            if updated_names is not None and not (targets & updated_names):
                continue
            rt = runtime(obj)
            if rt is not None and rt.target_sig is not None and rt.target_sig == target_signature(obj):
                continue
            try:
                if obj.mode == "EDIT":
                    continue
                solve(obj, weights="interactive", validate="fast")
                solved += 1
            except Exception as exc:  # a handler must never raise; LarapError is the expected kind
                msg = str(exc) if isinstance(exc, LarapError) else "internal error: %s: %s" % (
                    type(exc).__name__, exc)
                rt = runtime_or_placeholder(obj)
                if rt.last_error != msg:
                    print("LARAP live update of %r: %s" % (obj.name, msg))
                    if not isinstance(exc, LarapError):
                        import traceback
                        traceback.print_exc()
                rt.last_error = msg
                try:
                    rt.target_sig = target_signature(obj)
                except Exception:
                    rt.target_sig = None
    return solved



@persistent
def larap_depsgraph_update_post(scene, depsgraph=None):
    """Live mode: a target moved (G/R/S, drivers, constraints) -> solve the meshes it drives.

    Our own writes only tag the mesh (never a target), and live_update skips meshes whose target
    matrices did not change, so this does not recurse. Deleted objects raise ReferenceError and are
    skipped."""
    if live_suspended() or depsgraph is None:
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
        live_update(scene, updated)


@persistent
def larap_frame_change_post(scene, depsgraph=None):
    """Animated targets: depsgraph_update_post does not fire on frame changes."""
    if not live_suspended():
        live_update(scene, None)


@persistent
def larap_load_post(*_args):
    """A new file: pointers and data changed; engines are rebuilt lazily from the stored settings."""
    drop_runtime()


@persistent
def larap_undo_post(*_args):
    """Undo/redo replaced the mesh, keys, settings and targets with a stored state: the cached
    engines re-validate, forget their warm start, and Live does not overwrite the restored pose."""
    after_undo()


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
