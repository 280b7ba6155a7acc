# SPDX-License-Identifier: GPL-3.0-or-later
# Fixtures for the add-on tests; run them with
#   blender -b --factory-startup --python-exit-code 1 --python tests/blender/run_tests.py -- [pytest args]
import math
import os

import addon_utils
import bpy
import numpy as np
import pytest

ADDON = "larap_blender"
REPO_ADDON = os.path.realpath(os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "addon"))


def _our_handlers():
    found = []
    for attr in ("depsgraph_update_post", "frame_change_post", "load_post", "undo_post", "redo_post",
                 "undo_pre", "redo_pre", "save_pre", "save_post", "load_pre", "render_init", "render_pre",
                 "object_bake_pre"):
        for h in getattr(bpy.app.handlers, attr):
            if getattr(h, "__module__", "").startswith(ADDON):
                found.append((attr, h.__name__))
    return found


def enable_addon():
    mod = addon_utils.enable(ADDON, default_set=True)
    assert mod is not None, "addon_utils.enable(%r) failed (see the log above)" % ADDON
    # The repo's copy, not one installed in Blender's user add-ons folder by scripts/install_addon.
    assert os.path.realpath(mod.__file__).startswith(REPO_ADDON), mod.__file__
    # addon_utils hides exceptions raised by register(): check that it really registered.
    assert hasattr(bpy.types.Object, "larap"), "register() did not complete"
    assert hasattr(bpy.ops.larap, "bind")
    return mod


def disable_addon():
    addon_utils.disable(ADDON, default_set=True)


@pytest.fixture
def addon():
    bpy.ops.wm.read_factory_settings(use_empty=True)
    mod = enable_addon()
    yield mod
    if ADDON in {a.module for a in bpy.context.preferences.addons}:
        disable_addon()


@pytest.fixture
def core(addon):
    from larap_blender import core as core_module, engine
    if engine.get() is None:
        pytest.fail("LARAP engine unavailable: %s" % engine.error())
    return core_module


@pytest.fixture
def gpu_preview(monkeypatch):
    """The preview path as in a window (lattice-only solves, the object hidden), headless."""
    from larap_blender import preview
    monkeypatch.setattr(preview, "available", lambda: True)
    preview._SHADER[:] = [None, ""]
    return preview


# ------------------------------------------------------------------------------------------------
# Scene helpers

def activate(obj):
    for o in bpy.context.selected_objects:
        o.select_set(False)
    bpy.context.view_layer.objects.active = obj
    obj.select_set(True)


def mesh_object(name, verts, faces=()):
    me = bpy.data.meshes.new(name)
    me.from_pydata([tuple(map(float, v)) for v in verts], [], [tuple(map(int, f)) for f in faces])
    me.update()
    obj = bpy.data.objects.new(name, me)
    bpy.context.scene.collection.objects.link(obj)
    activate(obj)
    return obj


def make_bar(name="Bar", length=4.0, radius=0.25, rings=41, segments=16):
    """A closed tube along X (quads + two n-gon caps), centred at the origin."""
    xs = np.linspace(-length / 2, length / 2, rings)
    ang = np.linspace(0, 2 * math.pi, segments, endpoint=False)
    verts = [(x, radius * math.cos(a), radius * math.sin(a)) for x in xs for a in ang]
    faces = []
    for r in range(rings - 1):
        for s in range(segments):
            a, b = r * segments + s, r * segments + (s + 1) % segments
            faces.append((a, b, b + segments, a + segments))
    faces.append(tuple(reversed(range(segments))))
    faces.append(tuple((rings - 1) * segments + s for s in range(segments)))
    return mesh_object(name, verts, faces)


def coords(obj, key=None):
    me = obj.data
    n = len(me.vertices)
    buf = np.empty(n * 3, dtype=np.float32)
    if key is None:
        me.vertices.foreach_get("co", buf)
    else:
        me.shape_keys.key_blocks[key].data.foreach_get("co", buf)
    return buf.reshape(n, 3).astype(np.float64)


def evaluated_coords(obj):
    dg = bpy.context.evaluated_depsgraph_get()
    dg.update()
    ev = obj.evaluated_get(dg).data
    buf = np.empty(len(ev.vertices) * 3, dtype=np.float32)
    ev.vertices.foreach_get("co", buf)
    return buf.reshape(-1, 3).astype(np.float64)


def diagonal(points):
    return float(np.linalg.norm(points.max(axis=0) - points.min(axis=0)))


def add_group(obj, name, indices):
    vg = obj.vertex_groups.new(name=name)
    vg.add([int(i) for i in indices], 1.0, "REPLACE")
    return vg


def bar_with_handles(core):
    """Bound bar with handles 'Left' (x < -1.8) and 'Right' (x > 1.8) following new Empties."""
    obj = make_bar()
    rest = coords(obj)
    left = np.flatnonzero(rest[:, 0] < -1.8)
    right = np.flatnonzero(rest[:, 0] > 1.8)
    add_group(obj, "Left", left)
    add_group(obj, "Right", right)
    assert bpy.ops.larap.handle_add(vertex_group="Left") == {"FINISHED"}
    assert bpy.ops.larap.handle_add(vertex_group="Right") == {"FINISHED"}
    coarse(obj)
    obj.larap.iterations = 10
    assert bpy.ops.larap.bind() == {"FINISHED"}
    targets = [h.target for h in obj.larap.handles]
    return obj, rest, left, right, targets


def posed_bar(core):
    """bar_with_handles with its Right Empty moved up and turned, solved: (obj, rest, left, right,
    targets, pose), pose the LARAP key's positions."""
    from mathutils import Euler
    obj, rest, left, right, targets = bar_with_handles(core)
    targets[1].location.z += 0.6
    targets[1].rotation_euler = Euler((0.0, math.radians(-30), 0.0))
    bpy.context.view_layer.update()
    assert bpy.ops.larap.solve() == {"FINISHED"}
    pose = coords(obj, "LARAP")
    assert np.abs(pose[right, 2] - rest[right, 2]).max() > 0.3  # really posed
    return obj, rest, left, right, targets, pose


def coarse(obj, cells=1000):
    """A coarser lattice than the engine default keeps the tests quick on small CI machines."""
    obj.larap.resolution_mode = "CELLS"
    obj.larap.cells = cells


def connected_components(obj):
    """Vertex -> component id (union-find over the mesh edges)."""
    me = obj.data
    n = len(me.vertices)
    edges = np.empty(len(me.edges) * 2, dtype=np.int64)
    me.edges.foreach_get("vertices", edges)
    parent = list(range(n))

    def find(a):
        while parent[a] != a:
            parent[a] = parent[parent[a]]
            a = parent[a]
        return a

    for a, b in edges.reshape(-1, 2):
        ra, rb = find(int(a)), find(int(b))
        if ra != rb:
            parent[ra] = rb
    return np.array([find(i) for i in range(n)])


def rigid_fit(p, q):
    """Best rigid (R, t) with q ~ p @ R.T + t."""
    cp, cq = p.mean(axis=0), q.mean(axis=0)
    u, _, vt = np.linalg.svd((p - cp).T @ (q - cq))
    d = np.sign(np.linalg.det(vt.T @ u.T)) or 1.0
    r = vt.T @ np.diag([1.0, 1.0, d]) @ u.T
    return r, cq - cp @ r.T
