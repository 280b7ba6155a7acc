# Run: PYTHONPATH=python /usr/bin/python3 -m pytest tests/python/test_topology.py
"""Cell splitting, the stencil shell and the topology-preserving hierarchy (issue 9): parts closer
than a cell do not move together, pinned parts stay put at every level count, and the real
lattice's pose does not depend on the weight kind. Poses are made with handle groups, as artists
make them."""
import os

import numpy as np
import pytest
from conftest import diagonal, rotation

import larap
from larap import shapes

H = 1.0  # cell size of the generated models


def affine(R=np.eye(3), pivot=(0, 0, 0)):
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = np.asarray(pivot, float) - R @ np.asarray(pivot, float)
    return T


def apply(T, X):
    return X @ T[:3, :3].T + T[:3, 3]


def comb(tines=3, gap=0.1, width=1.0, height=1.0, length=6.0):
    """A base block with `tines` bars along +x, `gap` cells apart in y, joined at the base (the
    tines reach into the base block: a soup joint, as separate mesh parts). The base ends just
    before the cell boundary x = 0, so the lattice joins the tines in the cell before it."""
    pitch = width + gap
    y1 = tines * pitch - gap
    parts = [shapes.box((-3.0, 0.0, 0.0), (-0.1, y1, height), 6)]
    spans = []
    for t in range(tines):
        y0 = t * pitch
        parts.append(shapes.box((-0.5, y0, 0.0), (length, y0 + width, height), 6))
        spans.append((y0, y0 + width))
    V, F = shapes.concat(*parts)
    counts = np.cumsum([0] + [len(p[0]) for p in parts])
    tine_ids = [np.arange(counts[t + 1], counts[t + 2]) for t in range(tines)]
    return V, F, tine_ids, spans


def comb_pose(V, tine_ids, moved, degrees=60.0):
    """Groups: the base, and the tip of every tine; the tip of tine `moved` turned
    `degrees` about the y axis through its root (it lifts out of the comb's plane)."""
    base = np.flatnonzero(V[:, 0] <= -0.05)  # the whole base block (a palm held in place)
    tips = [ids[V[ids, 0] >= 5.0] for ids in tine_ids]
    groups = [base] + tips
    T = [np.eye(4) for _ in groups]
    T[1 + moved] = affine(rotation([0, -1, 0], degrees), pivot=(0.0, 0.0, 0.5))
    return groups, np.stack(T)


@pytest.mark.xfail(strict=True, reason="not met yet (2026-11-22): the tines share the 4 nodes of "
                   "their root face, whose tilt drags the neighbours 1.7% of the comb's diagonal "
                   "(target 1%; the plain lattice: see the test below); the hand test meets it")
@pytest.mark.parametrize("weights", ["trilinear", "bspline"])
@pytest.mark.parametrize("levels", [1, 2, 3, 4])
def test_comb_tine_turned_leaves_its_neighbours(weights, levels):
    V, F, tine_ids, _ = comb()
    d = larap.Deformer(V, F, cell_size=H, weights=weights, levels=levels)
    groups, T = comb_pose(V, tine_ids, moved=1)
    d.set_handle_groups(groups)
    X = d.solve(transforms=T, iterations=30)
    size = diagonal(V)
    for t in (0, 2):
        drag = np.linalg.norm(X[tine_ids[t]] - V[tine_ids[t]], axis=1).max()
        assert drag <= 0.01 * size, (t, drag / size)
    tip = groups[2]
    miss = np.linalg.norm(X[tip] - apply(T[2], V[tip]), axis=1).max()
    assert miss <= 0.03 * 6.0, miss / 6.0


def test_without_splitting_the_tines_move_together():
    """The same pose on the plain lattice drags the neighbours (what splitting fixes)."""
    V, F, tine_ids, _ = comb()
    d = larap.Deformer(V, F, cell_size=H, split_cells=False)
    groups, T = comb_pose(V, tine_ids, moved=1)
    d.set_handle_groups(groups)
    X = d.solve(transforms=T, iterations=30)
    drag = max(np.linalg.norm(X[tine_ids[t]] - V[tine_ids[t]], axis=1).max() for t in (0, 2))
    assert drag > 0.05 * diagonal(V)


def test_split_lattice_keeps_tines_apart():
    V, F, tine_ids, _ = comb()
    split = larap.Deformer(V, F, cell_size=H)
    plain = larap.Deformer(V, F, cell_size=H, split_cells=False)
    assert split.num_cells > plain.num_cells  # cells the tines share are kept once per tine
    assert split.num_components == 1  # joined at the base
    # Where nothing is split the lattice is the plain one: a lone bar is the same either way.
    Vb, Fb = shapes.box((0, 0, 0), (6, 0.6, 0.8), 6)
    a, b = larap.Deformer(Vb, Fb, cell_size=H), larap.Deformer(Vb, Fb, cell_size=H, split_cells=False)
    assert a.num_cells == b.num_cells and a.num_nodes == b.num_nodes


