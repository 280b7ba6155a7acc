# SPDX-License-Identifier: GPL-3.0-or-later
"""Live mode and the application handlers.

Live: when a handle target moves (G/R/S, drivers, constraints, animation), the meshes it drives
solve again with the interactive weights (:func:`live_update`, from ``depsgraph_update_post`` and
``frame_change_post``): with the preview (preview.py), only the lattice is posed and drawn, and
the mesh data catches up once the moves pause (catchup.py); without it, the pose key is written
at each move (and converged once they pause). A mesh being dragged (session.py) is left to its
drag: each drag step solves once. While a render job runs, a frame change writes the final pose
directly. :func:`suspend_live` holds Live off while LARAP itself steps frames or writes (bake).
A change the preview cannot draw (mixed shading, a modifier), made while it shows a mesh, ends
the preview at the update that reports it (:func:`refresh_preview`: the mesh catches up).

The other handlers keep the runtime cache and the mesh data true to the file: ``load_post``
drops the cache, ``undo_post``/``redo_post`` make it re-validate (runtime.after_undo); both end
any preview and catch up live meshes restored behind their targets; ``save_pre``,
``render_init``/``render_pre`` and ``object_bake_pre`` catch up first. The bound meshes of the
scene and the targets' presence are read from scene_index, which these handlers tell when they
may have changed (a reported Scene or Collection, undo, redo, load), so an update does not look at
every object of the file.
"""
import contextlib

import bpy
from bpy.app.handlers import persistent

from . import catchup, preview, scene_index
from .errors import LarapError
from .props import SETTINGS_VERSION, upgrade_settings
from .runtime import after_undo, drop_runtime, runtime, runtime_or_placeholder
from .session import dragging
from .solving import key_up_to_date, solve
from .targets import handle_problems, target_names, target_signature

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


def rendering():
    """A render job runs (F12, animation render): frames must hold their final pose."""
    is_job_running = getattr(bpy.app, "is_job_running", None)  # Blender 3.3+
    try:
        return bool(is_job_running and is_job_running("RENDER"))
    except (TypeError, ValueError):
        return False


def _live_solve(obj, rt, sig, render):
    """One live step for ``obj`` whose targets moved; returns whether the engine solved."""
    if (rt is None or rt.target_sig is None) and not (rt is not None and rt.needs_catchup) \
            and key_up_to_date(obj):
        # First look after a load, an undo or a cancel: the pose key already holds the pose of
        # these targets (moving nothing changes nothing).
        runtime_or_placeholder(obj).target_sig = sig
        return False
    if render:
        solve(obj, weights="final", validate="fast")
        return True
    if not preview.blocker(obj):
        posed = solve(obj, weights="interactive", validate="fast", lattice_only=True)
        # (no usable handle: the rest pose was written, and there is nothing to draw instead)
        if posed.handles > 0 and not preview.show(obj):  # cannot hide it: write what it would show
            solve(obj, weights="interactive", validate="fast")
    else:
        solve(obj, weights="interactive", validate="fast")
    catchup.request(obj)
    return True


