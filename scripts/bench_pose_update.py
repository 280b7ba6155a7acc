#!/usr/bin/env python3
"""The pose update against another checkout (issue 9's cost bound: a pose update within 10% of
the tree before): 5 flip-flops + the trilinear transfer into a float32 array (as the add-on
writes it), and the lattice alone (`pose_lattice`, what the GPU preview reads), on tori of 0.5M
and 1M vertices at the default resolution and at four times the cells, two vertex groups holding
about 11% of the vertices (one held, one lifted a little more at every pose, as a drag). Each tree
in its own process, the trees alternating, median over the poses, best of the rounds.

Run: /usr/bin/python3 scripts/bench_pose_update.py --other CHECKOUT [--device cuda] [--rounds 2]"""
import argparse
import os

import machine_info
from tree_child import run_child

CHILD = r'''
import json, sys, time
import numpy as np, larap
from larap import shapes
n_major, n_minor, cells, device = int(sys.argv[1]), int(sys.argv[2]), int(sys.argv[3]), sys.argv[4]
V, F = shapes.torus(1.0, 0.35, n_major, n_minor)
d = larap.Deformer(V, F, device=device, **({"cells": cells} if cells else {}))
ang = np.arctan2(V[:, 1], V[:, 0])
a, b = np.flatnonzero(ang < -2.8), np.flatnonzero(np.abs(ang) < 0.17)
d.set_handle_groups([a, b])
out = np.empty((len(V), 3), np.float32)
solve, lattice = [], []
for k in range(12):
    T = np.tile(np.eye(4), (2, 1, 1))
    T[1, 2, 3] = 0.01 * (k + 1)
    t0 = time.perf_counter(); d.solve(transforms=T, iterations=5, out=out); solve.append(time.perf_counter() - t0)
    T[1, 2, 3] += 0.005
    t0 = time.perf_counter(); d.pose_lattice(transforms=T, iterations=5); lattice.append(time.perf_counter() - t0)
print(json.dumps({"vertices": len(V), "nodes": d.num_nodes, "cells": d.num_cells, "handles": int(len(a) + len(b)),
                  "solve_ms": 1e3 * float(np.median(solve[2:])), "lattice_ms": 1e3 * float(np.median(lattice[2:]))}))
'''


def main():
    p = argparse.ArgumentParser(description=__doc__)
    p.add_argument("--other", required=True, help="checkout to compare with, built (its python/ is used)")
    p.add_argument("--device", default="cpu", choices=["cpu", "cuda"])
    p.add_argument("--rounds", type=int, default=2)
    a = p.parse_args()
    here = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    print("machine:", machine_info.describe(), "| device", a.device,
          "| load average before: %.2f %.2f %.2f" % os.getloadavg())
    print("| vertices | cells | nodes (other / this) | handle vertices | solve ms: other / this / ratio | "
          "lattice only ms: other / this / ratio |")
    print("|---|---|---|---|---|---|")
    for nm, nn in ((1000, 500), (1414, 707)):
        for cells in (0, 24000):
            best = {}
            for _ in range(a.rounds):
                for label, path in (("other", a.other), ("this", here)):
                    r = run_child(path, CHILD, str(nm), str(nn), str(cells), a.device)
                    if label not in best:
                        best[label] = r
                    else:
                        for k in ("solve_ms", "lattice_ms"):
                            best[label][k] = min(best[label][k], r[k])
            o, t = best["other"], best["this"]
            print(f"| {t['vertices']:,} | {t['cells']:,} | {o['nodes']:,} / {t['nodes']:,} | "
                  f"{t['handles']:,} ({100 * t['handles'] / t['vertices']:.1f}%) | "
                  f"{o['solve_ms']:.2f} / {t['solve_ms']:.2f} / {t['solve_ms'] / o['solve_ms']:.2f} | "
                  f"{o['lattice_ms']:.2f} / {t['lattice_ms']:.2f} / {t['lattice_ms'] / o['lattice_ms']:.2f} |", flush=True)
    print("load average after: %.2f %.2f %.2f" % os.getloadavg())


if __name__ == "__main__":
    main()
