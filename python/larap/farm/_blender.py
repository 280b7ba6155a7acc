"""Shared by the scripts that run inside headless Blender (blender_chunk.py, blender_bind.py):
their arguments after ``--``, and the LARAP add-on enabled with a clear error when it cannot be."""
from __future__ import annotations

import hashlib
import json
import os
import sys

ADDON = "larap_blender"


def script_argv(argv=None) -> list:
    argv = sys.argv if argv is None else argv
    return list(argv[argv.index("--") + 1:]) if "--" in argv else []


def enable_addon(addon_path=None):
    """Enable the add-on (already enabled by ``--addons larap_blender``, or importable from
    ``addon_path`` / sys.path) and return its ``core`` module; RuntimeError when that fails."""
    import addon_utils
    import bpy
    if addon_path:
        addon_path = os.path.abspath(addon_path)
        if addon_path not in sys.path:
            sys.path.insert(0, addon_path)
    if not hasattr(bpy.types.Object, "larap"):
        errors = []
        addon_utils.enable(ADDON, default_set=False, handle_error=errors.append)
        if errors or not hasattr(bpy.types.Object, "larap"):
            raise RuntimeError(f"could not enable the {ADDON} add-on ({errors[0] if errors else 'not found'}); "
                               f"install it (scripts/install_addon) or pass --addon-path")
    from larap_blender import core, engine
    if engine.get() is None:
        raise RuntimeError(engine.error())
    return core


def find_objects(names):
    """The named mesh objects of the open file; RuntimeError naming the ones that are missing."""
    import bpy
    missing = [n for n in names if n not in bpy.data.objects]
    if missing:
        raise RuntimeError(f"{bpy.data.filepath or 'the file'} has no object named "
                           + ", ".join(repr(n) for n in missing))
    return [bpy.data.objects[n] for n in names]


def final_solve(core, obj, tol=None, max_iterations=None, from_rest=True):
    """The add-on's final solve of ``obj`` at this frame, from rest (or, ``from_rest=False``,
    warm-started from the previous frame's pose), to ``tol`` (relative energy change) in at most
    ``max_iterations`` flip-flops (None: the add-on's defaults); the pose stays in
    core.runtime(obj).out (nothing is written to the file)."""
    return core.solve(obj, weights="final", validate="fast", write=False, tol=tol, max_iterations=max_iterations,
                      from_rest=from_rest)


def bind_state(core, obj) -> str:
    """A fingerprint (SHA-256) of what ``obj`` is bound to, as the engine of this process built it:
    the rest shape and face topology the lattice was built on, the lattice resolution, the
    stiffness and final weights, and each handle's group (its vertices and weights), target, rest
    matrix, weight and switch. Chunks of one bake must agree on it (the merge checks): it catches
    farm machines whose add-on binds the same file differently. Call after a solve (the handle
    groups are read by it)."""
    rt = core.runtime(obj)
    s = obj.larap
    state = {"rest": rt.rest_hash, "topology": rt.topology, "bind_topology": s.bind_topology,
             "vertices": s.bind_vertex_count, "lattice": [str(v) for v in (rt.settings_sig or ())[:-1]],
             "gamma": rt.engine_gamma if rt.engine_gamma is not None else float(s.gamma),
             "weights": s.weights_final, "groups": rt.membership_hash,
             "handles": [[h.vertex_group, h.target.name if h.target else "", h.subtarget, [float(v) for v in h.rest_matrix],
                          float(h.weight), bool(h.enabled)] for h in s.handles]}
    return hashlib.sha256(json.dumps(state, sort_keys=True).encode("utf-8")).hexdigest()
