"""Issue 9, session 30: where separate parts meet, one cell copy per branch (a reference solver on
the engine's own lattice). Research code, not used by the engine or the add-on. Split alone, the
neighbours' drag goes with the finger's hold on its palm; with `--anchor --couple 10` both hold on
the character in this solver (figures and limits: scripts/experiments/README.md). In the engine since
session 31 (native/src/branch_copies.cpp, `Deformer(_branch_copies=True)`, off by default).

Where fingers pushed into a palm leave it, the engine's lattice holds the palm's end and the roots
of every finger in a cell in one copy (its piece is connected through the palm), and copies of the
next cells share nodes with it across their faces; a turned finger moves those nodes and drags its
neighbours along (docs/method.md, "What splitting cannot separate"). Here the lattice is changed
so that the nodes beyond the palm belong to one finger each:

1. Material. The mesh's parts (vertices joined by faces) are solids, told apart by winding number
   (`Solids`). Near where parts meet (cells whose box meets two parts' boxes, and their
   neighbours; within the right hand's box, where the pose asks for it), each cell is sampled
   (m^3 points); its samples go to its copies by the 6-connected components of the solid samples,
   each copy taking the components that hold its vertices' parts, and a copy's own vertices count
   as samples too (a finger grazing a cell can miss the grid). A copy's *trunk* is the largest part
   (by volume) it holds (the palm among fingers, the arm at the wrist); the others are branches,
   and a branch's *exposed* material is what of it lies outside the trunk.
2. Sides. A node is on the branches' side when, over the copies around it, some exposed branch
   material lies closer to it than `kappa` times the nearest trunk material (dB < kappa dT).
   `--face`: every copy to be split keeps the face most on the trunk's side (the least dT / dB);
   `--anchor`: every copy to be split keeps at least its corner most on the trunk's side (a ball
   joint: the branch's translation held).
3. Copies. A copy that holds trunk and exposed branch material and has a node on the branches'
   side is split: the trunk keeps the copy, each exposed branch gets a copy of its own (that
   part's vertices bind there). A copy of two or more branches and no trunk is split per branch.
   Every other copy is labelled with what it holds (its trunk), or, with too little material for
   the samples, with the one branch of its labelled neighbours.
4. Nodes. A node on the branches' side becomes, in the copies labelled with another part than the
   trunk nearest to it, a node of that part's own at the same point.
Weights: a trunk copy weighs its trunk's share of the cell, a branch copy its branch's and the
trunk's (at least 1/24); `--whole-weights`: every copy weighs what its cell did.
`--branch-brace MU`: each node of a branch's own held by a brace (as the engine's junction braces)
to the straight extension of the trunk-side node next to it. `--couple LAMBDA`: each branch copy's
rotation answers for the edges of the copy it was split from too, at LAMBDA times that copy's
weight (`coupled_terms`): a branch without handles turns with its trunk, and the energy is still
one (zero at rest and under rigid motions; flip-flops never increase it).

The energy and solve are the engine's (arap_variants.Solver: one rotation per cell copy, gamma
0.03, the junction braces of junction_brace.py at the engine's default weight, trilinear, 30
flip-flops from rest unless `--iterations`); `--compare` also solves the engine's lattice unchanged
in the same solver. Poses: test_junctions' finger pose (default), `--palm-part`, `--wrist` (palm
and fingertips turned 90 degrees about the wrist) and `--follow` (the palm alone turned so, no
fingertip handles: a finger must follow its palm).

Run from the repository root (figures: scripts/experiments/README.md; about 15 s per lattice):
  PYTHONPATH=python /usr/bin/python3 scripts/experiments/branch_copies.py --angles 15,30,45 --compare
  PYTHONPATH=python /usr/bin/python3 scripts/experiments/branch_copies.py --angles 30,45 --cells 4000,8000 --follow --iterations 200 --compare
  PYTHONPATH=python /usr/bin/python3 scripts/experiments/branch_copies.py --samples 16 --anchor --couple 10
  PYTHONPATH=python /usr/bin/python3 scripts/experiments/branch_copies.py --comb --anchor --couple 10 [--follow]
"""
import argparse
import sys

