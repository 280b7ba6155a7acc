"""Measures of a pose's quality, written once for the benchmarks, the evidence report and tests.

All take rest positions V (n, 3), deformed positions X (n, 3) and plain numpy arrays; lengths
are returned relative to the rest bounding-box diagonal where they say so.

    from larap import quality
    tris = quality.triangles(F)
    quality.volume_change(V, X, tris)               # relative, closed meshes only
    quality.edge_distortion(V, X, quality.edges(tris))  # {"mean", "p95"} of |l'/l - 1|
"""
from __future__ import annotations

import numpy as np


def diagonal(V) -> float:
    """Length of the bounding-box diagonal."""
    V = np.asarray(V, float)
    return float(np.linalg.norm(V.max(0) - V.min(0)))


def triangles(F) -> np.ndarray:
    """(t, 3) int64 triangles of polygons F ((m, k) array or list of lists), fan-triangulated;
    faces of fewer than 3 vertices (loose edges, points) give none."""
    if isinstance(F, np.ndarray) and F.ndim == 2:
        k = F.shape[1]
        if k < 3:  # loose edges or points: no triangle
            return np.zeros((0, 3), np.int64)
        return np.concatenate([F[:, [0, j, j + 1]] for j in range(1, k - 1)]).astype(np.int64)
    tris = [(f[0], f[j], f[j + 1]) for f in F for j in range(1, len(f) - 1)]
    return np.asarray(tris, np.int64).reshape(-1, 3)


def edges(tris) -> np.ndarray:
    """(e, 2) unique undirected edges of triangles."""
    e = np.concatenate([tris[:, [0, 1]], tris[:, [1, 2]], tris[:, [2, 0]]])
    return np.unique(np.sort(e, axis=1), axis=0)


def is_closed(tris) -> bool:
    """Every edge shared by exactly two triangles (a volume is defined)."""
    e = np.sort(np.concatenate([tris[:, [0, 1]], tris[:, [1, 2]], tris[:, [2, 0]]]), axis=1)
    _, counts = np.unique(e, axis=0, return_counts=True)
    return bool(len(counts) and np.all(counts == 2))


def volume(X, tris) -> float:
    """Signed volume enclosed by the triangles (positive for outward-facing closed meshes)."""
    X = np.asarray(X, float)
    a, b, c = X[tris[:, 0]], X[tris[:, 1]], X[tris[:, 2]]
    return float(np.einsum("ij,ij->i", a, np.cross(b, c)).sum() / 6.0)


def volume_change(V, X, tris) -> float:
    """(vol(X) - vol(V)) / vol(V); NaN when the mesh is not closed."""
    if not is_closed(tris):
        return float("nan")
    v0 = volume(V, tris)
    return (volume(X, tris) - v0) / v0


def edge_distortion(V, X, edge_list) -> dict:
    """Mean and 95th percentile of |l'/l - 1| over the edges (0 = lengths kept)."""
    V, X = np.asarray(V, float), np.asarray(X, float)
    l0 = np.linalg.norm(V[edge_list[:, 0]] - V[edge_list[:, 1]], axis=1)
    l1 = np.linalg.norm(X[edge_list[:, 0]] - X[edge_list[:, 1]], axis=1)
    keep = l0 > 0
    r = np.abs(l1[keep] / l0[keep] - 1.0)
    return {"mean": float(r.mean()), "p95": float(np.percentile(r, 95))}


def handle_error(X, ids, targets, diag) -> float:
    """Largest distance of a handle vertex from its target, relative to `diag`."""
    d = np.linalg.norm(np.asarray(X, float)[ids] - targets, axis=1)
    return float(d.max() / diag) if d.size else 0.0


def displacement(V, X, ids, diag) -> float:
    """Largest displacement of the vertices `ids`, relative to `diag` (drag of parts that should
    stay still)."""
    if len(ids) == 0:
        return float("nan")
    return float(np.linalg.norm(np.asarray(X, float)[ids] - np.asarray(V, float)[ids], axis=1).max() / diag)


def rigid_fit(V, X):
    """Best rigid motion (R, t) taking V to X in the least-squares sense (Kabsch)."""
    V, X = np.asarray(V, float), np.asarray(X, float)
    cv, cx = V.mean(0), X.mean(0)
    U, _, Wt = np.linalg.svd((V - cv).T @ (X - cx))
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(Wt.T @ U.T))])
    R = Wt.T @ D @ U.T
    return R, cx - R @ cv


def rigidity_error(V, X, diag) -> float:
    """Largest distance from the best rigid motion of the whole mesh, relative to `diag`
    (0 when the pose is a rigid motion of the rest shape)."""
    R, t = rigid_fit(V, X)
    return float(np.linalg.norm(np.asarray(X, float) - (np.asarray(V, float) @ R.T + t), axis=1).max() / diag)


def dihedral_angles(X, tris):
    """(edges (e, 2), angles (e,), faces (e, 2)) for every edge shared by exactly two triangles:
    the angle between the two face normals, radians, and the two triangles' ids."""
    X = np.asarray(X, float)
    e = np.concatenate([tris[:, [0, 1]], tris[:, [1, 2]], tris[:, [2, 0]]])
    face = np.tile(np.arange(len(tris)), 3)
    key = np.sort(e, axis=1)
    order = np.lexsort((key[:, 1], key[:, 0]))
    key, face = key[order], face[order]
    _, first, counts = np.unique(key, axis=0, return_index=True, return_counts=True)
    ok = first[counts == 2]  # the edge's two faces sit at ok and ok + 1
    n = np.cross(X[tris[:, 1]] - X[tris[:, 0]], X[tris[:, 2]] - X[tris[:, 0]])
    n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-300)
    c = np.clip(np.einsum("ij,ij->i", n[face[ok]], n[face[ok + 1]]), -1.0, 1.0)
    return key[ok], np.arccos(c), np.stack([face[ok], face[ok + 1]], 1)


def dihedral_change(V, X, tris, cell_of=None) -> dict:
    """|dihedral(X) - dihedral(V)| in degrees over interior edges: mean, 95th percentile and
    maximum; given `cell_of` (n,) lattice cell ids per vertex, the same split into edges at a cell
    boundary (the vertices of the edge's two triangles lie in more than one cell: a boundary
    plane passes between them) and the rest ("inside")."""
    _, a0, faces = dihedral_angles(V, tris)
    _, a1, _ = dihedral_angles(X, tris)
    d = np.degrees(np.abs(a1 - a0))
    out = {"mean": float(d.mean()), "p95": float(np.percentile(d, 95)), "max": float(d.max())}
    if cell_of is not None:
        c = cell_of[tris[faces].reshape(len(faces), 6)]
        cross = np.any(c != c[:, :1], axis=1)
        for name, mask in (("boundary", cross), ("inside", ~cross)):
            out[name + "_mean"] = float(d[mask].mean()) if mask.any() else float("nan")
            out[name + "_p95"] = float(np.percentile(d[mask], 95)) if mask.any() else float("nan")
            out[name + "_edges"] = int(mask.sum())
    return out
