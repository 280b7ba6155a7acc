#!/usr/bin/env python3
"""The pose update against another checkout (issue 9's cost bound: a pose update within 10% of
the tree before): 5 flip-flops + the trilinear transfer into a float32 array (as the add-on
writes it), and the lattice alone (`pose_lattice`, what the GPU preview reads), on tori of 0.5M
and 1M vertices at the default resolution and at four times the cells, two vertex groups holding
about 11% of the vertices (one held, one lifted a little more at every pose, as a drag); and
`shapes.character()` at its default lattice, where cells split and the solid branches (fingers
leaving the palm), posed as tests/python/test_junctions.py pins a hand (body, palm and every
fingertip, one fingertip turned a little further at every pose). Each tree in its own process,
the trees alternating, median over the poses, best of the rounds.

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
if n_major:
    V, F = shapes.torus(1.0, 0.35, n_major, n_minor)
    ang = np.arctan2(V[:, 1], V[:, 0])
    groups = [np.flatnonzero(ang < -2.8), np.flatnonzero(np.abs(ang) < 0.17)]
    def pose(t):  # the second group lifted by t
        T = np.tile(np.eye(4), (2, 1, 1)); T[1, 2, 3] = t; return T
else:  # the character's hand as the tests pin it, one fingertip turned by 60 t degrees about its root
    import os
    sys.path.insert(0, os.path.join(os.path.dirname(os.path.dirname(os.path.dirname(larap.__file__))), "tests", "python"))
    from test_junctions import finger_pose  # this checkout's own pose
    V, F, parts = shapes.character()
    groups = finger_pose(V, parts)[0]
    def pose(t):
        return finger_pose(V, parts, degrees=60.0 * t)[1]
d = larap.Deformer(V, F, device=device, **({"cells": cells} if cells else {}))
d.set_handle_groups(groups)
out = np.empty((len(V), 3), np.float32)
solve, lattice = [], []
for k in range(12):
    T = pose(0.01 * (k + 1) if n_major else 0.08 * (k + 1))
    t0 = time.perf_counter(); d.solve(transforms=T, iterations=5, out=out); solve.append(time.perf_counter() - t0)
    T = pose(0.01 * (k + 1) + 0.005 if n_major else 0.08 * (k + 1) + 0.04)
    t0 = time.perf_counter(); d.pose_lattice(transforms=T, iterations=5); lattice.append(time.perf_counter() - t0)
handles = sum(len(g) for g in groups)
print(json.dumps({"vertices": len(V), "nodes": d.num_nodes, "cells": d.num_cells, "handles": int(handles),
                  "solve_ms": 1e3 * float(np.median(solve[2:])), "lattice_ms": 1e3 * float(np.median(lattice[2:]))}))
'''


def main():
    p = argparse.ArgumentParser(description=__doc__)
    p.add_argument("--other", required=True, help="checkout to compare with, built (its python/ is used)")
    p.add_argument("--device", default="cpu", choices=["cpu", "cuda"])
    p.add_argument("--rounds", type=int, default=2)
    p.add_argument("--no-character", action="store_true",
                   help="tori only (for an other tree without shapes.character: before issue 9)")
    a = p.parse_args()
    here = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    print("machine:", machine_info.describe(), "| device", a.device,
          "| load average before: %.2f %.2f %.2f" % os.getloadavg())
    print("| vertices | cells | nodes (other / this) | handle vertices | solve ms: other / this / ratio | "
          "lattice only ms: other / this / ratio |")
    print("|---|---|---|---|---|---|")
    rows = ((1000, 500, 0), (1000, 500, 24000), (1414, 707, 0), (1414, 707, 24000), (0, 0, 0))
    for nm, nn, cells in rows[:4] if a.no_character else rows:
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