def live_update(scene, updated_names=None):
    """Re-solve every live, bound mesh of ``scene`` whose targets moved. ``updated_names``: the
    objects the depsgraph reported (None: check all). Never raises; errors land in rt.last_error."""
    if live_suspended():
        return 0
    solved = 0
    render = rendering()
    with suspend_live():
        meshes = list(scene_index.bound_meshes(scene))
        new = scene_index.take_new(scene)  # found since the last look: their targets may have moved unseen
        for obj in meshes:
            try:
                if obj.type != "MESH" or not obj.larap.bound or not obj.larap.live:
                    continue
            except ReferenceError:
                continue
            targets = target_names(obj)
            if updated_names is not None and not (targets & updated_names) and obj.as_pointer() not in new:
                continue
            rt = runtime(obj)
            sig = target_signature(obj)
            if rt is not None and rt.target_sig is not None and rt.target_sig == sig:
                continue
            if dragging(obj):  # the drag solves each of its steps itself
                continue
            try:
                if obj.mode == "EDIT":
                    continue
                solved += _live_solve(obj, rt, sig, render)
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
    skipped. Meshes the update changed (an edit, Shade Smooth/Flat, the catch-up's write) have
    their faces' shading read again for the preview, here rather than at the next move, and a
    preview that can no longer draw a reported object ends here (:func:`refresh_preview`)."""
    if depsgraph is None:
        return
    updated, meshes, objects = set(), set(), []
    try:
        for update in depsgraph.updates:
            try:
                idd = update.id
                if isinstance(idd, bpy.types.Object):
                    obj = idd.original
                    updated.add(obj.name_full)
                    if obj.type == "MESH":
                        objects.append(obj)
                elif isinstance(idd, bpy.types.Mesh):
                    meshes.add(idd.original.as_pointer())
                else:
                    scene_index.note_updated(idd)
            except ReferenceError:
                scene_index.invalidate()
                continue
    except ReferenceError:
        scene_index.invalidate()
        return
    if objects:  # an object appended from an older file shows and solves with its own Stiffness
        upgrade_all_settings(objects)
    if meshes:
        preview.meshes_changed(meshes)
    if live_suspended():
        return
    if updated:
        live_update(scene, updated)
    if objects:
        refresh_preview(objects, meshes)


def refresh_preview(objects, meshes):
    """The preview after an update, for the mesh objects it reported (``objects``; Blender reports
    a changed mesh's objects with it, ``meshes`` being the pointers of the meshes it reported),
    those bound and with the preview on; the rest of the scene is not looked at. Never raises.

    * One the preview shows that it can no longer draw as Blender would (a script set a few faces
      of a smooth mesh flat, a modifier was added: :func:`preview.blocker` gives a reason) catches
      up now (catchup.catch_up: the mesh is written with the final pose of the current targets
      and shown again), as a live move would have written it, rather than being drawn wrongly
      until the next move or the catch-up timer. A mesh being dragged is left to its drag, whose
      next step asks the blocker itself (and confirm or cancel write or restore the pose key).
    * A live mesh whose faces changed has their shading read now, so the next live move reads
      nothing per face (preview.face_shading). Only where everything else lets the preview draw
      (the blocker stops before the faces otherwise: a mesh written at each move is not read
      again at each move). Not in Edit Mode, whose edits reach the mesh when it is left."""
    for obj in objects:
        try:
            s = obj.larap
            if not s.bound or not s.preview or obj.data is None or obj.mode == "EDIT" or dragging(obj):
                continue
            if preview.showing(obj):
                if preview.blocker(obj):
                    catchup.catch_up(obj)
            elif s.live and obj.data.as_pointer() in meshes and preview.shading_stale(obj):
                preview.blocker(obj)
        except (ReferenceError, AttributeError, RuntimeError):
            continue


@persistent
def larap_frame_change_post(scene, depsgraph=None):
    """Animated targets: depsgraph_update_post does not fire on frame changes, so what the frame's
    evaluation reports (a mesh linked by a script or another add-on's frame_change_pre) is told
    to scene_index here."""
    if depsgraph is not None:
        scene_index.note_evaluated(depsgraph)
    if not live_suspended():
        live_update(scene, None)


@persistent
def larap_load_pre(*_args):
    """Another file replaces this one: no preview or pending catch-up carries over. Nothing is
    caught up here: the open file's unsaved state (a pending pose too) is being discarded, and a
    save offered first went through save_pre, which caught up."""
    scene_index.forget_all()
    catchup.cancel_timer()
    preview.reset_all()


def upgrade_all_settings(objects=None):
    """props.upgrade_settings for every mesh object of ``objects`` (default: the file's); one
    that fails is reported and skipped. Never raises."""
    for obj in list(bpy.data.objects) if objects is None else objects:
        try:
            if obj.type == "MESH" and obj.larap.settings_version < SETTINGS_VERSION:
                upgrade_settings(obj.larap)
        except Exception as exc:  # a handler must never raise
            print("LARAP: could not bring the settings of %r up to date: %s" % (getattr(obj, "name", "?"), exc))


@persistent
def larap_load_post(*_args):
    """A new file: pointers and data changed; engines are rebuilt lazily from the stored settings.
    Objects saved hidden behind a preview (an autosave) are shown again, and live meshes whose
    pose key was saved behind their targets catch up; an up-to-date file is left as it is.
    Settings stored by an older version are brought up to date first, keeping their pose
    (props.upgrade_settings), so that the catch-up compares like with like."""
    scene_index.forget_all()
    upgrade_all_settings()
    drop_runtime()
    preview.reset_all()
    catchup.after_load()


@persistent
def larap_undo_post(*_args):
    """Undo/redo replaced the mesh, keys, settings and targets with a stored state: the cached
    engines re-validate and forget their warm start; objects stored hidden behind a preview are
    shown again; live meshes whose restored pose key is behind their restored targets catch up
    (the same targets give the same pose, so undo shows the caught-up pose)."""
    scene_index.forget_all()
    after_undo()
    upgrade_all_settings()  # a step stored before an older object's upgrade
    refresh_warnings_after_undo()
    preview.reset_all()
    with suspend_live():
        catchup.after_restore()


def refresh_warnings_after_undo():
    """The panel's warnings describe the restored state, not the undone one: an error is dropped
    unless its cause (a topology change) is still there, and the handle warnings are re-read from
    the restored settings (nothing is solved or written here)."""
    for obj in list(bpy.data.objects):
        try:
            if obj.type != "MESH" or not obj.larap.bound:
                continue
            rt = runtime(obj)
            if rt is None:
                continue
            if len(obj.data.vertices) == obj.larap.bind_vertex_count or "topology" not in rt.last_error:
                rt.last_error = ""
            rt.warnings = handle_problems(obj)
        except (ReferenceError, AttributeError):
            continue


@persistent
def larap_before_swap(*_args):
    """undo_pre/redo_pre: the objects held between updates (scene_index) are about to be
    replaced; nothing reads them until they are found again."""
    scene_index.forget_all()


@persistent
def larap_catch_up(*_args):
    """save_pre, render_init/render_pre, object_bake_pre: the mesh data holds the pose first."""
    with suspend_live():
        catchup.catch_up_all()


_HANDLERS = (
    ("depsgraph_update_post", larap_depsgraph_update_post),
    ("frame_change_post", larap_frame_change_post),
    ("load_pre", larap_load_pre),
    ("load_post", larap_load_post),
    ("undo_pre", larap_before_swap),
    ("redo_pre", larap_before_swap),
    ("undo_post", larap_undo_post),
    ("redo_post", larap_undo_post),
    ("save_pre", larap_catch_up),
    ("render_init", larap_catch_up),
    ("render_pre", larap_catch_up),
    ("object_bake_pre", larap_catch_up),
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
    catchup.cancel_timer()
    for attr, func in _HANDLERS:
        _remove_ours(getattr(bpy.app.handlers, attr), func)