def bars(spacing, length=8.0, side=0.8):
    a = shapes.box((0.0, 0.0, 0.0), (length, side, side), 8)
    b = shapes.box((0.0, side + spacing, 0.0), (length, 2 * side + spacing, side), 8)
    V, F = shapes.concat(a, b)
    n = len(a[0])
    return V, F, np.arange(n), np.arange(n, len(V))


def bend_first_pin_second(V, first, second, length=8.0):
    """Groups: the first bar's two ends (its far end turned 90 degrees about z), the second bar's
    two ends held at rest."""
    lo = lambda ids: ids[V[ids, 0] <= 0.1 * length]
    hi = lambda ids: ids[V[ids, 0] >= 0.9 * length]
    groups = [lo(first), hi(first), lo(second), hi(second)]
    T = [np.eye(4)] * 4
    T[1] = affine(rotation([0, 0, 1], -90), pivot=(0.5 * length, -0.5 * length, 0.4))
    return groups, np.stack(T)


@pytest.mark.parametrize("spacing,levels", [(2.5, 1), (2.5, 2), (2.5, 3), (2.5, 4), (5.0, 3)])
@pytest.mark.parametrize("weights", ["trilinear", "bspline"])
def test_pinned_bar_stays_while_its_neighbour_bends(spacing, levels, weights):
    V, F, first, second = bars(spacing)
    d = larap.Deformer(V, F, cell_size=H, weights=weights, levels=levels)
    groups, T = bend_first_pin_second(V, first, second)
    d.set_handle_groups(groups)
    X = d.solve(transforms=T, iterations=5)
    moved = np.linalg.norm(X[second] - V[second], axis=1).max()
    assert moved <= 0.005 * 8.0, moved / 8.0
    assert np.linalg.norm(X[groups[1]] - V[groups[1]], axis=1).mean() > 2.0  # the first bar did bend


@pytest.mark.parametrize("weights", ["trilinear", "bspline"])
@pytest.mark.parametrize("levels", [1, 2, 3])
def test_separate_part_with_still_handles_does_not_move(weights, levels):
    """Two blocks 0.3 cells apart (they share cells): the second's handles stay at rest while the
    first is moved; after one iteration the second has moved at most 0.1% of its length."""
    a = shapes.box((0.0, 0.0, 0.0), (4.0, 1.0, 1.0), 6)
    b = shapes.box((0.0, 1.3, 0.0), (4.0, 2.3, 1.0), 6)
    V, F = shapes.concat(a, b)
    n = len(a[0])
    first, second = np.arange(n), np.arange(n, len(V))
    d = larap.Deformer(V, F, cell_size=H, weights=weights, levels=levels)
    assert d.num_components == 2
    groups = [first[V[first, 0] < 0.5], first[V[first, 0] > 3.5], second[V[second, 0] < 0.5],
              second[V[second, 0] > 3.5]]
    d.set_handle_groups(groups)
    T = np.stack([np.eye(4), affine(rotation([0, 1, 0], 45), pivot=(2.0, 0.5, 0.5)), np.eye(4), np.eye(4)])
    d.solve(transforms=T, iterations=10)
    T[1] = affine(rotation([0, 1, 0], -45), pivot=(2.0, 0.5, 0.5))
    X = d.solve(transforms=T, iterations=1)
    assert np.linalg.norm(X[second] - V[second], axis=1).max() <= 0.001 * 4.0


def test_lattice_pose_does_not_depend_on_the_weight_kind():
    V, F, tine_ids, _ = comb()
    groups, T = comb_pose(V, tine_ids, moved=0)
    poses = {}
    for weights in ("trilinear", "bspline"):
        d = larap.Deformer(V, F, cell_size=H, weights=weights)
        d.set_handle_groups(groups)
        d.solve(transforms=T, iterations=10)
        poses[weights] = d.lattice_deformed()
    assert np.abs(poses["trilinear"] - poses["bspline"]).max() <= 1e-9 * diagonal(V)
    # switching the kind keeps the pose and needs no new factorisation
    d.weights = "trilinear"
    assert np.abs(d.lattice_deformed() - poses["bspline"]).max() == 0.0


