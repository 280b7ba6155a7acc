# SPDX-License-Identifier: GPL-3.0-or-later
"""3D View overlay: the lattice of bound meshes and their handle vertices.

What it draws is always true, and says so: the lattice of the pose the mesh shows when the engine
holds it (after a solve, or a cancelled drag, which puts the engine's lattice back), else the rest
lattice, greyed and labelled "rest lattice" (after an undo the engine no longer holds the shown
pose). The lattice is depth-tested
against the mesh (only what is in front shows, like Blender's wireframe overlay) unless Lattice
X-Ray or the viewport's X-Ray is on; a dense lattice is drawn fainter so the model stays readable.
While Pose waits for a click (:func:`set_picking`), the handle vertices are drawn even with the
lattice hidden, and the handle under the cursor is highlighted.
"""
import math

import bpy
import numpy as np

from . import core

# Kept across importlib.reload (F8 / re-enable), so a reload can never orphan a registered callback.
_DRAW_HANDLE = globals().get("_DRAW_HANDLE")
_TEXT_HANDLE = globals().get("_TEXT_HANDLE")
_CACHE = {}  # runtime id -> (cache key, lattice batch, {handle index: batch})
_PICKING = {}  # runtime id -> the handle under the cursor (None: none) while Pose waits for a click
LATTICE_COLOR = (0.2, 0.75, 1.0)
REST_COLOR = (0.85, 0.55, 1.0)  # not the pose's blue, and seen on a grey mesh
HANDLE_COLOR = (1.0, 0.45, 0.05, 0.9)
HOVER_COLOR = (1.0, 0.9, 0.2, 1.0)
MAX_POINTS_PER_HANDLE = 1500  # more are thinned out: points, not a solid blob
REST_LABEL = "LARAP: rest lattice (Solve to see the pose's)"


# ----------------------------------------------------------------------------------------------
# Pose's waiting-for-a-click state (set by modal.py)

def set_picking(obj, hovered):
    _PICKING[obj.larap.runtime_id] = hovered


def picking(obj, default=-2):
    return _PICKING.get(obj.larap.runtime_id, default) if obj is not None else default


def clear_picking(obj=None):
    if obj is None:
        _PICKING.clear()
        return
    try:
        _PICKING.pop(obj.larap.runtime_id, None)
    except ReferenceError:
        pass


# ----------------------------------------------------------------------------------------------
# What is drawn (plain functions: the tests read them without a GPU)

def lattice_state(obj, rt):
    """"pose": the lattice of the pose the mesh shows; "rest": the rest lattice (labelled), the
    engine no longer holding the shown pose (undo, reload); None: no lattice."""
    if rt is None or rt.deformer is None:
        return None
    return "pose" if rt.lattice_current else "rest"


def lattice_alpha(num_cells):
    """Fainter as the lattice gets denser: 0.55 up to 1000 cells, about 0.25 at 5000, never below 0.12."""
    return float(min(0.55, max(0.12, 0.55 * math.sqrt(1000.0 / max(num_cells, 1)))))


def depth_tested(obj, space=None):
    """Lattice drawn only where it is in front of the mesh (False: Lattice X-Ray or viewport X-Ray)."""
    if obj.larap.overlay_xray:
        return False
    shading = getattr(space, "shading", None)
    return not (shading is not None and getattr(shading, "show_xray", False))


def _shader():
    import gpu
    for name in ("UNIFORM_COLOR", "3D_UNIFORM_COLOR"):
        try:
            return gpu.shader.from_builtin(name)
        except (ValueError, TypeError, SystemError):
            continue
    return None


def _thin(points):
    if len(points) <= MAX_POINTS_PER_HANDLE:
        return points
    return points[:: int(math.ceil(len(points) / MAX_POINTS_PER_HANDLE))]


def _batches(obj, rt, shader, want_lattice):
    from gpu_extras.batch import batch_for_shader
    key = obj.larap.runtime_id
    state = lattice_state(obj, rt) if want_lattice else None
    cache_key = (rt.pose_version, state)
    cached = _CACHE.get(key)
    if cached is not None and cached[0] == cache_key:
        return cached[1], cached[2]
    lattice, handles = None, {}
    try:
        if state is not None:
            d = rt.deformer
            nodes = np.asarray(d.lattice_deformed() if state == "pose" else d.lattice_rest(), dtype=np.float32)
            edges = np.asarray(d.lattice_edges(), dtype=np.int64)
            if len(edges):
                lattice = batch_for_shader(shader, "LINES", {"pos": nodes[edges.ravel()]})
    except Exception:  # engine without overlay data: draw the handles only
        lattice = None
    pts, owner = core.handle_points(obj, refresh=False)
    for i in np.unique(owner):
        handles[int(i)] = batch_for_shader(shader, "POINTS", {"pos": _thin(pts[owner == i]).astype(np.float32)})
    _CACHE[key] = (cache_key, lattice, handles)
    return lattice, handles


