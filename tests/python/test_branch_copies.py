# Run: PYTHONPATH=python /usr/bin/python3 -m pytest tests/python/test_branch_copies.py
"""One copy per branch where separate parts meet (issue 9, session 31; native/src/branch_copies.h;
research stage, `_branch_copies=True`, off by default): on the generated character turned to the
lattice, where the engine's own lattice drags the other fingers up to 9.5% of the hand, a finger
turned 60 degrees leaves them within 1%; a finger without handles still follows its palm; rest,
rigid and affine poses are still reproduced, the energy never increases, both devices agree; a
mesh of one part gets the lattice it always had."""
import numpy as np
import pytest
from conftest import affine, need_cuda, rotation
from test_junctions import assert_rest_and_rigid, finger_pose, hand_size, turned_about_vertical

import larap
from larap import shapes

BRANCH = dict(_branch_copies=True)


def turned_character(turn):
    """The character, its finger pose, both turned `turn` degrees about the vertical, and the
    unturned hand's diagonal (test_junctions' yardstick at every angle)."""
    V, F, parts = shapes.character()
    groups, T = finger_pose(V, parts)
    size = hand_size(V, parts)
    if turn:
        V, T = turned_about_vertical(V, T, turn)
    return V, F, parts, groups, T, size


def drag_and_miss(V, parts, groups, T, X, size):
    """The other fingers' largest move (% of the hand) and the turned tip's miss (% of its finger)."""
    drag = max(np.linalg.norm(X[parts["fingers"][k]] - V[parts["fingers"][k]], axis=1).max() for k in (0, 2, 3))
    tip = groups[3]
    miss = np.linalg.norm(X[tip] - (V[tip] @ T[3][:3, :3].T + T[3][:3, 3]), axis=1).max()
    return 100 * drag / size, 100 * miss / 0.09


# (turn, cells): where the engine's own lattice drags the most (2026-11-25, trilinear, 30
# flip-flops: 7.1, 4.8, 6.4 and 9.5% of the hand).
WORST = ((30.0, 4000), (45.0, 4000), (45.0, 5500), (45.0, 6000))


@pytest.mark.parametrize("turn,cells", WORST)
def test_turned_hand_leaves_the_other_fingers(turn, cells):
    """Trilinear, 30 flip-flops: the other fingers within 1% of the hand and the tip within 3% of
    its finger, where the engine's own lattice drags them over 4% (measured 0.22-0.34%)."""
    V, F, parts, groups, T, size = turned_character(turn)
    out = {}
    for kw in ({}, BRANCH):
        d = larap.Deformer(V, F, cells=cells, **kw)
        d.set_handle_groups(groups)
        out[bool(kw)] = drag_and_miss(V, parts, groups, T, d.solve(transforms=T, iterations=30), size)
    assert out[False][0] > 4.0, out  # the case is a hard one for the engine's own lattice
    drag, miss = out[True]
    assert drag <= 1.0 and miss <= 3.0, out


@pytest.mark.parametrize("turn,cells", [(15.0, 5000), (30.0, 6000), (45.0, 7500)])
def test_bspline_pose_reads_each_branch_from_its_side(turn, cells):
    """The final (B-spline) pose: a vertex near a ball joint reads, at a point where its part has
    two nodes (one on the palm's side, its own beyond), one of them (junction_stencils.cpp, rule
    1), not the node's own item, which mixed every finger's node there: the other fingers within
    1% (measured 0.14-0.42%; 1.10-1.68% with the mixed item; the trilinear pose 0.14-0.25%)."""
    V, F, parts, groups, T, size = turned_character(turn)
    d = larap.Deformer(V, F, cells=cells, weights="bspline", **BRANCH)
    d.set_handle_groups(groups)
    drag, _ = drag_and_miss(V, parts, groups, T, d.solve(transforms=T, iterations=30), size)
    assert drag <= 1.0, drag


