"""Quality per method on the same poses: LARAP (B-spline and trilinear transfer) beside surface
ARAP on the full mesh (CGAL, scripts/peers), plus the dihedral change at cell boundaries and the
pose-update speed against surface ARAP at about 500k vertices.

Writes quality.csv, dihedral.csv, speed_vs_surface_arap.csv and meshes/<case>__<method>.npz (the
posed vertices, for the pictures)."""
from __future__ import annotations

import os
import time

import numpy as np

import larap
from larap import quality
from peers import surface_arap

from . import api, cases, table

LARAP_ITER = 30        # flip-flops per drag step (converging; the final step to tol)
FINAL_ITER, FINAL_TOL = 300, 1e-7
CGAL_ITER, CGAL_TOL = 100, 1e-6


def save_pose(out, case, method, X):
    os.makedirs(os.path.join(out, "meshes"), exist_ok=True)
    np.savez(os.path.join(out, "meshes", f"{case.name}__{method}.npz"), X=np.asarray(X, np.float32))


def save_rest(out, case):
    os.makedirs(os.path.join(out, "meshes"), exist_ok=True)
    offsets, indices = larap.faces_to_csr(case.F, len(case.V))
    np.savez(os.path.join(out, "meshes", f"{case.name}__rest.npz"), X=case.V.astype(np.float32),
             offsets=offsets, indices=indices)


def measure(case, X, diag, tris, edge_list):
    row = dict(handle_error=quality.handle_error(X, np.concatenate(case.groups),
                                                 api.targets(case.V, case.groups, case.final), diag),
               volume_change=quality.volume_change(case.V, X, tris))
    dist = quality.edge_distortion(case.V, X, edge_list)
    row.update(edge_mean=dist["mean"], edge_p95=dist["p95"])
    for k, ids in case.still.items():
        row["drag"] = quality.displacement(case.V, X, ids, diag)
        row["drag_of"] = k
    if case.rigid:
        row["rigidity_error"] = quality.rigidity_error(case.V, X, diag)
    return row


def run_larap(case):
    d = larap.Deformer(case.V, case.F, weights="bspline", **({"cells": case.cells} if case.cells else {}))
    p = api.Posed(d, case.V, case.groups)
    t0 = time.perf_counter()
    for T in case.steps[:-1]:
        p.solve(T, LARAP_ITER)
    X = p.solve(case.final, FINAL_ITER, tol=FINAL_TOL)
    ms = (time.perf_counter() - t0) * 1e3
    info = dict(nodes=d.num_nodes, iterations=d.stats["iterations"], ms=ms)
    d.weights = "trilinear"
    Xt = p.solve(case.final, 1)
    return X, Xt, info, d


def run(out, quick, exe, log):
    rows, skipped = [], []
    case_list, missing = cases.quality_cases(quick)
    skipped += missing
    for case in case_list:
        log(f"quality: {case.name} ({len(case.V)} vertices, {case.handle_count} handle vertices)")
        tris, diag = case.tris, quality.diagonal(case.V)
        edge_list = quality.edges(tris)
        save_rest(out, case)
        base = dict(case=case.name, title=case.title, vertices=len(case.V), handles=case.handle_count,
                    groups=len(case.groups), closed=quality.is_closed(tris))
        X, Xt, info, d = run_larap(case)
        for method, Y in (("larap_bspline", X), ("larap_trilinear", Xt)):
            rows.append(dict(base, method=method, nodes=info["nodes"], iterations=info["iterations"],
                             ms=info["ms"], **measure(case, Y, diag, tris, edge_list)))
            save_pose(out, case, method, Y)
        if exe is None:
            continue
        poses = [api.targets(case.V, case.groups, T) for T in case.steps]
        res = surface_arap.deform(exe, case.V, tris, np.concatenate(case.groups), poses, CGAL_ITER, CGAL_TOL,
                                  timeout=600)
        if not res.get("ok"):
            rows.append(dict(base, method="surface_arap", error=res.get("error", "failed")))
            continue
        rows.append(dict(base, method="surface_arap", ms=res["preprocess_ms"] + sum(res["pose_ms"]),
                         skipped_faces=res["skipped_faces"], **measure(case, res["X"][-1], diag, tris, edge_list)))
        save_pose(out, case, "surface_arap", res["X"][-1])
    table.write_csv(os.path.join(out, "quality.csv"), rows)
    return rows, skipped


