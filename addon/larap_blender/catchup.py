# SPDX-License-Identifier: GPL-3.0-or-later
"""The catch-up: when the mesh data is written after posing with the preview (or live).

While the artist poses, a mesh's pose key may be behind what is shown (``rt.needs_catchup``):
the preview draws interactive poses from the lattice (preview.py), or, without a preview, Live
wrote interactive (unconverged) poses. Catching up is one final solve of the current targets
(``solving.solve(weights="final")``: from rest, converged, written, recorded in the object), so
the mesh holds the one pose of these targets and the preview ends.

It happens:

* :data:`DELAY` seconds after the last live move (a ``bpy.app.timers`` timer, postponed by each
  move, so playback and drags of targets catch up once they pause);
* before render, save (also the save Blender offers on quit or before opening another file) and
  object bake (``render_init``/``render_pre``, ``save_pre``, ``object_bake_pre``), on the main
  thread; before LARAP's own Bake/Apply (``solving.current_pose``) and ``larap.solve``;
* on a frame change while a render job runs (the live update writes the final pose directly);
* when Live or the preview is turned off (their property updates);
* when a change the preview cannot draw reaches a mesh it shows (handlers.refresh_preview);
* after an undo/redo or a file load, for live meshes whose restored pose key was not solved for
  the restored targets (the signature stored in the object tells), so undo and reopening show
  the caught-up pose, and a file whose pose key is up to date is left exactly as it is.

Loading another file is not a catch-up: ``load_pre`` cancels the timer and ends the previews
(handlers.py), because the open file's unsaved state, the pending pose with it, is being
discarded anyway (Blender offers to save first, and that save catches up); the file on disk
keeps what was saved.

Blender has no handler before an export operator: an export run at human speed starts after
the timer has caught up; a script that exports right after moving targets calls
:func:`catch_up_all` first.
"""
import threading
import time

import bpy

from . import preview, scene_index
from .errors import LarapError
from .runtime import _RUNTIMES, runtime
from .solving import key_up_to_date, solve, stored_signature

DELAY = 0.4  # seconds after the last move


def _objects_by_key(keys=()):
    """The file's bound meshes by runtime id. When one of ``keys`` is missing from the kept list
    (scene_index), the file is read again before the caller decides that its mesh is gone (a
    mesh bound or linked in a way no handler was told of)."""
    for fresh in (False, True):
        if fresh:
            scene_index.invalidate()
        out = {}
        for obj in scene_index.bound_meshes(None):
            try:
                if obj.larap.bound and obj.larap.runtime_id:
                    out[obj.larap.runtime_id] = obj
            except ReferenceError:
                continue
        if all(key in out for key in keys):
            break
    return out


def pending():
    """Runtime ids whose pose key is behind what is shown."""
    return {key for key, rt in _RUNTIMES.items() if rt.needs_catchup} | preview.shown_keys()


def request(obj):
    """A live move just happened: catch up DELAY seconds after the last one."""
    rt = runtime(obj)
    if rt is None:
        return
    rt.needs_catchup = True
    rt.last_move = time.monotonic()
    if not bpy.app.timers.is_registered(_timer):
        bpy.app.timers.register(_timer, first_interval=DELAY)


def catch_up(obj):
    """Write the final pose of the current targets now (when it is behind). Never raises (it
    runs from timers and handlers): a failure lands in rt.last_error and the preview ends."""
    rt = runtime(obj)
    if rt is None or not (rt.needs_catchup or preview.showing(obj)):
        return False
    from .session import dragging  # (session imports this module)
    if dragging(obj):  # the drag's confirm or cancel writes or restores the pose key
        return False
    try:
        if obj.mode == "EDIT":
            raise LarapError("%r is in Edit Mode" % obj.name)
        from .handlers import suspend_live
        with suspend_live():
            solve(obj, weights="final", validate="fast")
        return True
    except Exception as exc:  # a timer/handler must never raise
        rt.last_error = "catching up failed: %s" % exc
        rt.needs_catchup = False
        preview.stop(obj)
        print("LARAP:", rt.last_error)
        return False


def catch_up_all(*_args):
    """Catch up every mesh that is behind (main thread only: handlers of threaded jobs skip)."""
    if threading.current_thread() is not threading.main_thread():
        return 0
    keys = list(pending())
    objects = _objects_by_key(keys)
    done = 0
    for key in keys:
        obj = objects.get(key)
        if obj is None:
            preview.forget(key)
            rt = _RUNTIMES.get(key)
            if rt is not None:
                rt.needs_catchup = False
            continue
        done += bool(catch_up(obj))
    return done


def _timer():
    """bpy.app.timers callback: catch up the meshes whose last move is DELAY seconds old;
    returns the time to the next check while some are still moving (None: done)."""
    now = time.monotonic()
    keys = list(pending())
    objects = _objects_by_key(keys)
    wait = None
    for key in keys:
        rt = _RUNTIMES.get(key)
        obj = objects.get(key)
        if obj is None:
            preview.forget(key)
            if rt is not None:
                rt.needs_catchup = False
            continue
        left = DELAY - (now - (rt.last_move if rt is not None else 0.0))
        if left > 1e-3:
            wait = left if wait is None else min(wait, left)
            continue
        catch_up(obj)
    return wait


def cancel_timer():
    if bpy.app.timers.is_registered(_timer):
        bpy.app.timers.unregister(_timer)


def stale_live_objects():
    """Live meshes whose pose key holds a recorded pose of other targets than the current ones
    (after an undo or loading a file saved before the catch-up). A key without a record (older
    files) is left alone."""
    out = []
    for obj in _objects_by_key().values():
        try:
            if obj.larap.live and stored_signature(obj) and not key_up_to_date(obj):
                out.append(obj)
        except Exception:
            continue
    return out


def after_restore():
    """undo_post/redo_post (after runtime.after_undo) and after a file load: live meshes whose
    restored pose key is behind their restored targets catch up now."""
    for obj in stale_live_objects():
        from .runtime import runtime_or_placeholder
        runtime_or_placeholder(obj).needs_catchup = True
        catch_up(obj)


def _after_load_timer():
    after_restore()
    return None


def after_load():
    """load_post: the depsgraph has not evaluated the new file yet; check once it has."""
    if bpy.app.background:
        after_restore()
    elif not bpy.app.timers.is_registered(_after_load_timer):
        bpy.app.timers.register(_after_load_timer, first_interval=0.0)


def setting_turned_off(obj):
    """Live or the preview was switched off: write what is shown now."""
    if obj is not None and getattr(obj, "type", None) == "MESH":
        catch_up(obj)