def test_the_split_is_a_ball_joint_with_couplings():
    """Where the fingers leave the palm some copies are split: each copy split off is coupled to the
    copy it came from at 10 times that copy's weight, shares at least one node with it (the ball
    joint) and not all eight, and holds the vertices of one part only."""
    V, F, parts, groups, T, size = turned_character(30.0)
    d0 = larap.Deformer(V, F, cells=4000)
    d = larap.Deformer(V, F, cells=4000, **BRANCH)
    pairs, w = d._core.branch_couplings()
    assert len(pairs) > 0 and len(d0._core.branch_couplings()[0]) == 0
    assert len(d.cell_nodes()) == len(d0.cell_nodes()) + len(pairs)
    cells, weight = d.cell_nodes(), d.cell_weights()
    np.testing.assert_allclose(w, 10.0 * weight[pairs[:, 1]])
    part = mesh_parts(len(V), F)
    fingers = {int(part[f[0]]) for f in parts["fingers"]}
    vcell, _ = d.trilinear_binding()
    held = set()
    for b, t in pairs:
        shared = len(set(cells[b]) & set(cells[t]))
        assert 1 <= shared < 8, (b, t, shared)
        assert len(np.unique(part[vcell == b])) <= 1, np.unique(part[vcell == b])
        held |= set(part[vcell == b].tolist())
    assert len(held & fingers) >= 3, (held, fingers)  # the fingers of the posed hand at least


def mesh_parts(n, F):
    """Each vertex's part: the connected components of the faces (a union-find)."""
    root = np.arange(n)

    def find(x):
        while root[x] != x:
            root[x] = root[root[x]]
            x = root[x]
        return x
    for f in F:
        for a, b in zip(f, f[1:]):
            ra, rb = find(a), find(b)
            if ra != rb:
                root[max(ra, rb)] = min(ra, rb)
    return np.array([find(v) for v in range(n)])


def extruded(poly, tris2d, z0, z1):
    """A prism: the polygon `poly` (its triangles `tris2d`) from z0 to z1."""
    n = len(poly)
    V = [(x, y, z0) for x, y in poly] + [(x, y, z1) for x, y in poly]
    F = [(a, c, b) for a, b, c in tris2d] + [(n + a, n + b, n + c) for a, b, c in tris2d]
    for i in range(n):
        j = (i + 1) % n
        F += [(i, j, n + j), (i, n + j, n + i)]
    return np.array(V, float), F


def test_a_junction_whose_trunk_fills_two_copies_of_a_cell_is_split():
    """A coarse U-shaped trunk whose slot (0.04 wide) runs through cells of 0.25, so that the trunk
    fills two copies of them, and a box pushed into one prong with no vertex beside the trunk's: the
    junction is still found and split (a narrower choice of the cells to look at, by the copies'
    vertices, missed it: found by a review, session 31)."""
    trunk = extruded([(0, 0), (2, 0), (2, 0.45), (0.2, 0.45), (0.2, 0.49), (2, 0.49), (2, 1), (0, 1)],
                     [(0, 1, 2), (0, 2, 3), (0, 3, 4), (0, 4, 7), (4, 5, 6), (4, 6, 7)], 0.0, 0.88)
    branch = extruded([(0.8, 0.27), (1.2, 0.27), (1.2, 0.44), (0.8, 0.44)], [(0, 1, 2), (0, 2, 3)], 0.55, 1.9)
    V, F = shapes.concat(trunk, branch)
    d = larap.Deformer(V, F, cell_size=0.25, **BRANCH)
    assert len(d._core.branch_couplings()[0]) > 0