def dihedral(out, quick, log):
    """Trilinear against B-spline on one lattice pose: a finely meshed plate on a coarse lattice,
    bent 90°; the dihedral change of its flat top face's edges, split into edges whose ends lie in
    different lattice cells ("boundary") and the rest ("inside"). A C0 transfer puts the bend into
    kinks at the cell boundaries; a C1 one spreads it."""
    case = cases.plate_case(24 if quick else 48)
    log(f"dihedral: {len(case.V)} vertices")
    d = larap.Deformer(case.V, case.F, cells=120, weights="trilinear")
    p = api.Posed(d, case.V, case.groups)
    for T in case.steps[:-1]:
        p.solve(T, LARAP_ITER)
    Xt = p.solve(case.final, FINAL_ITER, tol=FINAL_TOL)
    d.weights = "bspline"
    Xb = p.solve(case.final, 1)
    origin, h = d.lattice_rest().min(0), d.cell_size
    cell = np.floor((case.V - origin) / h + 1e-9).astype(np.int64)
    cell_id = (cell[:, 0] * 100003 + cell[:, 1]) * 100003 + cell[:, 2]
    top = np.flatnonzero((case.V[:, 2] > 0.25 - 1e-9) & (case.V[:, 0] > 0.6) & (case.V[:, 0] < 3.4))
    tris = case.tris
    tris = tris[np.all(np.isin(tris, top), axis=1)]
    rows = []
    save_rest(out, case)
    for method, X in (("larap_trilinear", Xt), ("larap_bspline", Xb)):
        r = quality.dihedral_change(case.V, X, tris, cell_of=cell_id)
        rows.append(dict(case=case.name, vertices=len(case.V), nodes=d.num_nodes, cell_size=h, method=method, **r))
        save_pose(out, case, method, X)
    table.write_csv(os.path.join(out, "dihedral.csv"), rows)
    return rows


def speed(out, quick, exe, log):
    """One handle move of a bar of ~500k vertices (quick: ~50k): LARAP's pose update (5 flip-flops
    + transfer, warm) against surface ARAP's deform() with 5 iterations of the same move."""
    seg, rings = (160, 320) if quick else (500, 1000)
    V, F = cases.shapes.tube(length=4.0, radius=0.5, segments=seg, rings=rings)
    case = cases.bar_case("bend90")
    groups = [np.flatnonzero(V[:, 0] <= 0.4), np.flatnonzero(V[:, 0] >= 3.6)]
    T1, T2 = case.steps[0], case.steps[1]
    log(f"speed vs surface ARAP: {len(V)} vertices")
    d = larap.Deformer(V, F)
    p = api.Posed(d, V, groups)
    out_buf = np.empty((len(V), 3), np.float32)
    p.solve(T1, 30, out=out_buf)
    t0 = time.perf_counter()
    p.solve(T2, 5, out=out_buf)
    larap_ms = (time.perf_counter() - t0) * 1e3
    row = dict(vertices=len(V), handles=int(sum(len(g) for g in groups)), nodes=d.num_nodes,
               larap_pose_ms=larap_ms, larap_engine_ms=d.stats["ms_total"])
    if exe is not None:
        tris = quality.triangles(F)
        res = surface_arap.deform(exe, V, tris, np.concatenate(groups),
                                  [api.targets(V, groups, T1), api.targets(V, groups, T2)], 5, 0.0, timeout=900)
        if res.get("ok"):
            row.update(surface_arap_preprocess_ms=res["preprocess_ms"], surface_arap_pose_ms=res["pose_ms"][1],
                       ratio=res["pose_ms"][1] / larap_ms)
        else:
            row.update(surface_arap_error=res.get("error"))
    table.write_csv(os.path.join(out, "speed_vs_surface_arap.csv"), [row])
    return row
