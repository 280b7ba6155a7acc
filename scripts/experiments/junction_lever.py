"""What sets the neighbours' drag where separate parts meet (issue 9's last target), and whether a
soft hinge at the junction removes it. Research code, not used by the engine or the add-on.

Where the fingers (or a comb's tines) leave the palm, the engine's lattice has one cell copy
holding the palm's end and every finger's root; its far face's nodes are shared by all the
fingers (docs/method.md, "What splitting cannot separate"). This prints, per lattice size, the
*lever*: how far that shared node plane lies beyond the palm's end, in cells (the palm's end is
`shapes.character`'s root_x, or the comb's base end at x = -0.1), beside the neighbours' largest
move on the engine's lattice (the reference flip-flop of glued_parts.Model.engine, which gives the
engine's trilinear figures), and that move within one cell past the palm's end and within the
fingers' last cell (a band of width h at each end, not a grid cell). Then two hinges, the energy's edges weighted by w around the shared
nodes, so that a turned finger bends in its own cells instead of pulling them:

  "split"  the copies of a split cell (a grid cell with 2 or more copies) that touch a node
           which is a corner of 2 or more copies of one grid cell;
  "parts"  every copy whose vertices are of one mesh part and that touches a node which such
           copies of another part touch too.

An edge weighs the mean of its copies' factors (the engine's rule for split copies). Also the
turned finger's largest edge stretch (triangle edges, % of their rest length): what the hinge
costs in shape. Results: scripts/experiments/README.md.

    PYTHONPATH=python /usr/bin/python3 scripts/experiments/junction_lever.py [--w 0.1 0.03]
        [--character-cells 4000 ... 9000] [--comb-sizes 0.25 ... 1.05]"""
import argparse
import os
import sys

import numpy as np

REPO = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
sys.path[:0] = [os.path.join(REPO, "python"), os.path.join(REPO, "tests", "python"),
                os.path.dirname(os.path.abspath(__file__))]

import larap  # noqa: E402
from larap import quality  # noqa: E402
from arap_variants import Lat, mean_over_copies  # noqa: E402
from glued_parts import Model, cases, mesh_parts  # noqa: E402


def copies_by_cell(lat):
    by = {}
    for c, cc in enumerate(lat.cell_coords):
        by.setdefault(tuple(cc), []).append(c)
    return by


def split_hinge(lat):
    """(C,) bool: the copies of split cells that touch a node shared by two copies of one cell."""
    by = copies_by_cell(lat)
    branch = np.zeros(lat.nr, bool)
    for copies in by.values():
        if len(copies) > 1:
            ids, n = np.unique(lat.cells[copies].ravel(), return_counts=True)
            branch[ids[n >= 2]] = True
    soft = np.zeros(len(lat.cells), bool)
    for copies in by.values():
        if len(copies) > 1:
            for c in copies:
                soft[c] = branch[lat.cells[c]].any()
    return soft


def part_hinge(lat, comp):
    """(C,) bool: the one-part copies (by their vertices) touching a node that one-part copies of
    another part touch too."""
    parts = [set() for _ in lat.cells]
    for v, c in enumerate(lat.vcell):
        parts[c].add(comp[v])
    owner = np.array([next(iter(p)) if len(p) == 1 else -1 for p in parts])
    touching = {}
    for c in np.flatnonzero(owner >= 0):
        for node in lat.cells[c]:
            touching.setdefault(node, set()).add(owner[c])
    soft = np.zeros(len(lat.cells), bool)
    for c in np.flatnonzero(owner >= 0):
        soft[c] = any(len(touching[node]) > 1 for node in lat.cells[c])
    return soft


def hinged(lat, edge_w, soft, w):
    factor = np.where(soft, w, 1.0)
    return Model(lat.rest, lat.edges, edge_w * mean_over_copies(lat, factor), lat.tri_ids, lat.tri_w)


def stretch(V, X, F, ids):
    """Largest relative change of an edge of the triangles of the vertices ids, in %."""
    tris = quality.triangles(F)
    e = quality.edges(tris[np.isin(tris[:, 0], ids)])
    l0 = np.linalg.norm(V[e[:, 0]] - V[e[:, 1]], axis=1)
    l1 = np.linalg.norm(X[e[:, 0]] - X[e[:, 1]], axis=1)
    return 100 * float(np.max(np.abs(l1 / l0 - 1.0)))


def main():
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--w", type=float, nargs="+", default=[0.1, 0.03])
    p.add_argument("--character-cells", type=int, nargs="*",
                   default=[4000, 4500, 5000, 5500, 6000, 6500, 7000, 7500, 8000, 9000])
    p.add_argument("--comb-sizes", type=float, nargs="*", default=None)
    a = p.parse_args()
    from larap import shapes
    from test_topology import SWEEP_SIZES
    palm_end = {"character": shapes.character()[2]["root_x"], "comb": -0.1}
    heads = [f"{kind} w {w:g}" for kind in ("split", "parts") for w in a.w]
    print("model | size | pose | lever (cells) | hinged copies: split / parts | neighbours moved, % of the "
          "diagonal: engine | " + " | ".join(heads) + " | turned finger's edge stretch %: engine | "
          + " | ".join(heads))
    for name, size, V, F, h, poses, others, diag, tip, length in cases(
            a.character_cells, SWEEP_SIZES if a.comb_sizes is None else a.comb_sizes):
        d = larap.Deformer(V, F, cell_size=h, weights="trilinear")
        lat = Lat(d, V)
        x = (palm_end[name] - lat.origin[0]) / h
        lever = np.ceil(x) - x
        edge_w = d.lattice_edge_weights().astype(float)
        comp = mesh_parts(V, F)[1]
        masks = [split_hinge(lat), part_hinge(lat, comp)]
        models = [Model.engine(V, F, h)] + [hinged(lat, edge_w, m, w) for m in masks for w in a.w]
        for pose, (groups, T) in poses.items():
            drag, st, where = [], [], ""
            for m in models:
                X = m.solve(V, groups, T, h)
                drag.append(100 * max(np.linalg.norm(X[o] - V[o], axis=1).max() for o in others) / diag)
                if m is models[0]:  # the engine: where along the neighbours they move
                    o = np.concatenate(others)
                    move = 100 * np.linalg.norm(X[o] - V[o], axis=1) / diag
                    near = (V[o, 0] >= palm_end[name]) & (V[o, 0] <= palm_end[name] + h)
                    far = V[o, 0] >= V[o, 0].max() - h
                    if near.any():  # (the comb's tines have few vertices along x)
                        where = f" (within a cell past the palm's end {move[near].max():.2f}, last {move[far].max():.2f})"
                st.append(stretch(V, X, F, np.flatnonzero(comp == comp[groups[tip][0]])))
            print(f"{name} | {size} | {pose} | {lever:.2f} | {masks[0].sum()} / {masks[1].sum()} | "
                  + f"{drag[0]:.2f}{where} | " + " | ".join(f"{x:.2f}" for x in drag[1:]) + " | "
                  + " | ".join(f"{x:.0f}" for x in st), flush=True)


if __name__ == "__main__":
    main()
