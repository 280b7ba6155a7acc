# SPDX-License-Identifier: GPL-3.0-or-later
"""3D View overlay: the deformed lattice (edges) and the handle vertices of bound meshes."""
import bpy
import numpy as np

from . import core

# Kept across importlib.reload (F8 / re-enable), so a reload can never orphan a registered callback.
_DRAW_HANDLE = globals().get("_DRAW_HANDLE")
_CACHE = {}  # runtime id -> (pose_version, lattice batch, handle batch)
LATTICE_COLOR = (0.2, 0.75, 1.0, 0.55)
HANDLE_COLOR = (1.0, 0.45, 0.05, 1.0)


def _shader():
    import gpu
    for name in ("UNIFORM_COLOR", "3D_UNIFORM_COLOR"):
        try:
            return gpu.shader.from_builtin(name)
        except (ValueError, TypeError, SystemError):
            continue
    return None


def _batches(obj, rt, shader):
    from gpu_extras.batch import batch_for_shader
    key = obj.larap.runtime_id
    cached = _CACHE.get(key)
    if cached is not None and cached[0] == rt.pose_version:
        return cached[1], cached[2]
    lattice = handles = None
    try:
        if not rt.lattice_current:  # e.g. after an undo or a cancelled drag: no stale lattice
            raise LookupError
        d = rt.deformer
        nodes = np.asarray(d.lattice_deformed(), dtype=np.float32)
        edges = np.asarray(d.lattice_edges(), dtype=np.int64)
        if len(edges):
            lattice = batch_for_shader(shader, "LINES", {"pos": nodes[edges.ravel()]})
    except Exception:  # engine without overlay data: draw the handles only
        lattice = None
    pts, _owner = core.handle_points(obj, refresh=False)
    if len(pts):
        handles = batch_for_shader(shader, "POINTS", {"pos": pts.astype(np.float32)})
    _CACHE[key] = (rt.pose_version, lattice, handles)
    return lattice, handles


def draw():
    import gpu
    shader = _shader()
    if shader is None:
        return
    for obj in list(getattr(bpy.context, "visible_objects", None) or ()):
        try:
            if obj.type != "MESH" or not obj.larap.bound or not obj.larap.show_overlay:
                continue
            rt = core.runtime(obj)  # by the stable runtime id: follows renames
            if rt is None or rt.deformer is None:
                continue
        except (ReferenceError, RuntimeError, AttributeError):
            continue
        lattice, handles = _batches(obj, rt, shader)
        gpu.state.blend_set("ALPHA")
        gpu.state.depth_test_set("NONE")
        if lattice is not None:
            gpu.matrix.push()
            gpu.matrix.multiply_matrix(obj.matrix_world)
            gpu.state.line_width_set(1.0)
            shader.bind()
            shader.uniform_float("color", LATTICE_COLOR)
            lattice.draw(shader)
            gpu.matrix.pop()
        if handles is not None:
            gpu.state.point_size_set(6.0)
            shader.bind()
            shader.uniform_float("color", HANDLE_COLOR)
            handles.draw(shader)
        gpu.state.blend_set("NONE")


def register():
    """Also in background mode (the callback then never runs), so tests see the same lifecycle."""
    global _DRAW_HANDLE
    if _DRAW_HANDLE is not None:
        return
    _DRAW_HANDLE = bpy.types.SpaceView3D.draw_handler_add(draw, (), "WINDOW", "POST_VIEW")


def unregister():
    global _DRAW_HANDLE
    if _DRAW_HANDLE is not None:
        try:
            bpy.types.SpaceView3D.draw_handler_remove(_DRAW_HANDLE, "WINDOW")
        except ValueError:  # already removed
            pass
        _DRAW_HANDLE = None
    _CACHE.clear()


def is_registered():
    return _DRAW_HANDLE is not None
