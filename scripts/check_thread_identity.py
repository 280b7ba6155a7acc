#!/usr/bin/env python3
"""Is the split lattice the same whatever the number of worker threads? Builds the lattice of the
character, the tests' comb, a long box of large triangles and a few public meshes (../shared, when
present) with 1, 2, 16 and all threads, and compares digests of the copies' cells, corner nodes,
node positions and edges. Prints one line per mesh; exits 1 on any difference. Meant for machines
with many cores (the C++ test CellPieces.SameLatticeWhateverTheThreadCount runs on every machine).

Run: /usr/bin/python3 scripts/check_thread_identity.py"""
import hashlib
import os
import sys

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, os.path.join(ROOT, "python"))
sys.path.insert(0, os.path.join(ROOT, "tests", "python"))
SHARED = os.path.join(ROOT, "..", "shared", "data", "meshes")


def digest(d):
    h = hashlib.sha256()
    for a in (d._core.cell_coords(), d.cell_nodes(), d.lattice_rest(), d.lattice_edges()):
        a = np.ascontiguousarray(a)
        h.update(str(a.shape).encode() + a.tobytes())
    return h.hexdigest()[:12]


def main():
    import larap
    from larap import shapes
    from test_topology import comb

    cases = [("character", shapes.character()[:2], {}), ("comb", comb()[:2], {"cell_size": 1.0}),
             ("long box", shapes.box((0, 0, 0), (237.0, 0.9, 0.9), 8), {"cell_size": 0.5})]
    for name in ("suzanne.obj", "truck.obj", "woody.obj"):
        path = os.path.join(SHARED, name)
        if os.path.exists(path):
            cases.append((name, larap.load_mesh(path), {}))
    before = larap.num_threads()
    bad = 0
    for name, (V, F), kw in cases:
        digests = []
        for threads in (1, 2, 16, 0):
            larap.set_num_threads(threads)
            digests.append(digest(larap.Deformer(V, F, **kw)))
        same = len(set(digests)) == 1
        bad += not same
        print(f"{name}: {' '.join(digests)} {'same' if same else 'DIFFER'}", flush=True)
    larap.set_num_threads(before)
    print("all equal" if not bad else f"{bad} meshes differ")
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