import numpy as np
import scipy.sparse as sp
from scipy import ndimage
from scipy.sparse import csr_matrix
from scipy.sparse.csgraph import connected_components

sys.path.insert(0, "tests/python")
sys.path.insert(0, "scripts/experiments")
import arap_variants as av  # noqa: E402
import junction_brace as jb  # noqa: E402
import test_junctions as tj  # noqa: E402
from conftest import affine, rotation  # noqa: E402

import larap  # noqa: E402
from larap import shapes  # noqa: E402

MIN_WEIGHT = 1.0 / 24  # a copy's least weight (the engine's floor at its default split_resolution)
BRACE = 100.0  # junction_brace.py's mu matching the engine's default junction_brace = 50 (its README)


class Solids:
    """The mesh's parts (vertices joined by faces) as solids: inside tests by generalised winding
    number against each part's own triangles (fans of its polygons)."""

    def __init__(self, V, F):
        self.V = np.asarray(V, float)
        tris = np.array([(f[0], f[i], f[i + 1]) for f in F for i in range(1, len(f) - 1)], np.int64)
        n, e = len(V), np.concatenate([tris[:, [0, 1]], tris[:, [1, 2]]])
        _, self.part_of = connected_components(csr_matrix((np.ones(len(e)), (e[:, 0], e[:, 1])), shape=(n, n)),
                                               directed=False)
        self.tris = [tris[self.part_of[tris[:, 0]] == p] for p in range(self.part_of.max() + 1)]
        self.lo = np.array([self.V[np.unique(t)].min(0) for t in self.tris])
        self.hi = np.array([self.V[np.unique(t)].max(0) for t in self.tris])
        self.tests = [av.winding_inside(self.V, t) for t in self.tris]
        self.volume = np.array([abs(np.einsum("ij,ij->i", self.V[t[:, 0]], np.cross(self.V[t[:, 1]], self.V[t[:, 2]]))
                                    .sum()) / 6 for t in self.tris])

    def near(self, lo, hi):
        """The parts whose boxes meet [lo, hi]."""
        return np.flatnonzero(np.all(self.lo <= hi, 1) & np.all(self.hi >= lo, 1))

    def inside(self, p, P):
        """(n,) the points P inside part p (arap_variants' winding number, on those in its box)."""
        out = np.zeros(len(P), bool)
        box = np.all((P >= self.lo[p]) & (P <= self.hi[p]), 1)
        if box.any():
            out[box] = self.tests[p](P[box])
        return out


