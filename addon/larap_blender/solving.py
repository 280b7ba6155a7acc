# SPDX-License-Identifier: GPL-3.0-or-later
"""One solve: from the handle targets, through the engine, to the pose key.

At each pose: :func:`targets.gather` gives the handle groups and one transform per group; the
runtime gives the engine only what changed (groups, weights, gamma); the engine solves into the
runtime's float32 buffer ``rt.out``; :func:`mesh_data.write_pose` copies it into the pose key
with one ``foreach_set``. :func:`current_pose` is the pose Bake and Apply use.
"""
import time

import numpy as np

from .errors import check_object, engine_errors
from .mesh_data import key_positions, write_pose
from .runtime import ensure_runtime, runtime
from .targets import gather, target_signature

FINAL_TOLERANCE = 1e-5  # relative energy decrease at which a final solve stops


class SolveResult:
    def __init__(self, ms, engine_ms, warnings, weights, handles):
        self.ms = ms
        self.engine_ms = engine_ms
        self.warnings = warnings
        self.weights = weights
        self.handles = handles


def _weights_name(s, which):
    if which in ("trilinear", "bspline"):
        return which
    return s.weights_final if which == "final" else s.weights_interactive


def solve(obj, *, weights="final", validate="full", overrides=None, write=True, tol=None, max_iterations=None):
    """One solve from the current target transforms; writes the pose key. Returns SolveResult.

    ``weights``: "final", "interactive" or a weights name; ``validate``: see ensure_runtime;
    ``overrides``: {(target name, bone): world matrix} (a drag in progress). A final solve
    iterates until the energy changes by less than ``tol`` (default FINAL_TOLERANCE) relative,
    at most ``max_iterations`` times (default max(30, 10 x the object's iterations))."""
    check_object(obj, need_bound=True)
    s = obj.larap
    t0 = time.perf_counter()
    rt = ensure_runtime(obj, validate)
    d = rt.deformer
    pose = gather(obj, rt, overrides)
    warnings = pose.warnings
    wname = _weights_name(s, weights)
    engine_ms = 0.0
    with engine_errors("Solve failed"):
        if pose.count == 0:
            warnings.append("no usable handles: rest pose written")
            np.copyto(rt.out, rt.rest)
        else:
            rt.set_engine_state(pose, wname, float(s.gamma))
            if weights == "final":
                # The final pose converges (up to 10x the interactive iterations), so solving
                # again from the same targets gives the same pose.
                cap = max(30, 10 * int(s.iterations)) if max_iterations is None else int(max_iterations)
                d.solve(transforms=pose.transforms, iterations=cap, out=rt.out,
                        tol=FINAL_TOLERANCE if tol is None else float(tol))
            else:
                d.solve(transforms=pose.transforms, iterations=int(s.iterations), out=rt.out)
            stats = dict(d.stats)
            rt.stats = stats
            engine_ms = float(stats.get("ms_total", 0.0))
    rt.weights = wname
    rt.lattice_current = True
    if write:
        write_pose(obj, rt.out)
    rt.pose_version += 1
    rt.last_ms = (time.perf_counter() - t0) * 1e3
    rt.last_error = ""
    rt.warnings = warnings
    rt.target_sig = target_signature(obj) if not overrides else None
    return SolveResult(rt.last_ms, engine_ms, warnings, wname, pose.count)


def current_pose(obj):
    """The pose to bake/apply: the pose key as it is when it is up to date (solved with the final
    weights from the current target transforms, so what you see is what you get), else a new solve
    with the final weights. Returns (n,3) float32."""
    check_object(obj, need_bound=True)
    s = obj.larap
    rt = ensure_runtime(obj, "full")
    posed = key_positions(obj, s.shape_key)
    if (posed is not None and rt.target_sig is not None and rt.weights == s.weights_final
            and rt.target_sig == target_signature(obj)):
        return posed
    solve(obj, weights="final", validate="fast")
    return runtime(obj).out.copy()
