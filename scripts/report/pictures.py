"""The report's pictures: which posed meshes go side by side in which picture (the Workbench
render itself is render_scenes.py, inside Blender), and the 1M-vertex pose they need."""
from __future__ import annotations

import json
import os
import time

import numpy as np

import larap

from . import api, cases, quality_runs, table

GREY, BLUE, ORANGE, GREEN = (0.75, 0.75, 0.75), (0.35, 0.55, 0.85), (0.9, 0.55, 0.25), (0.45, 0.75, 0.45)


def big_pose(work, quick, log):
    """A character of about 1M vertices (armadillo, midpoint-subdivided 3 times; quick: once)
    posed by a drag of 4 steps of 5 flip-flops (each timed, as in the viewport), then converged."""
    mesh = cases.load("armadillo.obj")
    if mesh is None:
        return None, "armadillo.obj not found"
    V, F = cases.subdivide(*mesh, times=1 if quick else 3)
    case = cases.armadillo_case("big", V, F, name="armadillo_big")
    log(f"1M-vertex pose: {len(V)} vertices")
    t0 = time.perf_counter()
    d = larap.Deformer(V, F)
    p = api.Posed(d, V, case.groups)
    bind_ms = (time.perf_counter() - t0) * 1e3
    out = np.empty((len(V), 3), np.float32)
    moves = []
    for T in case.steps:
        t0 = time.perf_counter()
        p.solve(T, 5, out=out)
        moves.append((time.perf_counter() - t0) * 1e3)
    X = p.solve(case.final, 60, tol=1e-6)
    quality_runs.save_rest(work, case)
    quality_runs.save_pose(work, case, "larap_bspline", X)
    row = dict(case=case.name, vertices=len(V), faces=len(F), nodes=d.num_nodes, handles=case.handle_count,
               bind_ms=bind_ms, move_ms_median=float(np.median(moves)), move_ms_max=float(max(moves)))
    return row, None


def specs(work, pics):
    """Picture specs for the posed meshes that exist under work/meshes."""
    m = os.path.join(work, "meshes")

    def have(case, method):
        return os.path.exists(os.path.join(m, f"{case}__{method}.npz"))

    def obj(case, method, offset=(0, 0, 0), color=GREY, rotate_z=0):
        return dict(rest=os.path.join(m, f"{case}__rest.npz"),
                    pose=None if method == "rest" else os.path.join(m, f"{case}__{method}.npz"),
                    offset=list(offset), color=list(color), rotate_z=rotate_z)
    out = []
    if have("bar_bend90", "surface_arap"):
        out.append(dict(out=os.path.join(pics, "fig3_bar_bend90.png"), view=[0, 0.35, -1], size=[1200, 500],
                        objects=[obj("bar_bend90", "rest", (-1, 4.5, 0)),
                                 obj("bar_bend90", "surface_arap", (0, 0, 0), ORANGE),
                                 obj("bar_bend90", "larap_bspline", (5, 0, 0), BLUE)]))
    if have("bar_bend135", "surface_arap"):
        out.append(dict(out=os.path.join(pics, "fig3_bar_bend135_twist180.png"), view=[0, 0.35, -1], size=[1200, 500],
                        objects=[obj("bar_bend135", "surface_arap", (0, 0, 0), ORANGE),
                                 obj("bar_bend135", "larap_bspline", (4.5, 0, 0), BLUE),
                                 obj("bar_twist180", "surface_arap", (-0.5, -3, 0), ORANGE),
                                 obj("bar_twist180", "larap_bspline", (4.5, -3, 0), BLUE)]))
    if have("plate_bend90", "larap_bspline"):
        out.append(dict(out=os.path.join(pics, "fig4_trilinear_vs_bspline.png"), view=[0.3, 0.5, -1], size=[1200, 600],
                        focus=[[0.5, -0.6, 0.0], [3.2, 2.6, 1.6]], objects=[obj("plate_bend90", "larap_trilinear", (0, 0, 0), ORANGE),
                                            obj("plate_bend90", "larap_bspline", (0, 2.0, 0), BLUE)]))
    if have("hand_finger", "larap_bspline"):
        objs = [obj("hand_finger", "rest", (0, 0, 0))]
        if have("hand_finger", "surface_arap"):
            objs.append(obj("hand_finger", "surface_arap", (0.8, 0, 0), ORANGE))
        objs.append(obj("hand_finger", "larap_bspline", (1.6, 0, 0), BLUE))
        out.append(dict(out=os.path.join(pics, "hand_finger.png"), view=[0.5, -0.2, -1], size=[1200, 600],
                        objects=objs))
    if have("truck_multipart", "larap_bspline"):
        out.append(dict(out=os.path.join(pics, "truck_multipart.png"), view=[0.6, 1, -0.5], size=[1200, 600],
                        objects=[obj("truck_multipart", "rest", (0, 0, 0)),
                                 obj("truck_multipart", "larap_bspline", (0, 0, 1.0), BLUE)]))
    char = [c for c in ("armadillo_arm", "armadillo_wave", "armadillo_mix") if have(c, "larap_bspline")]
    if char:
        objs = [obj("armadillo_arm", "rest", (0, 0, 0))] + [obj(c, "larap_bspline", (1.0 * (k + 1), 0, 0), BLUE)
                                                           for k, c in enumerate(char)]
        out.append(dict(out=os.path.join(pics, "character_poses.png"), view=[0, -0.2, -1], size=[1400, 500],
                        objects=objs))
    if have("two_bars", "larap_bspline"):
        out.append(dict(out=os.path.join(pics, "two_bars.png"), view=[0.3, 1, -0.6], size=[1200, 500],
                        objects=[obj("two_bars", "surface_arap", (0, 0, 0), ORANGE),
                                 obj("two_bars", "larap_bspline", (5, 0, 0), BLUE)] if have("two_bars", "surface_arap")
                        else [obj("two_bars", "larap_bspline", (0, 0, 0), BLUE)]))
    if have("armadillo_big", "larap_bspline"):
        out.append(dict(out=os.path.join(pics, "million_vertices.png"), view=[0, -0.2, -1], size=[1000, 600],
                        objects=[obj("armadillo_big", "rest", (0, 0, 0)),
                                 obj("armadillo_big", "larap_bspline", (1.0, 0, 0), BLUE)]))
    return out


def write_specs(path, spec_list):
    with open(path, "w") as f:
        json.dump(spec_list, f, indent=1)


def big_csv(out, row):
    table.write_csv(os.path.join(out, "million_vertices.csv"), [row])