def copy_material(lat, solids, m, region=None):
    """Per copy of the cells near where parts meet (cells whose box meets two parts' boxes, and
    their neighbours; inside `region` (lo, hi) if given): (points, trunk mask, {part: exposed
    mask}, {part: mask}, trunk part). The points are m^3 samples of the cell and the copy's own
    vertices; the trunk is the largest (by volume) of the parts the copy holds."""
    g = (np.arange(m) + 0.5) / m
    G = np.stack(np.meshgrid(g, g, g, indexing="ij"), -1).reshape(-1, 3)
    by_cell = {}
    for X, cc in enumerate(lat.cell_coords):
        by_cell.setdefault(tuple(cc), []).append(X)
    corner = {key: lat.rest[lat.cells[copies[0]][0]] for key, copies in by_cell.items()}
    meets = {key for key, lo in corner.items() if len(solids.near(lo, lo + lat.h)) >= 2
             and (region is None or (np.all(lo + lat.h >= region[0]) and np.all(lo <= region[1])))}
    todo = {(k[0] + a, k[1] + b, k[2] + c) for k in meets for a in (-1, 0, 1) for b in (-1, 0, 1) for c in (-1, 0, 1)}
    part_of = solids.part_of
    material = {}
    for key in todo & set(by_cell):
        copies, lo = by_cell[key], corner[key]
        P = lo + G * lat.h
        cand = solids.near(lo, lo + lat.h)
        ins = np.stack([solids.inside(p, P) for p in cand], 1) if len(cand) else np.zeros((len(P), 0), bool)
        col = {p: j for j, p in enumerate(cand)}
        comp, _ = ndimage.label(ins.any(1).reshape(m, m, m))
        comp = comp.ravel()
        everything = set(comp.tolist()) - {0}
        verts = {X: np.flatnonzero(lat.vcell == X) for X in copies}
        held = {}
        for X in copies:
            if len(copies) == 1:
                held[X] = everything
                continue
            held[X] = set()
            for p in set(part_of[verts[X]].tolist()) & set(col):
                held[X] |= set(comp[ins[:, col[p]]].tolist()) - {0}
        left = everything - set().union(*held.values())
        empty = [X for X in copies if not held[X]]
        if empty and left:  # a copy without vertices: what no other copy holds
            held[empty[0]] = left
        for X in copies:
            mine = np.isin(comp, list(held[X])) if held[X] else np.zeros(len(P), bool)
            v = verts[X]
            pts = np.vstack([P, lat.V[v]])
            masks = {p: np.concatenate([ins[:, col[p]] & mine, part_of[v] == p]) for p in cand}
            for p in set(part_of[v].tolist()) - set(cand):
                masks[p] = np.concatenate([np.zeros(len(P), bool), part_of[v] == p])
            masks = {p: x for p, x in masks.items() if x.any()}
            if not masks:
                continue
            trunk = max(masks, key=lambda p: solids.volume[p])
            within = masks[trunk].copy()
            within[len(P):] |= solids.inside(trunk, lat.V[v])  # vertices of other parts inside it
            exposed = {p: x & ~within for p, x in masks.items() if p != trunk and (x & ~within).any()}
            material[X] = (pts, within, exposed, masks, trunk)
    return material


