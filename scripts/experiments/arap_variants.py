"""Reference ARAP solver on the engine's own lattice, to test energy variants (issue 9: the comb's
neighbouring tines are dragged when one tine turns). Research code, not used by the add-on.

The lattice (nodes, cell copies, edges), the trilinear handle binding and the B-spline vertex
binding are read from a larap.Deformer; the energy and the flip-flop solve are re-done here in
numpy/scipy so the rotation structure and the edge weights can be changed:

  E = gamma_eff * sum_terms w_t |(x_i - x_k) - R_{r(t)} (c_i - c_k)|^2 + sum_j alpha_j |B_j x - t_j|^2

A term is one (edge, rotation) pair:
  "node"      the engine's energy: every lattice edge twice, once with each end's rotation;
  "cell"      element ARAP: each cell copy's 12 edges with one rotation per copy;
  "nodecell"  a rotation per (node, cell copy) over the node's 3 edges in that copy;
weights: 1, or per (cell copy, edge) from the material the copy holds (cell_weights: its fraction
of the cell, or the fraction of the quarter cell next to the edge); for "node" an edge's weight
is the sum of its copies' weights over the 4 cell slots around it, / 4.
gamma_eff = gamma * s^2 / (h^2 * sum_t w_t) (the engine's normalisation: mean strain term).
"""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla


