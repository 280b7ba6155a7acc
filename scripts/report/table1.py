"""The paper's Table 1, reproduced: per-stage milliseconds of a pose update for meshes of ~17k to
2M faces on lattices of ~5k to 40k nodes, single level and hierarchy (levels=2), on one device.

Mesh: generated tori of the given triangle count (quads counted as two, as scripts/bench.py);
handles: three vertex groups (6% of the vertices: one held, one lifted and turned, one nudged),
moved by one transform each. A pose update = 5 flip-flop iterations warm-started after a small
move of the groups + the trilinear transfer into a float32 array (what Blender receives); the
engine's per-stage times (stats) are medians over `repeat` updates. Writes table1_<device>.csv."""
from __future__ import annotations

import os
import statistics
import time

import numpy as np

import larap

from . import api, cases, table

# The paper's figures as this project quotes them (docs/results.md): total ms of a pose update.
PAPER = {(1_700_000, 10_000): "GPU 45 ms (GTX 580)", (2_000_000, 10_000): "CPU 142 ms (8 threads)",
         (2_000_000, 40_000): "GPU 71 ms hierarchy, 222 ms single level"}

FULL = [(17_000, 5_000), (17_000, 10_000), (170_000, 10_000), (1_700_000, 10_000), (2_000_000, 10_000),
        (2_000_000, 5_000), (2_000_000, 20_000), (2_000_000, 40_000)]
QUICK = [(17_000, 2_500), (17_000, 5_000), (170_000, 5_000)]
TINY = [(4_000, 800)]
STAGES = ("ms_rotations", "ms_rhs", "ms_solve", "ms_energy", "ms_start", "ms_coarse", "ms_transfer", "ms_total")


def one(faces, nodes, levels, device, repeat):
    V, F = cases.torus_with_faces(faces)
    groups = cases.torus_groups(V)
    t0 = time.perf_counter()
    d = larap.Deformer(V, F, cells=max(8, int(nodes / 1.3)), weights="trilinear", device=device, levels=levels)
    build_ms = (time.perf_counter() - t0) * 1e3
    bind = dict(d.stats)
    p = api.Posed(d, V, groups)
    factor_ms = d.stats.get("ms_factorize", float("nan"))
    out = np.empty((len(V), 3), np.float32)
    p.solve(cases.torus_move(1), 5, out=out)
    stats, wall = [], []
    for r in range(repeat):
        t0 = time.perf_counter()
        p.solve(cases.torus_move(2 + r), 5, out=out)
        wall.append((time.perf_counter() - t0) * 1e3)
        stats.append(dict(d.stats))
    row = dict(device=device, faces_target=faces, nodes_target=nodes, faces=2 * len(F), vertices=len(V),
               nodes=d.num_nodes, levels=levels, handles=p.ids.size, handle_groups=len(groups),
               handle_percent=100.0 * p.ids.size / len(V), api=api.name(d), build_ms=build_ms,
               lattice_ms=bind.get("ms_lattice"), binding_ms=bind.get("ms_binding"), factorize_ms=factor_ms,
               iterations=5, wall_ms=statistics.median(wall))
    for k in STAGES:
        row[k[3:] + "_ms"] = statistics.median(s.get(k, 0.0) for s in stats)
    row["paper"] = PAPER.get((faces, nodes), "")
    return row


def run(out, size, device="cpu", log=print, repeat=5):
    configs = {"full": FULL, "quick": QUICK, "tiny": TINY}[size]
    rows = []
    for faces, nodes in configs:
        for levels in (1, 2):
            log(f"table1 {device}: {faces:,} faces, {nodes:,} nodes, levels {levels}")
            rows.append(one(faces, nodes, levels, device, repeat if size != "tiny" else 2))
    table.write_csv(os.path.join(out, f"table1_{device}.csv"), rows)
    return rows