def split_per_branch(lat, solids, kappa=2.0, m=24, region=None, hold="none", whole=False):
    """Changes `lat` (an arap_variants.Lat) in place as the module's docstring says; returns the
    copies' weights (C,), the number of copies split and of nodes on the branches' side. hold:
    "anchor" or "face", what of each copy to be split stays on the trunk's side (--anchor, --face);
    whole: split copies weigh what their cell did (--whole-weights)."""
    material = copy_material(lat, solids, m, region)
    part_of = solids.part_of
    users = {}
    for X in material:
        for n in lat.cells[X]:
            users.setdefault(n, []).append(X)
    trunk_at = {}  # node on the branches' side -> the part whose material is nearest among the trunks
    ratio = {}  # its dT / dB
    for n, around in users.items():
        p = lat.rest[n]
        dT, dB, t = np.inf, np.inf, None
        for X in around:
            pts, within, exposed, _, trunk = material[X]
            if within.any():
                d = np.linalg.norm(pts[within] - p, axis=1).min()
                if d < dT:
                    dT, t = d, trunk
            for e in exposed.values():
                dB = min(dB, np.linalg.norm(pts[e] - p, axis=1).min())
        if dB < kappa * dT:
            trunk_at[n] = t
            ratio[n] = dT / dB if dB > 0 else np.inf
    # --anchor: each copy to be split keeps at least one corner on the trunk's side; --face: the
    # whole face most on it, so that every branch is held by its trunk through a face.
    grid = slice(0, m ** 3)  # a copy's samples (its vertices follow)
    for X, (pts, within, exposed, _, _) in material.items():
        if hold == "none" or not (exposed and within[grid].any()):
            continue
        corners = lat.cells[X]
        if hold == "anchor":  # at least one corner: a ball joint
            if all(n in trunk_at for n in corners):
                trunk_at.pop(min(corners, key=lambda n: ratio.get(n, 0.0)), None)
            continue
        faces = [[q for q in range(8) if (q >> axis & 1) == side] for axis in range(3) for side in (0, 1)]
        if any(all(corners[q] not in trunk_at for q in f) for f in faces):
            continue
        best = min(faces, key=lambda f: max(ratio.get(corners[q], 0.0) for q in f))
        for q in best:
            trunk_at.pop(corners[q], None)

    cells = [list(c) for c in lat.cells]
    coords = [tuple(c) for c in lat.cell_coords]
    w = lat.d.cell_weights()
    weight = list(w) if len(w) else [1.0] * len(cells)
    weight0 = list(weight)
    pairs = []  # (branch copy, the copy it was split from: its trunk's)
    vcell = lat.vcell.copy()
    label = {}
    split = 0

    def add_copy(X, b, share):
        cells.append(list(lat.cells[X]))
        coords.append(coords[X])
        label[len(cells) - 1] = b
        weight.append(weight0[X] if whole else max(share, MIN_WEIGHT))
        vcell[np.flatnonzero((lat.vcell == X) & (part_of == b))] = len(cells) - 1
        pairs.append((len(cells) - 1, X))

    for X, (pts, within, exposed, masks, trunk) in material.items():
        on_side = any(n in trunk_at for n in lat.cells[X])
        if exposed and on_side and within[grid].any():
            split += 1
            label[X] = trunk
            if not whole:
                weight[X] = max(within[grid].mean(), MIN_WEIGHT)
            for b in exposed:
                add_copy(X, b, (masks[b] | within)[grid].mean())
        elif len(exposed) >= 2 and on_side:
            split += 1
            first, *rest = sorted(exposed)
            label[X] = first
            if not whole:
                weight[X] = max(masks[first][grid].mean(), MIN_WEIGHT)
            for b in rest:
                add_copy(X, b, masks[b][grid].mean())
        elif within.any() or len(masks) == 1:
            label[X] = trunk
        elif len(exposed) == 1:
            label[X] = next(iter(exposed))
    around = {}
    for X in range(len(lat.cells)):
        for n in lat.cells[X]:
            around.setdefault(n, []).append(X)
    for X in range(len(lat.cells)):  # too little material for the samples: the neighbours' branch
        if X in label or not any(n in trunk_at for n in lat.cells[X]):
            continue
        near = {label[Y] for n in lat.cells[X] if n in trunk_at for Y in around[n]
                if Y in label and label[Y] != trunk_at[n]}
        if len(near) == 1:
            label[X] = near.pop()

    rest = list(lat.rest)
    own = {}
    for X, b in label.items():
        for q in range(8):
            n = cells[X][q]
            if n in trunk_at and b != trunk_at[n]:
                if (n, b) not in own:
                    own[(n, b)] = len(rest)
                    rest.append(lat.rest[n])
                cells[X][q] = own[(n, b)]
    cells, rest = np.array(cells, np.int64), np.array(rest)
    used = np.unique(cells)  # an original node may now have no copy
    renumber = np.full(len(rest), -1)
    renumber[used] = np.arange(len(used))
    lat.cells, lat.rest, lat.nr = renumber[cells], rest[used], len(used)
    lat.cell_coords, lat.vcell = np.array(coords), vcell
    lat.tri_ids, lat.tri_w = lat.trilinear_rows(lat.vcell, lat.V)
    lat.edges = lat.rest_all = lat.coords = lat._bs = None  # the engine's, no longer this lattice's
    lat.branch_nodes = set(renumber[list(own.values())].tolist())
    lat.branch_pairs = pairs
    return np.array(weight), split, len(trunk_at)


def branch_braces(lat):
    """(a, b, c) node columns that hold each branch's own nodes to its trunk's straight
    extension: c a node of a branch's own, b the trunk-side node next to it along an axis in one
    of its copies, a the node one cell farther on in a copy that has b too (not a branch's own)."""
    own = lat.branch_nodes
    users = {}
    for X, cn in enumerate(lat.cells):
        for n in cn:
            users.setdefault(n, []).append(X)
    rows = set()
    for X, cn in enumerate(lat.cells):
        for q in range(8):
            if cn[q] not in own:
                continue
            for axis in range(3):
                b = cn[q ^ (1 << axis)]
                if b in own:
                    continue
                target = 2 * lat.rest[b] - lat.rest[cn[q]]
                for Y in users[b]:
                    for a in lat.cells[Y]:
                        if a not in own and np.allclose(lat.rest[a], target, atol=1e-9 * lat.h):
                            rows.add((a, b, cn[q]))
    return sorted(rows)


