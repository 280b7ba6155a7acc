#!/usr/bin/env python3
"""Cost of cell splitting (issue 9): bind (lattice + binding) and a pose update (5 iterations +
trilinear transfer) on tori of 0.5M and 1M vertices at the default resolution, two handle groups
holding about 11% of the vertices, this tree with and without splitting against another checkout
(one with handle groups but without splitting), each in its own process.

Run: /usr/bin/python3 scripts/bench_split.py --other CHECKOUT"""
import argparse
import os

import machine_info
from tree_child import run_child

CHILD = r'''
import json, sys, time
import numpy as np, larap
from larap import shapes
n_major, n_minor, split = int(sys.argv[1]), int(sys.argv[2]), sys.argv[3]
V, F = shapes.torus(1.0, 0.35, n_major, n_minor)
kw = {} if split == "na" else {"split_cells": split == "on"}
binds = []
for _ in range(3):
    t0 = time.perf_counter(); d = larap.Deformer(V, F, **kw); binds.append(time.perf_counter() - t0)
# Two vertex groups, as an artist makes them: opposite sectors of the torus, about 11% of the
# vertices together; one held, the other lifted by one transform per pose.
ang = np.arctan2(V[:, 1], V[:, 0])
a = np.flatnonzero(ang < -2.8)
b = np.flatnonzero(np.abs(ang) < 0.17)
d.set_handle_groups([a, b])
poses = []
out = np.empty((len(V), 3), np.float32)  # float32 output, as the add-on writes it
for k in range(6):
    T = np.tile(np.eye(4), (2, 1, 1))
    T[1, 2, 3] = 0.02 * (k + 1)
    t0 = time.perf_counter()
    d.solve(transforms=T, iterations=5, out=out)
    poses.append(time.perf_counter() - t0)
print(json.dumps({"vertices": len(V), "nodes": d.num_nodes, "cells": d.num_cells, "bind_s": min(binds),
                  "pose_ms": 1e3 * float(np.median(poses[1:])), "handles": int(len(a) + len(b)),
                  "handle_share": float(len(a) + len(b)) / len(V)}))
'''


def main():
    p = argparse.ArgumentParser(description=__doc__)
    p.add_argument("--other", required=True, help="checkout to compare with, built (its python/ is used)")
    a = p.parse_args()
    here = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    print("machine:", machine_info.describe(), "| load average before: %.2f %.2f %.2f" % os.getloadavg())
    print("| vertices | tree | nodes | cells | handle vertices | bind s | pose update ms (5 it + transfer) |")
    print("|---|---|---|---|---|---|---|")
    for nm, nn in ((1000, 500), (1414, 707)):
        for label, path, split in (("other", a.other, "na"), ("split on", here, "on"),
                                   ("split off", here, "off")):
            r = run_child(path, CHILD, str(nm), str(nn), split)
            print(f"| {r['vertices']:,} | {label} | {r['nodes']:,} | {r['cells']:,} | "
                  f"{r['handles']:,} ({100 * r['handle_share']:.1f}%) | {r['bind_s']:.3f} | {r['pose_ms']:.1f} |",
                  flush=True)
    print("load average after: %.2f %.2f %.2f" % os.getloadavg())


if __name__ == "__main__":
    main()