# ----------------------------------------------------------------------------- lattice
class Lat:
    """The engine's lattice, real nodes only (shell nodes are for the B-spline transfer)."""

    def __init__(self, d, V):
        self.d = d
        self.V = np.asarray(V, float)
        self.cells = d.cell_nodes().astype(np.int64)
        self.nr = int(self.cells.max()) + 1
        self.rest_all = d.lattice_rest()
        self.rest = self.rest_all[: self.nr].copy()
        self.edges = d.lattice_edges().astype(np.int64)
        self.h = d.cell_size
        self.origin = np.array(d._core.origin)
        self.coords = np.rint((self.rest_all - self.origin) / self.h).astype(np.int64)
        self.cell_coords = d._core.cell_coords().astype(np.int64)
        c = self.V.mean(0)
        self.s = float(np.sqrt(((self.V - c) ** 2).sum(1).mean()))
        cell, _ = d.trilinear_binding()  # its float32 fractions are refined from V below
        self.vcell = cell.astype(np.int64)
        self.tri_ids, self.tri_w = self.trilinear_rows(self.vcell, self.V)
        self._bs = None

    def trilinear_rows(self, cells, P):
        """(ids, weights), n by 8, of points P read in the cell copies `cells` (corner q at
        (q & 1, q >> 1 & 1, q >> 2))."""
        f = np.clip((P - self.rest[self.cells[cells, 0]]) / self.h, 0.0, 1.0)
        ids = np.empty((len(P), 8), np.int64)
        w = np.empty((len(P), 8))
        for q in range(8):
            b = np.array([q & 1, (q >> 1) & 1, q >> 2])
            ids[:, q] = self.cells[cells, q]
            w[:, q] = np.prod(np.where(b == 1, f, 1.0 - f), axis=1)
        return ids, w

    def tri_matrix(self, rows=None):
        ids, w = self.tri_ids, self.tri_w
        if rows is not None:
            ids, w = ids[rows], w[rows]
        m = len(ids)
        return sp.csr_matrix((w.ravel(), (np.repeat(np.arange(m), 8), ids.ravel())), shape=(m, self.nr))

    # B-spline transfer: the engine's 27-node rows, shell nodes expanded into real ones.
    def bspline_matrix(self):
        if self._bs is not None:
            return self._bs
        S = self.shell_map()
        rows, cols, vals = [], [], []
        for v in range(len(self.V)):
            ids, w = self.d._core.binding_weights(v)
            for i, x in zip(ids, w):
                if x == 0.0:
                    continue
                if i < self.nr:
                    rows.append(v); cols.append(i); vals.append(x)
                else:
                    for j, y in S[i - self.nr]:
                        rows.append(v); cols.append(j); vals.append(x * y)
        self._bs = sp.csr_matrix((vals, (rows, cols)), shape=(len(self.V), self.nr))
        return self._bs

    def shell_map(self):
        """Per shell node, its (real node, weight) terms (docs/method.md, Stencil shell)."""
        nr, C = self.nr, self.coords
        oi = lambda dx, dy, dz: (dx + 1) + 3 * (dy + 1) + 9 * (dz + 1)
        NONE, AMB = -1, -2
        cover = np.full(27 * nr, NONE, np.int64)
        for cn in self.cells:
            for a in range(8):
                for b in range(8):
                    k = oi((b & 1) - (a & 1), ((b >> 1) & 1) - ((a >> 1) & 1), (b >> 2) - (a >> 2))
                    i = 27 * cn[a] + k
                    if cover[i] == NONE:
                        cover[i] = cn[b]
                    elif cover[i] != cn[b]:
                        cover[i] = AMB
        parent = np.arange(27 * nr)
        real = np.where(cover >= 0, cover, NONE)

        def find(x):
            while parent[x] != x:
                parent[x] = parent[parent[x]]
                x = parent[x]
            return x

        adj = [[] for _ in range(nr)]
        for u, v in self.edges:
            adj[u].append(v); adj[v].append(u)
        for u, v in self.edges:
            step = C[v] - C[u]
            if step.sum() < 0:
                u, v, step = v, u, -step
            axis = int(np.flatnonzero(step)[0])
            for dz in (-1, 0, 1):
                for dy in (-1, 0, 1):
                    for dx in (-1, 0, 1):
                        dd = [dx, dy, dz]
                        if dd[axis] < 0:
                            continue
                        iu = 27 * u + oi(*dd)
                        dd[axis] -= 1
                        iv = 27 * v + oi(*dd)
                        if cover[iu] == AMB or cover[iv] == AMB:
                            continue
                        ru, rv = find(iu), find(iv)
                        if ru == rv:
                            continue
                        pu, pv = real[ru], real[rv]
                        if pu >= 0 and pv >= 0 and pu != pv:
                            continue
                        root, other = min(ru, rv), max(ru, rv)
                        parent[other] = root
                        real[root] = pu if pu >= 0 else pv

        def nbrs(n, axis, dr):
            return [m for m in adj[n] if C[m][axis] - C[n][axis] == dr]

        shell_of, members, items = {}, [], []
        for i in range(27 * nr):
            r = find(i)
            if real[r] >= 0:
                continue
            key = i if cover[i] == AMB else r
            if key not in shell_of:
                shell_of[key] = len(members)
                members.append(0)
            s = shell_of[key]
            members[s] += 1
            items.append((i, s))
        terms = [dict() for _ in members]
        for i, s in items:
            n, k = i // 27, i % 27
            d = (k % 3 - 1, (k // 3) % 3 - 1, k // 9 - 1)
            sc = 1.0 / members[s]
            t = terms[s]
            t[n] = t.get(n, 0.0) + sc
            for a in range(3):
                if d[a] == 0:
                    continue
                fw = nbrs(n, a, d[a])
                if fw:
                    for m in fw:
                        t[m] = t.get(m, 0.0) + sc / len(fw)
                        t[n] = t.get(n, 0.0) - sc / len(fw)
                else:
                    bw = nbrs(n, a, -d[a])
                    for m in bw:
                        t[n] = t.get(n, 0.0) + sc / len(bw)
                        t[m] = t.get(m, 0.0) - sc / len(bw)
        return [[(j, w) for j, w in sorted(t.items()) if w != 0.0] for t in terms]


# ----------------------------------------------------------------------------- material
def material_masks(lat: Lat, inside, k=12):
    """Per cell copy, the (k, k, k) mask (index order x, y, z) of the samples its piece fills;
    inside(P) -> bool; the samples inside the solid are split into 6-connected pieces per cell
    and each piece goes to the copy that most of the vertices nearest to it bind to."""
    C = len(lat.cells)
    masks = np.zeros((C, k, k, k), bool)
    g = (np.arange(k) + 0.5) / k
    G = np.stack(np.meshgrid(g, g, g, indexing="ij"), -1).reshape(-1, 3)
    by_coord = {}
    for c, cc in enumerate(lat.cell_coords):
        by_coord.setdefault(tuple(cc), []).append(c)
    vert_by_cell = {}
    for v, c in enumerate(lat.vcell):
        vert_by_cell.setdefault(c, []).append(v)
    for cc, copies in by_coord.items():
        lo = lat.origin + lat.h * np.array(cc)
        P = lo + lat.h * G
        ins = inside(P).reshape(k, k, k)
        if len(copies) == 1:
            masks[copies[0]] = ins
            continue
        lab = _label(ins)
        verts = [(v, c) for c in copies for v in vert_by_cell.get(c, [])]
        for piece in range(1, lab.max() + 1):
            pts = P[lab.ravel() == piece]
            if not verts:
                continue
            vv = np.array([v for v, _ in verts])
            dist = np.linalg.norm(lat.V[vv][None, :, :] - pts[:, None, :], axis=2)
            near = np.array([verts[j][1] for j in dist.argmin(1)])
            vals, cnt = np.unique(near, return_counts=True)
            masks[vals[cnt.argmax()]] |= lab == piece
    return masks


def cell_weights(masks, mode="fraction"):
    """(C, 12) weights of each copy's edges (CELL_EDGES order): "fraction": the copy's material
    fraction on all 12; "quadrant": an edge along axis a gets the material fraction of the
    quarter of the cell (split across the two other axes) that touches it."""
    C, k = len(masks), masks.shape[1]
    W = np.zeros((C, 12))
    if mode == "fraction":
        W[:] = masks.reshape(C, -1).mean(1)[:, None]
        return W
    half = k // 2
    for e, (a, b) in enumerate(CELL_EDGES):
        ax = int(np.log2(a ^ b))
        sl = [slice(None)] * 3
        for o in range(3):
            if o != ax:
                bit = (a >> o) & 1
                sl[o] = slice(half, k) if bit else slice(0, half)
        W[:, e] = masks[(slice(None), *sl)].reshape(C, -1).mean(1)
    return W


def _label(mask):
    lab = np.zeros(mask.shape, np.int64)
    n = 0
    for start in zip(*np.nonzero(mask)):
        if lab[start]:
            continue
        n += 1
        stack = [start]
        lab[start] = n
        while stack:
            p = stack.pop()
            for a in range(3):
                for s in (-1, 1):
                    q = list(p); q[a] += s; q = tuple(q)
                    if 0 <= q[a] < mask.shape[a] and mask[q] and not lab[q]:
                        lab[q] = n
                        stack.append(q)
    return lab


def boxes_inside(boxes):
    def inside(P):
        r = np.zeros(len(P), bool)
        for lo, hi in boxes:
            r |= np.all((P >= np.asarray(lo)) & (P <= np.asarray(hi)), axis=1)
        return r
    return inside


def winding_inside(V, tris):
    """Generalised winding number > 0.5 (closed or nearly closed meshes)."""
    A, B, Cc = V[tris[:, 0]], V[tris[:, 1]], V[tris[:, 2]]

    def inside(P):
        out = np.zeros(len(P))
        for s in range(0, len(P), 256):
            p = P[s:s + 256, None, :]
            a, b, c = A[None] - p, B[None] - p, Cc[None] - p
            la, lb, lc = (np.linalg.norm(x, axis=2) for x in (a, b, c))
            det = np.einsum("ijk,ijk->ij", a, np.cross(b, c))
            den = la * lb * lc + np.einsum("ijk,ijk->ij", a, b) * lc + np.einsum("ijk,ijk->ij", b, c) * la \
                + np.einsum("ijk,ijk->ij", c, a) * lb
            out[s:s + 256] = 2 * np.arctan2(det, den).sum(1) / (4 * np.pi)
        return np.abs(out) > 0.5
    return inside


# ----------------------------------------------------------------------------- energy terms
CELL_EDGES = [(0, 1), (2, 3), (4, 5), (6, 7), (0, 2), (1, 3), (4, 6), (5, 7), (0, 4), (1, 5), (2, 6), (3, 7)]


def split_copy_weights(lat: Lat, masks, floor=0.05):
    """(C,) the engine's rule with these masks: a copy of a split cell weighs its material
    fraction (at least `floor`), every other cell 1."""
    frac = masks.reshape(len(masks), -1).mean(1)
    by_coord = {}
    for c, cc in enumerate(lat.cell_coords):
        by_coord.setdefault(tuple(cc), []).append(c)
    w = np.ones(len(lat.cells))
    for copies in by_coord.values():
        if len(copies) > 1:
            w[copies] = np.maximum(frac[copies], floor)
    return w


def mean_over_copies(lat: Lat, wc):
    """(E,) the engine's edge rule: an edge weighs the mean of wc over the copies it is an edge of."""
    acc = {}
    for c, cn in enumerate(lat.cells):
        for a, b in CELL_EDGES:
            acc.setdefault((min(cn[a], cn[b]), max(cn[a], cn[b])), []).append(wc[c])
    return np.array([np.mean(acc[(min(u, v), max(u, v))]) for u, v in lat.edges])


def terms(lat: Lat, rotations="node", cw=None, floor=1e-3, edge_w=None):
    """(i, k, w, r) arrays of the energy terms and the number of rotations; cw: (C, 12) weights
    of the copies' edges (None: 1), floored at `floor`; edge_w: (E,) weights of the lattice's
    edges for node rotations (the engine's rule: mean_over_copies), instead of cw."""
    if edge_w is not None and rotations == "node":
        E = lat.edges
        i = np.concatenate([E[:, 0], E[:, 1]])
        k = np.concatenate([E[:, 1], E[:, 0]])
        return i, k, np.concatenate([edge_w, edge_w]), i.copy(), lat.nr
    unit = cw is None
    cw = np.ones((len(lat.cells), 12)) if unit else np.maximum(cw, floor)
    if rotations == "node":
        # an edge's weight: mean over the 4 cell slots around it of the copies' weights
        acc = {}
        for c, cn in enumerate(lat.cells):
            for q, (a, b) in enumerate(CELL_EDGES):
                key = (min(cn[a], cn[b]), max(cn[a], cn[b]))
                acc[key] = acc.get(key, 0.0) + cw[c, q] / 4.0
        E = lat.edges
        w = np.array([acc[(min(u, v), max(u, v))] for u, v in E])
        if unit:  # the engine: every edge once, whatever the number of cells around it
            w = np.ones(len(E))
        i = np.concatenate([E[:, 0], E[:, 1]])
        k = np.concatenate([E[:, 1], E[:, 0]])
        return i, k, np.concatenate([w, w]), i.copy(), lat.nr
    if rotations == "cell":
        I, K, W, R = [], [], [], []
        for q, (a, b) in enumerate(CELL_EDGES):
            I.append(lat.cells[:, a]); K.append(lat.cells[:, b]); W.append(cw[:, q]); R.append(np.arange(len(lat.cells)))
        return np.concatenate(I), np.concatenate(K), np.concatenate(W), np.concatenate(R), len(lat.cells)
    if rotations == "nodecell":
        I, K, W, R = [], [], [], []
        C = len(lat.cells)
        for a in range(8):
            for axis in range(3):
                b = a ^ (1 << axis)
                q = CELL_EDGES.index((min(a, b), max(a, b)))
                I.append(lat.cells[:, a]); K.append(lat.cells[:, b]); W.append(cw[:, q] / 2.0)
                R.append(np.arange(C) * 8 + a)
        return np.concatenate(I), np.concatenate(K), np.concatenate(W), np.concatenate(R), 8 * C
    raise ValueError(rotations)


def best_rotations(S):
    U, _, Vt = np.linalg.svd(S)
    D = np.ones((len(S), 3))
    D[:, 2] = np.sign(np.linalg.det(U @ Vt))
    D[D[:, 2] == 0, 2] = 1.0
    return (U * D[:, None, :]) @ Vt


class Solver:
    def __init__(self, lat: Lat, handle_rows, alpha, gamma=0.1, rotations="node", cw=None, floor=1e-3,
                 edge_w=None, extra_terms=None, fixed=()):
        """extra_terms: a function (i, k, w, r, cw) -> (i, k, w, r) of terms to add to those of
        `rotations` (cw: the (C, 12) copy-edge weights as floored); fixed: (mu, G) pairs, each adding
        mu * gamma_eff * |G x|^2 (a fixed quadratic: braces, glues) to the system before it is
        factorised."""
        self.lat = lat
        self.i, self.k, self.w, self.r, self.nrot = terms(lat, rotations, cw, floor, edge_w)
        if extra_terms is not None:
            cwf = np.maximum(np.ones((len(lat.cells), 12)) if cw is None else cw, floor)
            self.i, self.k, self.w, self.r = extra_terms(self.i, self.k, self.w, self.r, cwf)
        self.e = lat.rest[self.i] - lat.rest[self.k]
        self.geff = gamma * lat.s ** 2 / (lat.h ** 2 * self.w.sum())
        n = lat.nr
        D = sp.csr_matrix((np.concatenate([self.w, -self.w]),
                           (np.concatenate([np.arange(len(self.i))] * 2), np.concatenate([self.i, self.k]))),
                          shape=(len(self.i), n))
        self.Dt = sp.csr_matrix((np.concatenate([np.ones_like(self.w), -np.ones_like(self.w)]),
                                 (np.concatenate([self.i, self.k]), np.concatenate([np.arange(len(self.i))] * 2))),
                                shape=(n, len(self.i)))
        Lw = (self.Dt @ D).tocsc()
        self.B = lat.tri_matrix(handle_rows)
        self.alpha = alpha
        A = sp.diags(alpha)
        M = self.geff * Lw + (self.B.T @ A @ self.B)
        for mu, G in fixed:
            M = M + mu * self.geff * (G.T @ G)
        self.M = M  # the system matrix
        # components without handles stay at rest (as the engine does)
        self.solve_lin = spla.factorized(sp.csc_matrix(M))
        self.BtA = (self.B.T @ A).tocsr()

    def rotations(self, X):
        d = X[self.i] - X[self.k]
        S = np.zeros((self.nrot, 3, 3))
        np.add.at(S, self.r, self.w[:, None, None] * d[:, :, None] * self.e[:, None, :])
        return best_rotations(S)

    def energy(self, X, T, R=None):
        R = self.rotations(X) if R is None else R
        d = X[self.i] - X[self.k] - np.einsum("tab,tb->ta", R[self.r], self.e)
        hres = self.B @ X - T
        return self.geff * (self.w * (d ** 2).sum(1)).sum() + (self.alpha * (hres ** 2).sum(1)).sum()

    def solve(self, T, iterations=200, X0=None):
        X = self.lat.rest.copy() if X0 is None else X0.copy()
        bt = self.BtA @ T
        for _ in range(iterations):
            R = self.rotations(X)
            Re = np.einsum("tab,tb->ta", R[self.r], self.e) * self.w[:, None]
            rhs = self.geff * (self.Dt @ Re) + bt
            X = np.stack([self.solve_lin(rhs[:, c]) for c in range(3)], 1)
        return X


def group_alpha(groups, weights=None):
    G = len(groups)
    alpha = []
    for g, ids in enumerate(groups):
        wg = 1.0 if weights is None else weights[g]
        alpha.append(np.full(len(ids), wg / G / len(ids)))
    return np.concatenate(groups), np.concatenate(alpha)


def group_targets(V, groups, T):
    return np.concatenate([V[g] @ T[k][:3, :3].T + T[k][:3, 3] for k, g in enumerate(groups)])


def transfer(lat: Lat, X, kind="trilinear"):
    M = lat.tri_matrix() if kind == "trilinear" else lat.bspline_matrix()
    return lat.V + M @ (X - lat.rest)