def coupled_terms(lat, lam):
    """An av.Solver extra_terms: for each branch copy b split from copy t, t's 12 edges once more,
    weighing lam times t's weight, with b's rotation. A branch's rotation then answers for its
    trunk's edges too, so a branch without handles turns with its trunk and one turned by its
    handles turns the trunk's copy only as far as lam asks; still an energy (zero at rest and under
    a rigid motion, the local step fits each rotation to all its terms), so flip-flops decrease it.
    (They count in gamma_eff's normalisation: 2% at lam = 10 on the character.)"""
    def extra(i, k, w, r, cw):
        pairs = getattr(lat, "branch_pairs", [])
        if lam <= 0 or not pairs:
            return i, k, w, r
        b, t = np.array(pairs).T
        q = np.arange(12)
        a, c = np.array(av.CELL_EDGES).T
        return (np.concatenate([i, lat.cells[t][:, a].ravel()]), np.concatenate([k, lat.cells[t][:, c].ravel()]),
                np.concatenate([w, lam * cw[t][:, q].ravel()]), np.concatenate([r, np.repeat(b, 12)]))
    return extra


def branch_brace_matrix(lat):
    """The rows of branch_braces as a sparse (K, N) matrix (None when there are none)."""
    R = branch_braces(lat) if hasattr(lat, "branch_nodes") else []
    if not R:
        return None
    return sp.csr_matrix((np.tile([1.0, -2.0, 1.0], len(R)), (np.repeat(np.arange(len(R)), 3), np.array(R).ravel())),
                         shape=(len(R), lat.nr))


def solver(lat, groups, w, couple=0.0, mu_branch=0.0):
    """The engine's energy on `lat` (junction braces at BRACE), with the branch copies' coupling
    at `couple` and the branch braces at `mu_branch` (0: none)."""
    rows, alpha = av.group_alpha(groups)
    G = branch_brace_matrix(lat) if mu_branch > 0 else None
    return jb.Braced(lat, rows, alpha, BRACE, gamma=0.03, rotations="cell", floor=1e-9,
                     cw=np.repeat(np.asarray(w, float)[:, None], 12, 1), extra_terms=coupled_terms(lat, couple),
                     fixed=[(mu_branch, G)] if G is not None else [])


