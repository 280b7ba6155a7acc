#!/usr/bin/python3
"""CPU benchmark in the shape of the paper's Table 1: milliseconds per stage for meshes of
~17k..2M faces on lattices of ~5k..40k nodes.

    PYTHONPATH=python /usr/bin/python3 scripts/bench.py [--quick] [--record docs/results.md]

A pose update = 5 flip-flop iterations from a warm start after a handle move, plus the transfer
of the lattice deformation to every vertex. Times are medians of --repeat runs.
"""
from __future__ import annotations

import argparse
import datetime
import os
import statistics
import time

import numpy as np

import larap
import machine_info
from larap import shapes


def mesh_with_faces(faces_wanted: int):
    """A torus of about `faces_wanted` quads (each quad = 2 triangles in the paper's count)."""
    quads = faces_wanted // 2
    n_minor = max(8, int(np.sqrt(quads / 3.0)))
    n_major = max(8, quads // n_minor)
    return shapes.torus(1.0, 0.35, n_major, n_minor)


def run(faces, nodes, repeat, device="cpu"):
    V, F = mesh_with_faces(faces)
    # cells ~ nodes / 1.3 for solid lattices of this shape; adjust once.
    cells = int(nodes / 1.3)
    t0 = time.perf_counter()
    d = larap.Deformer(V, F, cells=cells, weights="trilinear", device=device)
    t_build = (time.perf_counter() - t0) * 1e3
    s = d.stats
    # Handles: two opposite sectors of the torus; one turns about z and lifts.
    ang = np.arctan2(V[:, 1], V[:, 0])
    a = np.flatnonzero(np.abs(ang) < 0.05)
    b = np.flatnonzero(np.abs(np.abs(ang) - np.pi) < 0.05)
    idx = np.concatenate([a, b])
    d.set_handles(idx)
    ms_factor = d.stats["ms_factorize"]
    out = np.empty((len(V), 3), np.float32)
    rows = []
    for r in range(repeat + 1):
        lift = 0.05 * (r + 1)
        T = np.concatenate([V[a], V[b] + [0, 0, lift]])
        d.solve(T, 5, out=out)  # warm start after a small handle move
        if r:
            rows.append(dict(d.stats))
    med = {k: statistics.median(x[k] for x in rows) for k in
           ("ms_rotations", "ms_rhs", "ms_solve", "ms_transfer", "ms_total", "ms_energy", "ms_start")}
    d.weights = "bspline"
    t0 = time.perf_counter()
    d.solve(T, 5, out=out)
    bsp_transfer = d.stats["ms_transfer"]
    return dict(faces=2 * len(F), vertices=len(V), nodes=d.num_nodes, cells=d.num_cells,
                build=t_build, lattice=s["ms_lattice"], binding=s["ms_binding"], factorize=ms_factor,
                bspline_transfer=bsp_transfer, **med)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--quick", action="store_true", help="small configurations only")
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--record", help="append the table to this markdown file")
    args = ap.parse_args()
    configs = [(17_000, 5_000), (170_000, 10_000), (1_700_000, 20_000), (2_000_000, 10_000), (2_000_000, 40_000)]
    if args.quick:
        configs = [(17_000, 5_000), (170_000, 10_000)]
    head = ("| faces | vertices | nodes | lattice ms | binding ms | factorize ms | rotations ms (5 it) | "
            "rhs ms | solve ms | energy ms | start ms | transfer ms (tri) | pose update ms | transfer ms (B-spline) |")
    lines = [head, "|" + "---|" * 14]
    for faces, nodes in configs:
        r = run(faces, nodes, args.repeat)
        line = (f"| {r['faces']:,} | {r['vertices']:,} | {r['nodes']:,} | {r['lattice']:.0f} | {r['binding']:.0f} | "
                f"{r['factorize']:.0f} | {r['ms_rotations']:.1f} | {r['ms_rhs']:.1f} | {r['ms_solve']:.1f} | "
                f"{r['ms_energy']:.1f} | {r['ms_start']:.1f} | {r['ms_transfer']:.1f} | {r['ms_total']:.1f} | {r['bspline_transfer']:.1f} |")
        lines.append(line)
        print(line, flush=True)
    meta = (f"{datetime.date.today()} — {machine_info.cpu_model()}, {os.cpu_count()} cores, {larap.num_threads()} engine threads "
            f"(oneTBB), simplicial CHOLMOD, device cpu")
    print(meta)
    if args.record:
        with open(args.record, "a") as f:
            f.write(f"\n### CPU pose update ({meta})\n\n" + "\n".join(lines) + "\n")


if __name__ == "__main__":
    main()