def test_bspline_shell_follows_rigid_motion_and_is_continuous():
    """The shell reproduces a rigid motion exactly, and the B-spline output is continuous: two
    vertices at the same place on the two sides of a cell face (or cell centre) land together."""
    V, F = shapes.tube(length=4.0, radius=0.5, segments=24, rings=48)
    d = larap.Deformer(V, F, cell_size=0.3, weights="bspline")
    ends = [np.flatnonzero(V[:, 0] < 0.3), np.flatnonzero(V[:, 0] > 3.7)]
    d.set_handle_groups(ends)
    M = affine(rotation([1, 2, 3], 50), pivot=(2, 0, 0))
    X = d.solve(transforms=np.stack([M, M]), iterations=30)
    assert np.linalg.norm(X - apply(M, V), axis=1).max() <= 1e-3 * diagonal(V)
    T = np.stack([np.eye(4), affine(rotation([0, 0, 1], 90), pivot=(2.0, 0.0, 0.0))])
    X = d.solve(transforms=T, iterations=30)
    # Neighbouring vertices stay neighbours: edge lengths change smoothly (no cracks).
    tris = np.array([[f[0], f[k], f[k + 1]] for f in F for k in range(1, len(f) - 1)])
    e0 = np.linalg.norm(V[tris[:, 0]] - V[tris[:, 1]], axis=1)
    e1 = np.linalg.norm(X[tris[:, 0]] - X[tris[:, 1]], axis=1)
    assert np.max(e1 / e0) < 1.6


def finger_parts(V, tris, s, cut):
    """Connected components (through triangles) of the vertices with s > cut, 20 or more each."""
    far = s > cut
    parent = np.arange(len(V))

    def find(x):
        while parent[x] != x:
            parent[x] = parent[parent[x]]
            x = parent[x]
        return x

    for a, b, c in tris[far[tris].all(1)]:
        for u, v in ((a, b), (a, c)):
            ru, rv = find(u), find(v)
            if ru != rv:
                parent[max(ru, rv)] = min(ru, rv)
    roots = np.array([find(v) if far[v] else -1 for v in range(len(V))])
    labels, counts = np.unique(roots[roots >= 0], return_counts=True)
    return [np.flatnonzero(roots == r) for r in labels[counts >= 20]]


def hand_finger_pose(V, F):
    """The hand's pose of issue 9: fingers found from the mesh (along its main axis, the parts
    beyond a cut), the palm and every fingertip held, the longest finger turned 60 degrees about
    its root, out of the plane of the hand. Returns (groups = [palm] + tips, transforms (G,4,4),
    fingers, index of the moved finger, its length along the main axis)."""
    tris = np.array([[f[0], f[k], f[k + 1]] for f in F for k in range(1, len(f) - 1)])
    _, _, W = np.linalg.svd(V - V.mean(0), full_matrices=False)
    best = None
    for sign in (1.0, -1.0):
        s = sign * ((V - V.mean(0)) @ W[0])
        for frac in (0.6, 0.65, 0.7, 0.75):
            parts = finger_parts(V, tris, s, s.min() + frac * np.ptp(s))
            if best is None or len(parts) > len(best[1]):
                best = (s, parts, sign)
    s, fingers, sign = best
    axis = sign * W[0]
    palm = np.flatnonzero(s < s.min() + 0.35 * np.ptp(s))
    tips = [f[s[f] > np.quantile(s[f], 0.6)] for f in fingers]
    moved = int(np.argmax([len(f) for f in fingers])) if fingers else 0
    T = [np.eye(4) for _ in range(1 + len(tips))]
    if fingers:
        finger = fingers[moved]
        root = V[finger[np.argmin(s[finger])]]
        # turn about the axis across the hand (normal to the palm's plane x main axis): the
        # finger curls out of the plane of the hand, away from its neighbours
        T[1 + moved] = affine(rotation(np.cross(axis, W[2]), 60), pivot=root)
    length = float(np.ptp(s[fingers[moved]])) if fingers else 0.0
    return [palm] + tips, np.stack(T), fingers, moved, length


@pytest.mark.parametrize("weights", ["trilinear", "bspline"])
def test_hand_finger_turned_leaves_the_other_fingers(shared_meshes, weights):
    """hand_lowres.obj: palm and the other fingertips held, one finger turned 60 degrees about its
    root. Fingers are found from the mesh: along its main axis, the parts beyond a cut."""
    path = os.path.join(shared_meshes, "hand_lowres.obj")
    if not os.path.exists(path):
        pytest.skip("hand_lowres.obj not present")
    V, F = larap.load_mesh(path)
    size = diagonal(V)
    groups, T, fingers, moved, length = hand_finger_pose(V, F)
    assert len(fingers) >= 4, f"found {len(fingers)} fingers"
    tips = groups[1:]
    d = larap.Deformer(V, F, weights=weights)
    d.set_handle_groups(groups)
    X = d.solve(transforms=T, iterations=30)
    miss = np.linalg.norm(X[tips[moved]] - apply(T[1 + moved], V[tips[moved]]), axis=1).max()
    assert miss <= 0.03 * length, miss / length
    for k, f in enumerate(fingers):
        if k != moved:
            drag = np.linalg.norm(X[f] - V[f], axis=1).max()
            assert drag <= 0.01 * size, (k, drag / size)