class Case:
    """shapes.character turned `turn` degrees about the vertical, test_junctions' finger pose (or
    a wrist bend), on a lattice of `cells` cells."""

    def __init__(self, turn, cells, finger_gap=0.004, palm_part=False, wrist=False, follow=False):
        V, self.F, self.parts = shapes.character(finger_gap=finger_gap)
        groups, T = tj.finger_pose(V, self.parts)
        if palm_part:  # the palm's (and body's) group without the fingers' roots
            fingers = np.concatenate(self.parts["fingers"])
            groups = [np.setdiff1d(g, fingers) for g in groups[:2]] + groups[2:]
        if wrist or follow:  # palm (and fingertips) turned 90 degrees about the wrist, the body held
            R = affine(rotation([0, 1, 0], -90.0), pivot=(V[self.parts["hand"], 0].min() + 0.02, 0.0, 1.42))
            T = np.stack([np.eye(4)] + [R] * (len(groups) - 1))
        if follow:  # no fingertip handles, no fingers' roots in the palm's group: the fingers free
            fingers = np.concatenate(self.parts["fingers"])
            groups, T = [np.setdiff1d(g, fingers) for g in groups[:2]], T[:2]
        self.size = tj.hand_size(V, self.parts)
        self.V, self.T = tj.turned_about_vertical(V, T, turn) if turn else (V, T)
        self.groups, self.turn, self.gap = groups, turn, finger_gap
        self.d = larap.Deformer(self.V, self.F, weights="trilinear", cells=cells)
        self.solids = Solids(self.V, self.F)
        self.mu_branch = self.couple = 0.0  # the options of solver() and split_per_branch()
        self.hold, self.whole = "none", False
        H = self.V[self.parts["hand"]]  # the right hand: where the pose asks for it (saves time)
        self.region = (H.min(0), H.max(0))

    def solve(self, per_branch, kappa=2.0, samples=24, iterations=30):
        lat = av.Lat(self.d, self.V)
        info = ""
        if per_branch:
            w, split, side = split_per_branch(lat, self.solids, kappa, samples, self.region, self.hold, self.whole)
            info = f" ({split} split, {side} nodes)"
        else:
            w = self.d.cell_weights()
            w = w if len(w) else np.ones(len(lat.cells))
        s = solver(lat, self.groups, w, self.couple if per_branch else 0.0, self.mu_branch if per_branch else 0.0)
        return av.transfer(lat, s.solve(av.group_targets(self.V, self.groups, self.T), iterations)), info

    def figures(self, X):
        """Neighbours' largest move (% of the hand), the turned tip's miss (% of the finger), the
        turned finger's largest edge stretch (%), and (wrist) the fingers' distance from the
        rigid turn (% of the hand)."""
        f = self.parts["fingers"]
        drag = max(np.linalg.norm(X[f[j]] - self.V[f[j]], axis=1).max() for j in (0, 2, 3)) / self.size
        miss = np.nan
        if len(self.groups) > 3:
            tip, Tt = self.groups[3], self.T[3]
            miss = np.linalg.norm(X[tip] - (self.V[tip] @ Tt[:3, :3].T + Tt[:3, 3]), axis=1).max() / 0.09
        E = np.array([(a, b) for t in self.F if np.isin(t, f[1]).all() for a, b in zip(t, np.roll(t, -1))])
        stretch = np.abs(np.linalg.norm(X[E[:, 0]] - X[E[:, 1]], axis=1) /
                         np.linalg.norm(self.V[E[:, 0]] - self.V[E[:, 1]], axis=1) - 1).max()
        all_f = np.concatenate(f)
        Tw = self.T[1]
        off = np.linalg.norm(X[all_f] - (self.V[all_f] @ Tw[:3, :3].T + Tw[:3, 3]), axis=1).max() / self.size
        return 100 * drag, 100 * miss, 100 * stretch, 100 * off