def test_one_part_gets_the_lattice_it_had():
    V, F = shapes.torus()
    groups = [np.flatnonzero(V[:, 0] < -0.9), np.flatnonzero(V[:, 0] > 0.9)]
    T = np.stack([np.eye(4), affine(rotation([0, 1, 0], 40), pivot=(1.0, 0.0, 0.0))])
    X = {}
    for kw in ({}, BRANCH):
        d = larap.Deformer(V, F, weights="bspline", **kw)
        d.set_handle_groups(groups)
        X[bool(kw)] = d.solve(transforms=T, iterations=10)
    assert np.array_equal(X[False], X[True])


@pytest.mark.parametrize("weights", ["trilinear", "bspline"])
def test_branch_copies_keep_rest_rigid_and_lower_the_energy(weights):
    V, F, parts, groups, T, size = turned_character(30.0)
    d = larap.Deformer(V, F, cells=4000, weights=weights, **BRANCH)
    d.set_handle_groups(groups)
    assert len(d._core.branch_couplings()[0]) > 0
    assert_rest_and_rigid(d, V, parts)
    d.reset()
    d.solve(transforms=T, iterations=30)
    e = np.array(d.stats["energy"])
    assert e[-1] < e[0] and np.all(np.diff(e) <= 1e-9 * e[0]), np.diff(e).max() / e[0]


@pytest.mark.parametrize("turn,cells", [(30.0, 4000), (45.0, 8000)])
def test_free_fingers_follow_their_palm(turn, cells):
    """The palm turned 90 degrees about the wrist, no handle on any finger, the body held: each
    finger hangs from the palm by one node and its rotation's coupling, and still turns with it
    (200 flip-flops: within 1% of the hand of the palm's rigid turn; measured 0.47 and 0.49%, the
    engine's own lattice 3.78 and 0.20%). levels=2 carries it there in a drag as well: 12 steps of
    5 flip-flops keep the fingers within 3.5% (measured 2.27 and 3.27%; the engine's own lattice at
    levels 2: 3.50 and 2.99%; at levels 1 the split lags 7-28%)."""
    V, F, parts = shapes.character()
    groups, _ = finger_pose(V, parts)
    fingers = np.concatenate(parts["fingers"])
    groups = [np.setdiff1d(g, fingers) for g in groups[:2]]
    wrist = V[parts["hand"], 0].min() + 0.02
    size = hand_size(V, parts)
    R = affine(rotation([0, 1, 0], -90.0), pivot=(wrist, 0.0, 1.42))
    T = np.stack([np.eye(4), R])
    Vt, Tt = turned_about_vertical(V, T, turn)
    d = larap.Deformer(Vt, F, cells=cells, levels=2, **BRANCH)
    d.set_handle_groups(groups)
    X = d.solve(transforms=Tt, iterations=200)
    off = np.linalg.norm(X[fingers] - (Vt[fingers] @ Tt[1][:3, :3].T + Tt[1][:3, 3]), axis=1).max() / size
    assert off <= 0.01, off
    d.reset()
    worst = 0.0
    for k in range(1, 13):
        Rk = affine(rotation([0, 1, 0], -90.0 * k / 12), pivot=(wrist, 0.0, 1.42))
        _, Tk = turned_about_vertical(V, np.stack([np.eye(4), Rk]), turn)
        X = d.solve(transforms=Tk, iterations=5)
        worst = max(worst, np.linalg.norm(X[fingers] - (Vt[fingers] @ Tk[1][:3, :3].T + Tk[1][:3, 3]), axis=1).max())
    assert worst <= 0.035 * size, worst / size


@need_cuda()
@pytest.mark.parametrize("weights", ["trilinear", "bspline"])
def test_cpu_and_cuda_agree_on_branch_copies(weights):
    V, F, parts, groups, T, size = turned_character(30.0)
    out = {}
    for dev in ("cpu", "cuda"):
        d = larap.Deformer(V, F, cells=4000, weights=weights, device=dev, **BRANCH)
        d.set_handle_groups(groups)
        out[dev] = d.solve(transforms=T, iterations=300)
    assert np.abs(out["cpu"] - out["cuda"]).max() <= 1e-4 * size
