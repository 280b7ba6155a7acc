# SPDX-License-Identifier: GPL-3.0-or-later
"""The add-on's error vocabulary, said once: what a user is told, and the checks that tell it.

* :class:`LarapError` is a failure to report to the user (operators turn it into a report, the
  live handler into ``Runtime.last_error``); :class:`TopologyChanged` is the one kind callers
  tell apart.
* :func:`engine_errors` translates the engine's exceptions into LarapError, once, here.
* :func:`check_object` is the first line of every operation on an object.
"""
import contextlib

from . import engine

ENGINE_ERRORS = (ValueError, MemoryError, RuntimeError, TypeError)


class LarapError(Exception):
    """A failure to report to the user (no traceback)."""


class TopologyChanged(LarapError):
    pass


def memory_message(engine_text):
    """The engine's MemoryError in the panel's words: what would not fit, and the settings of the
    panel that lower it (the engine names its Python keywords, which the panel does not show)."""
    what = engine_text.split(";")[0].strip() or "the lattice is too large"
    if what.startswith("cell splitting"):
        return "out of memory (%s); use fewer Cells or a larger Cell Size, or turn off Parts Apart" % what
    return "out of memory (%s); use fewer Cells or a larger Cell Size" % what


def check_object(obj, *, need_bound=False, allow_edit_mode=False, bind=False):
    if obj is None:
        raise LarapError("No active object")
    try:
        obj_type = obj.type
    except ReferenceError:
        raise LarapError("The object was deleted")
    if obj_type != "MESH":
        raise LarapError("LARAP works on meshes; %r is a %s" % (obj.name, obj_type.lower()))
    if obj.library is not None or obj.data.library is not None:
        raise LarapError("%r is linked from a library and not editable (make it local or override it)" % obj.name)
    if obj.mode == "EDIT" and not allow_edit_mode:
        raise LarapError("%r is in Edit Mode; switch to Object Mode first" % obj.name)
    if need_bound and not obj.larap.bound:
        raise LarapError("%r is not bound; use LARAP > Bind first" % obj.name)
    if need_bound or bind:
        others = bound_sharing(obj)
        if others:
            raise LarapError(
                "%r shares its mesh data with %s, which LARAP also poses (a linked duplicate, Alt+D): the pose "
                "key is the mesh's, so each would overwrite the other's pose. Unbind one of them, or give this "
                "one its own mesh (Object > Relations > Make Single User > Object & Data)"
                % (obj.name, ", ".join(repr(o.name) for o in others[:3])))
    return obj


def bound_sharing(obj):
    """The other bound mesh objects in some scene that use ``obj``'s mesh data (Alt+D duplicates)."""
    me = obj.data
    if me.users < 2:
        return []
    from . import scene_index
    found = []
    for other in scene_index.bound_meshes(None):
        try:
            # (one in no scene, which the artist cannot select to unbind, poses nothing either)
            if other != obj and other.data == me and scene_index.target_alive(other):
                found.append(other)
        except ReferenceError:
            continue
    return found


def require_engine():
    """The compiled ``larap`` module, or LarapError saying why it could not be loaded."""
    mod = engine.get()
    if mod is None:
        raise LarapError(engine.error())
    return mod


@contextlib.contextmanager
def engine_errors(what):
    """Turn engine exceptions into LarapError with the engine's message."""
    try:
        yield
    except LarapError:
        raise
    except MemoryError as exc:
        raise LarapError("%s: %s" % (what, memory_message(str(exc))))
    except ENGINE_ERRORS as exc:
        raise LarapError("%s: %s" % (what, exc))