def comb_sweep(follow, kappa=2.0, samples=16, couple=10.0, hold="anchor"):
    """test_topology's comb (a base with three separate tines pushed into it) at its 17 cell sizes,
    the engine's lattice and the per-branch one (anchored, coupled) in the same solver: the
    neighbours' drag (% of the diagonal) with the middle tine turned, or (follow) the tines' distance
    from the base's rigid turn, the base alone turned 90 degrees about y and the tines free."""
    import test_topology as tt
    from larap.quality import diagonal
    out = {"engine": [], "per branch": []}
    for h in tt.SWEEP_SIZES:
        V, F, tines, _ = tt.comb(gap=0.1 * h)
        groups, T = tt.comb_pose(V, tines, moved=1)
        if follow:
            groups, T = [groups[0]], np.stack([affine(rotation([0, 1, 0], -90.0), pivot=(-3.0, 0.0, 0.5))])
        d = larap.Deformer(V, F, cell_size=h, weights="trilinear")
        line = []
        for name in out:
            lat = av.Lat(d, V)
            if name == "engine":
                w = d.cell_weights()
                w = w if len(w) else np.ones(len(lat.cells))
            else:
                w = split_per_branch(lat, Solids(V, F), kappa, samples, hold=hold)[0]
            s = solver(lat, groups, w, couple if name != "engine" else 0.0)
            X = av.transfer(lat, s.solve(av.group_targets(V, groups, T), 200 if follow else 30))
            if follow:
                t = np.concatenate(tines)
                v = np.linalg.norm(X[t] - tt.apply(T[0], V[t]), axis=1).max() / diagonal(V)
            else:
                v = max(np.linalg.norm(X[tines[k]] - V[tines[k]], axis=1).max() for k in (0, 2)) / diagonal(V)
            out[name].append(100 * v)
            line.append(f"{name}: {100 * v:5.2f}%")
        print(f"h {h:4.2f} | " + " | ".join(line), flush=True)
    return out


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--angles", default="0,15,30,45")
    ap.add_argument("--cells", default=",".join(map(str, tj.CHARACTER_CELLS)))
    ap.add_argument("--kappa", type=float, default=2.0)
    ap.add_argument("--samples", type=int, default=24, help="samples per cell edge (m)")
    ap.add_argument("--iterations", type=int, default=30)
    ap.add_argument("--finger-gap", type=float, default=0.004)
    pose = ap.add_mutually_exclusive_group()
    pose.add_argument("--palm-part", action="store_true", help="the palm's group without the fingers' roots")
    pose.add_argument("--wrist", action="store_true", help="palm and fingertips turned 90 deg about the wrist")
    pose.add_argument("--follow", action="store_true", help="the palm alone turned 90 deg, the fingers free")
    ap.add_argument("--compare", action="store_true", help="the engine's lattice too, in the same solver")
    ap.add_argument("--branch-brace", type=float, default=0.0, help="mu of the branch braces (0: none)")
    hold = ap.add_mutually_exclusive_group()
    hold.add_argument("--face", action="store_true", help="every split copy keeps a face on the trunk's side")
    hold.add_argument("--anchor", action="store_true", help="every split copy keeps a corner on the trunk's side")
    ap.add_argument("--couple", type=float, default=0.0, help="branch rotations answer for their trunk's edges (lambda)")
    ap.add_argument("--whole-weights", action="store_true", help="split copies weigh as their cell did")
    ap.add_argument("--comb", action="store_true", help="test_topology's comb instead (with --anchor --couple; "
                    "--follow: the base turned, the tines free)")
    a = ap.parse_args()
    hold = "face" if a.face else "anchor" if a.anchor else "none"
    if a.comb:
        for name, v in comb_sweep(a.follow, a.kappa, a.samples, a.couple, hold).items():
            v = np.array(v)
            print(f"{name}: {(v <= 1.0).sum()} of {len(v)} within 1%, median {np.median(v):.2f}%, worst {v.max():.2f}%")
        return
    kinds = ([("engine", False)] if a.compare else []) + [("per branch", True)]
    worst = {k: [] for k, _ in kinds}
    turned = a.wrist or a.follow
    for turn in [float(x) for x in a.angles.split(",")]:
        for cells in [int(c) for c in a.cells.split(",")]:
            case = Case(turn, cells, a.finger_gap, a.palm_part, a.wrist, a.follow)
            case.mu_branch, case.couple, case.hold, case.whole = a.branch_brace, a.couple, hold, a.whole_weights
            line = []
            for name, per_branch in kinds:
                X, info = case.solve(per_branch, a.kappa, a.samples, a.iterations)
                drag, miss, stretch, off = case.figures(X)
                value = off if turned else drag
                worst[name].append(value)
                line.append(f"{name}: {'off the turn' if turned else 'drag'} {value:5.2f}%"
                            + ("" if turned else f", tip miss {miss:4.1f}%, stretch {stretch:4.1f}%") + info)
            print(f"{turn:3.0f} deg {cells:5d} cells | " + " | ".join(line), flush=True)
    for name, v in worst.items():
        v = np.array(v)
        print(f"{name}: {(v <= 1.0).sum()} of {len(v)} within 1%, median {np.median(v):.2f}%, worst {v.max():.2f}%")


if __name__ == "__main__":
    main()