def _drawn_objects(context):
    for obj in list(getattr(context, "visible_objects", None) or ()):
        try:
            if obj.type != "MESH" or not obj.larap.bound:
                continue
            show = obj.larap.show_overlay
            pick = picking(obj) != -2
            if not (show or pick):
                continue
            rt = core.runtime(obj)  # by the stable runtime id: follows renames
            if rt is None or rt.deformer is None:
                continue
        except (ReferenceError, RuntimeError, AttributeError):
            continue
        yield obj, rt, show, pick


def draw():
    import gpu
    shader = _shader()
    if shader is None:
        return
    space = getattr(bpy.context, "space_data", None)
    for obj, rt, show, pick in _drawn_objects(bpy.context):
        lattice, handles = _batches(obj, rt, shader, show)
        gpu.state.blend_set("ALPHA")
        if lattice is not None:
            gpu.state.depth_test_set("LESS_EQUAL" if depth_tested(obj, space) else "NONE")
            gpu.state.depth_mask_set(False)
            gpu.matrix.push()
            gpu.matrix.multiply_matrix(obj.matrix_world)
            gpu.state.line_width_set(1.0)
            shader.bind()
            rgb = LATTICE_COLOR if lattice_state(obj, rt) == "pose" else REST_COLOR
            shader.uniform_float("color", rgb + (lattice_alpha(rt.deformer.num_cells),))
            lattice.draw(shader)
            gpu.matrix.pop()
        gpu.state.depth_test_set("NONE")  # handle vertices: always seen (they are what you grab)
        hovered = picking(obj, None) if pick else None
        for i, batch in handles.items():
            gpu.state.point_size_set(7.0 if i == hovered else 4.0)
            shader.bind()
            shader.uniform_float("color", HOVER_COLOR if i == hovered else HANDLE_COLOR)
            batch.draw(shader)
        gpu.state.point_size_set(1.0)
        gpu.state.blend_set("NONE")


def draw_labels():
    """POST_PIXEL: name what is drawn when it is not the pose's lattice."""
    import blf
    from bpy_extras.view3d_utils import location_3d_to_region_2d
    region, rv3d = bpy.context.region, getattr(bpy.context, "region_data", None)
    if rv3d is None:
        return
    for obj, rt, show, _pick in _drawn_objects(bpy.context):
        if not show or lattice_state(obj, rt) != "rest":
            continue
        p = location_3d_to_region_2d(region, rv3d, obj.matrix_world.translation)
        if p is None:
            continue
        blf.size(0, 12)
        blf.color(0, 1.0, 1.0, 1.0, 0.9)
        blf.enable(0, blf.SHADOW)
        blf.shadow(0, 3, 0.0, 0.0, 0.0, 0.8)
        blf.position(0, p.x + 12, p.y - 24, 0)
        blf.draw(0, REST_LABEL)
        blf.disable(0, blf.SHADOW)


def register():
    """Also in background mode (the callbacks then never run), so tests see the same lifecycle."""
    global _DRAW_HANDLE, _TEXT_HANDLE
    if _DRAW_HANDLE is None:
        _DRAW_HANDLE = bpy.types.SpaceView3D.draw_handler_add(draw, (), "WINDOW", "POST_VIEW")
    if _TEXT_HANDLE is None:
        _TEXT_HANDLE = bpy.types.SpaceView3D.draw_handler_add(draw_labels, (), "WINDOW", "POST_PIXEL")


def unregister():
    global _DRAW_HANDLE, _TEXT_HANDLE
    for handle in (_DRAW_HANDLE, _TEXT_HANDLE):
        if handle is not None:
            try:
                bpy.types.SpaceView3D.draw_handler_remove(handle, "WINDOW")
            except ValueError:  # already removed
                pass
    _DRAW_HANDLE = _TEXT_HANDLE = None
    _CACHE.clear()
    _PICKING.clear()


def is_registered():
    return _DRAW_HANDLE is not None and _TEXT_HANDLE is not None
