"""Time to quality: energy against milliseconds for each solver configuration (single level,
hierarchy of 2 and 3 levels), from a warm pose after one handle move, down to 0.1% of the
converged energy.

Every point of a curve is its own solve: reset, the same warm pose (20 flip-flops), then the
move with k flip-flops; the point is (engine ms of that solve, energy after it). So a point's
time is what a user waits for that quality, coarse levels included. The converged energy E* is
the lowest energy any run reaches (the longest runs: 300 flip-flops, quick 120). Writes
convergence_<device>.csv (the curves) and time_to_quality_<device>.csv (the first k within 0.1%
of E*, and its milliseconds)."""
from __future__ import annotations

import os

import numpy as np

import larap

from . import api, cases, table

KS = (1, 2, 3, 4, 6, 8, 12, 16, 24, 32, 48, 64, 96, 128, 192, 300)


def configs(size):
    if size == "full":
        return [(170_000, 10_000), (2_000_000, 40_000)]
    if size == "quick":
        return [(170_000, 5_000)]
    return [(4_000, 800)]


def points(V, F, groups, nodes, levels, device, ks):
    d = larap.Deformer(V, F, cells=max(8, int(nodes / 1.3)), device=device, levels=levels)
    p = api.Posed(d, V, groups)
    warm, move = cases.torus_move(6), cases.torus_move(12)
    out = np.empty((len(V), 3), np.float32)
    res = []
    for k in ks:
        d.reset()
        p.solve(warm, 20)
        p.solve(move, k, out=out)
        s = d.stats
        res.append(dict(iteration=k, ms=s["ms_total"], energy=s["energy"][-1]))
    return d, p, res


def run(out, size, device="cpu", log=print):
    rows, curves = [], []
    ks = KS if size == "full" else tuple(k for k in KS if k <= (120 if size == "quick" else 32)) + (
        (120,) if size == "quick" else ())
    for faces, nodes in configs(size):
        V, F = cases.torus_with_faces(faces)
        groups = cases.torus_groups(V)
        results = {}
        for levels in (1, 2, 3):
            log(f"time to quality {device}: {faces:,} faces, {nodes:,} nodes, levels {levels}")
            results[levels] = points(V, F, groups, nodes, levels, device, ks)
        e_star = min(pt["energy"] for r in results.values() for pt in r[2])
        for levels, (d, p, pts) in results.items():
            for pt in pts:
                curves.append(dict(device=device, faces=2 * len(F), nodes=d.num_nodes, levels=levels,
                                   handles=p.ids.size, relative=pt["energy"] / e_star - 1.0, **pt))
            hit = next((pt for pt in pts if pt["energy"] <= e_star * (1 + 1e-3)), None)
            rows.append(dict(device=device, faces=2 * len(F), vertices=len(V), nodes=d.num_nodes, levels=levels,
                             handles=p.ids.size, e_star=e_star,
                             iterations_to_quality=hit["iteration"] if hit else "",
                             ms_to_quality=hit["ms"] if hit else "",
                             best_relative=min(pt["energy"] for pt in pts) / e_star - 1.0))
    table.write_csv(os.path.join(out, f"convergence_{device}.csv"), curves)
    table.write_csv(os.path.join(out, f"time_to_quality_{device}.csv"), rows)
    return rows
