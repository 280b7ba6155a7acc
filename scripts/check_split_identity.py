#!/usr/bin/env python3
"""Is the split lattice of this tree the same as another checkout's? For a set of meshes (tori up to
1M vertices, the comb and bars of tests/python/test_topology.py, polygon soups, meshes with
triangles larger than a cell, one far from zero, and the public meshes of ../shared when present) both trees build a
Deformer with B-spline weights; the cells, cell kinds, corner nodes of every copy, node positions
(shell included), edges, trilinear binding and a posed result (handle groups, 3 iterations) must
be bit for bit equal. Prints one line per mesh with a digest of each tree; exits 1 on any
difference. Used to show that a change meant to be faster builds the same lattice.

Run: /usr/bin/python3 scripts/check_split_identity.py --other CHECKOUT [--quick]"""
import argparse
import json
import os
import sys
import tempfile

import numpy as np
from tree_child import run_child

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, os.path.join(ROOT, "python"))
sys.path.insert(0, os.path.join(ROOT, "tests", "python"))

CHILD = r'''
import hashlib, json, sys
import numpy as np, larap
data = np.load(sys.argv[1], allow_pickle=False)
opts = json.loads(sys.argv[2])
V, F = data["V"], data["F"]
d = larap.Deformer(V, F, weights="bspline", **opts)
core = d._core  # the engine's arrays that the wrapper does not expose
parts = {
    "cells": core.cell_coords(), "kinds": core.cell_kinds(), "cell_nodes": d.cell_nodes(),
    "rest": d.lattice_rest(), "edges": d.lattice_edges(),
}
cells, frac = d.trilinear_binding()
parts["binding"] = np.concatenate([cells.astype(np.float64), frac.astype(np.float64).ravel()])
# Two handle groups at the ends along x, the far one turned and lifted.
order = np.argsort(V[:, 0], kind="stable")
k = max(1, len(V) // 20)
d.set_handle_groups([order[:k], order[-k:]])
T = np.tile(np.eye(4), (2, 1, 1))
c, s = np.cos(0.3), np.sin(0.3)
T[1, :2, :2] = [[c, -s], [s, c]]
T[1, 2, 3] = 0.1 * float(np.ptp(V[:, 0]))
parts["pose"] = d.solve(transforms=T, iterations=3)
digest = hashlib.sha256()
for key in sorted(parts):
    a = np.ascontiguousarray(parts[key])
    digest.update(key.encode() + str(a.shape).encode() + a.tobytes())
print(json.dumps({"digest": digest.hexdigest()[:16], "cells": d.num_cells, "nodes": d.num_nodes,
                  "components": d.num_components}))
'''


def meshes(quick):
    """(name, V, F, options) of every mesh checked."""
    import larap
    from larap import shapes
    from test_topology import bars, comb

    out = []
    for nm, nn in ((64, 32), (300, 150)) + (() if quick else ((1000, 500), (1414, 707))):
        V, F = shapes.torus(1.0, 0.35, nm, nn)
        out.append((f"torus {len(V):,}", V, F, {}))
    V, F = shapes.torus(1.0, 0.35, 300, 150)
    out.append(("torus 45k, cells=60000", V, F, {"cells": 60000}))
    V, F, _, _ = comb()
    out.append(("comb, gap 0.1", V, F, {"cell_size": 1.0}))
    V, F, _, _ = comb(tines=4, gap=0.3)
    out.append(("comb, gap 0.3, k=8", V, F, {"cell_size": 1.0, "split_resolution": 8}))
    for spacing in (0.3, 2.5):
        V, F, _, _ = bars(spacing)
        out.append((f"bars {spacing} apart", V, F, {"cell_size": 1.0}))
    V, F, _, _ = comb()
    out.append(("comb 3e6 cells from zero", V + [3e6, 0, 0], F, {"cell_size": 1.0}))
    V, F = shapes.box((0, 0, 0), (1, 1, 1), 1)
    out.append(("box of 12 triangles, h=0.1", V, F, {"cell_size": 0.1}))
    V, F = shapes.box((0, 0, 0), (60, 0.9, 0.9), 8)
    out.append(("long thin box, triangles over 60 cells", V, F, {"cell_size": 0.5}))
    V, F, _ = shapes.character()
    out.append(("larap.shapes.character()", V, F, {}))
    V, F = shapes.sphere(radius=1.0, rings=12, segments=24)
    out.append(("coarse sphere, cells=20000", V, F, {"cells": 20000}))
    V, F = shapes.soup(*shapes.sphere(radius=1.0, rings=24, segments=48), seed=3)
    out.append(("sphere soup", V, F, {}))
    rng = np.random.default_rng(5)
    c = rng.random((400, 3)) * 4.0
    V = (c[:, None, :] + rng.normal(scale=0.15, size=(400, 3, 3))).reshape(-1, 3)
    out.append(("400 random triangles", V, np.arange(len(V)).reshape(-1, 3), {}))
    shared = os.path.join(ROOT, "..", "shared", "data", "meshes")
    if os.path.isdir(shared):
        for name in sorted(os.listdir(shared)):
            if name.endswith((".obj", ".off")):
                V, F = larap.load_mesh(os.path.join(shared, name))
                out.append((name, V, F, {}))
                if name == "hand_lowres.obj":
                    out.append((name + ", cells=20000", V, F, {"cells": 20000}))
    else:
        print(f"(public meshes not present at {shared}: skipped)")
    return out


def faces_array(F):
    """Faces as one int64 array, or None when their sizes differ."""
    if isinstance(F, np.ndarray):
        return F.astype(np.int64)
    sizes = {len(f) for f in F}
    if len(sizes) == 1:
        return np.asarray(F, np.int64)
    return None


def main():
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--other", required=True, help="the checkout to compare with, built (its python/ is used)")
    p.add_argument("--quick", action="store_true", help="leave out the 500k and 1M tori")
    a = p.parse_args()
    differ = 0
    print("| mesh | options | cells | nodes | this tree | other |")
    print("|---|---|---|---|---|---|")
    with tempfile.TemporaryDirectory() as tmp:
        for name, V, F, opts in meshes(a.quick):
            Fa = faces_array(F)
            if Fa is None:  # mixed polygon sizes: triangulate (the same for both trees)
                Fa = np.array([[f[0], f[k], f[k + 1]] for f in F for k in range(1, len(f) - 1)], np.int64)
            path = os.path.join(tmp, "mesh.npz")
            np.savez(path, V=np.asarray(V, np.float64), F=Fa)
            mine, other = (run_child(tree, CHILD, path, json.dumps(opts)) for tree in (ROOT, a.other))
            same = mine == other
            differ += not same
            print(f"| {name} | {opts or 'default'} | {mine['cells']:,} | {mine['nodes']:,} | "
                  f"{mine['digest']} | {other['digest'] if not same else 'same'} |", flush=True)
    print("all equal" if not differ else f"{differ} meshes differ")
    sys.exit(1 if differ else 0)


if __name__ == "__main__":
    main()
