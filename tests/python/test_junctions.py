# Run: PYTHONPATH=python /usr/bin/python3 -m pytest tests/python/test_junctions.py
"""B-spline stencils at junctions, where pieces meet (issue 9; native/src/junction_stencils.h): on a
generated character whose fingers are separate parts pushed into the palm, half a cell thick and a
tenth of a cell apart on the default lattice, a finger turned 60 degrees leaves its neighbours
within 1% of the hand with either weight kind at every lattice size from 4,000 to 9,000 cells
(with the junction braces, native/src/junction_braces.h; not yet with the palm part alone held, nor
with the hand at an angle to the lattice: strict xfails for the default lattice; one copy per branch,
off by default, meets both), and the final (B-spline) pose has no step where the fingers leave the
palm; rest, rigid and affine poses are still reproduced, on both devices."""
import math

import numpy as np
import pytest
from conftest import affine, cpu_and_cuda, need_cuda, rotation

import larap
from larap import shapes

DEVICES = cpu_and_cuda()
CUDA = need_cuda()


def finger_pose(V, parts, moved=1, degrees=60.0):
    """Groups as an artist pins a hand: the body, the palm (everything up to the fingers' roots)
    and each fingertip; the tip of finger `moved` turned `degrees` about the axis across the hand
    through its root, out of the hand's plane."""
    held = np.flatnonzero(V[:, 0] <= parts["root_x"] - 0.005)
    palm = np.intersect1d(held, parts["hand"])
    body = np.setdiff1d(held, palm)
    tips = [f[V[f, 0] >= 0.86] for f in parts["fingers"]]
    groups = [body, palm] + tips
    T = np.stack([np.eye(4)] * len(groups))
    T[2 + moved] = affine(rotation([0, 1, 0], -degrees), pivot=(parts["root_x"], 0.0, 1.42))
    return groups, T


def turned_about_vertical(V, T, degrees):
    """The model and its pose (one affine map per group) turned `degrees` about the vertical (z).
    Elementwise products and sums and the C library's sine and cosine, no BLAS (whose kernels
    differ between CPUs in the last bit), so that machines with the same libm turn the model to
    the same bits: the turned sweeps' lattices depend on them (a last-bit difference moved a
    4,000-cell lattice's cell size by 0.5% between this machine and the GPU machine, and the
    figures with it)."""
    c, s = math.cos(math.radians(degrees)), math.sin(math.radians(degrees))
    turned = np.column_stack([c * V[:, 0] - s * V[:, 1], s * V[:, 0] + c * V[:, 1], V[:, 2]])
    R = [[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]
    maps = []
    for t in np.asarray(T, float):  # R t R^T on the linear part, R applied to the translation
        A = [[sum(R[i][a] * t[a][b] * R[j][b] for a in range(3) for b in range(3)) for j in range(3)]
             for i in range(3)]
        u = [sum(R[i][a] * t[a][3] for a in range(3)) for i in range(3)]
        maps.append([A[0] + [u[0]], A[1] + [u[1]], A[2] + [u[2]], [0.0, 0.0, 0.0, 1.0]])
    return turned, np.array(maps)


def hand_size(V, parts):
    H = V[parts["hand"]]
    return float(np.linalg.norm(H.max(0) - H.min(0)))


@pytest.mark.parametrize("weights", ["trilinear", "bspline"])
def test_character_finger_turned_leaves_its_neighbours(weights):
    """Default lattice (fingers about 0.5 cell thick, 0.11 cell apart): the other fingers move at
    most 1% of the hand's diagonal, the turned tip reaches its target within 3% of the finger.
    (Before junction stencils the B-spline pose moved them 1.61%.)"""
    V, F, parts = shapes.character()
    d = larap.Deformer(V, F, weights=weights)
    assert 0.3 < 0.018 / d.cell_size < 0.8  # the fingers are thinner than a cell
    groups, T = finger_pose(V, parts)
    d.set_handle_groups(groups)
    X = d.solve(transforms=T, iterations=30)
    size = hand_size(V, parts)
    for k in (0, 2, 3):
        f = parts["fingers"][k]
        drag = np.linalg.norm(X[f] - V[f], axis=1).max()
        assert drag <= 0.01 * size, (k, drag / size)
    tip = groups[3]
    miss = np.linalg.norm(X[tip] - (V[tip] @ T[3][:3, :3].T + T[3][:3, 3]), axis=1).max()
    assert miss <= 0.03 * 0.09, miss / 0.09


# Lattice sizes around the default (6000 cells): the palm's end and the fingers' roots fall at
# every position in their cells.
CHARACTER_CELLS = (4000, 4500, 5000, 5500, 6000, 6500, 7000, 7500, 8000, 9000)


def character_sweep(palm_part_only=False, turned=0.0, branch_copies=False):
    """Per lattice size, the other fingers' largest move (% of the hand's diagonal) with the worse
    of the two weight kinds, for finger_pose after 30 flip-flops; palm_part_only: the palm's group
    (and the body's) without the fingers' roots inside the palm, as an artist who pins the palm
    object has it (a finger is then held to the palm by the lattice alone); turned: the whole
    character turned that many degrees about the vertical axis, so that the hand lies at an angle
    to the lattice's axes (the pose turned with it); branch_copies: one copy per branch where the
    parts meet (research stage, off by default; test_branch_copies.py)."""
    key = (("drag_palm_part" if palm_part_only else "drag") + (f"_turned_{turned:g}" if turned else "") +
           ("_branch" if branch_copies else ""))
    if not hasattr(character_sweep, key):
        V, F, parts = shapes.character()
        groups, T = finger_pose(V, parts)
        if palm_part_only:
            fingers = np.concatenate(parts["fingers"])
            groups = [np.setdiff1d(g, fingers) for g in groups[:2]] + groups[2:]
        size = hand_size(V, parts)  # the unturned hand's: the same yardstick at every angle
        if turned:
            V, T = turned_about_vertical(V, T, turned)
        drag = []
        for cells in CHARACTER_CELLS:
            worst = 0.0
            for weights in ("trilinear", "bspline"):
                d = larap.Deformer(V, F, weights=weights, cells=cells, _branch_copies=branch_copies)
                d.set_handle_groups(groups)
                X = d.solve(transforms=T, iterations=30)
                others = [parts["fingers"][k] for k in (0, 2, 3)]
                worst = max([worst] + [np.linalg.norm(X[f] - V[f], axis=1).max() for f in others])
            drag.append(100 * worst / size)
        setattr(character_sweep, key, np.array(drag))
    return getattr(character_sweep, key)


def assert_within(drag, median, worst, within_1pct, within=1.0):
    """A sweep's guard: its median and worst drag at most `median` and `worst` (% of the hand), at
    least `within_1pct` sizes at most `within`."""
    assert np.median(drag) <= median, drag
    assert drag.max() <= worst, drag
    assert (drag <= within).sum() >= within_1pct, drag


def test_character_at_every_lattice_size_meets_the_target():
    """The target, at every size: the other fingers within 1% of the hand (2026-11-24, junction
    braces: median 0.54%, worst 0.84%; one rotation per cell before them: 7 of 10 sizes within 1%,
    worst 2.0%; node rotations: 4 of 10, worst 3.1%)."""
    assert character_sweep().max() <= 1.0, character_sweep()
    assert np.median(character_sweep()) <= 0.6, character_sweep()


def test_character_without_braces_drags_its_neighbours_more():
    """junction_brace=0 gives back the lattice without braces, and its drag (2026-11-24: worst 2.0%
    at 3 sizes over 1%): the braces are what meets the target above."""
    V, F, parts = shapes.character()
    groups, T = finger_pose(V, parts)
    size = hand_size(V, parts)
    drag = {}
    for brace in (0.0, larap.DEFAULT_JUNCTION_BRACE):
        d = larap.Deformer(V, F, weights="trilinear", cells=8000, junction_brace=brace)
        d.set_handle_groups(groups)
        X = d.solve(transforms=T, iterations=30)
        drag[brace] = max(np.linalg.norm(X[parts["fingers"][k]] - V[parts["fingers"][k]], axis=1).max()
                          for k in (0, 2, 3)) / size
    assert drag[0.0] > 1.5 * drag[larap.DEFAULT_JUNCTION_BRACE], drag
    assert drag[0.0] > 0.01, drag


def test_character_with_the_palm_part_held_stays_within_the_measured_bounds():
    """The same with the palm's group holding the palm part alone (2026-11-24, junction braces: 7 of
    10 sizes within 1%, median 0.71%, worst 1.95%; before them 5 of 10, median 0.99%, worst 2.4%;
    node rotations: 1 of 10, median 2.0%, worst 4.1%): worse than with the roots held, a guard, not
    the target."""
    drag = character_sweep(palm_part_only=True)
    assert not np.allclose(drag, character_sweep()), drag  # the pose differs from the other sweep's
    assert_within(drag, median=0.8, worst=2.1, within_1pct=7)


@pytest.mark.xfail(strict=True, raises=AssertionError, reason="not met yet by the default lattice (2026-11-24): "
                   "with the palm part alone held (the fingers held to the palm by the lattice alone), "
                   "at 3 of 10 lattice sizes from 4000 to 9000 cells the other fingers move "
                   "1.15-1.95% of the hand, with the junction braces (docs/method.md, 'Junction "
                   "braces'); one copy per branch meets it (below), off by default")
def test_character_with_the_palm_part_held_meets_the_target():
    assert character_sweep(palm_part_only=True).max() <= 1.0, character_sweep(palm_part_only=True)


def test_character_with_the_palm_part_held_meets_the_target_with_branch_copies():
    """One copy per branch (research stage, `_branch_copies=True`; 2026-11-25: median 0.46%, worst
    0.72%, 10 of 10 within 1%): a finger's copies beyond the palm are its own, held to the palm by a
    ball joint and its rotation's coupling, so a turned finger no longer lifts its neighbours'."""
    drag = character_sweep(palm_part_only=True, branch_copies=True)
    assert drag.max() <= 1.0, drag
    assert np.median(drag) <= 0.5, drag


TURNED = (15.0, 30.0, 45.0)


def turned_sweeps():
    return np.concatenate([character_sweep(turned=a) for a in TURNED])


def test_character_at_an_angle_to_the_grid_stays_within_the_measured_bounds():
    """The character turned 15, 30 and 45 degrees about the vertical, so that its hands lie at an
    angle to the lattice (as most characters' hands do), at the same 10 cell counts (the turned
    model's box is larger, so its cells are 4-7% larger): what the engine does today (2026-11-24,
    junction braces: 9 of 30 within 1%, median 1.7%, worst 9.5%; one rotation per cell before
    them: 3 of 30 within 1%, median 2.7%, worst 9.6%; 2026-11-23, node rotations,
    with separate parts told apart in a cell's voxels: 1 of 30 within 1%, median 3.2%, worst 9.8%;
    before, fingers a tenth of a cell apart at an angle could fall into one piece of a cell: worst
    21.6%, 5 sizes over 12%). What is left is the junction's cells reaching farther along the
    fingers. A guard against getting worse, not the target."""
    for a in TURNED:  # the turn is real: the sweeps differ from the unturned one
        assert not np.allclose(character_sweep(turned=a), character_sweep()), a
    assert_within(turned_sweeps(), median=1.9, worst=10.0, within_1pct=9)


@pytest.mark.xfail(strict=True, raises=AssertionError, reason="not met (2026-11-24): with the hand at an "
                   "angle to the lattice the other fingers move up to 9.5% of the hand (21 of 30 "
                   "sizes and angles over 1%, with the junction braces): the cells where the fingers leave the palm reach "
                   "farther along them; docs/method.md, 'What splitting cannot separate'. One copy "
                   "per branch meets it (below), off by default")
def test_character_at_an_angle_to_the_grid_meets_the_target():
    assert turned_sweeps().max() <= 1.0, turned_sweeps()


def test_character_at_an_angle_to_the_grid_meets_the_target_with_branch_copies():
    """One copy per branch (research stage; 2026-11-25: median 0.23%, worst 0.79%, 30 of 30 within
    1%, against the default lattice's 9 of 30, worst 9.5%; with the sides' ratio at 2, 29 of 30, worst
    2.89% at 15 degrees and 7,000 cells, where three fingers shared a node on the palm's side)."""
    drag = np.concatenate([character_sweep(turned=a, branch_copies=True) for a in TURNED])
    assert drag.max() <= 1.0, drag
    assert np.median(drag) <= 0.3, drag


def test_bspline_pose_has_no_step_where_the_fingers_leave_the_palm():
    """Finely ringed fingers (a ring every 0.45 mm): every triangle edge of the turned finger and of
    its neighbours keeps its length within a factor of 1.6. A stencil that reads the average of the
    fingers at the junction put a step half a cell above it: edges there stretched 10-22 times."""
    V, F, parts = shapes.character(finger_rings=200)
    d = larap.Deformer(V, F, weights="bspline")
    groups, T = finger_pose(V, parts)
    d.set_handle_groups(groups)
    X = d.solve(transforms=T, iterations=30)
    for k in (0, 1, 2):
        f = set(parts["fingers"][k].tolist())
        tris = np.array([[p[0], p[j], p[j + 1]] for p in F if p[0] in f for j in range(1, len(p) - 1)])
        for a, b in ((0, 1), (1, 2), (0, 2)):
            e0 = np.linalg.norm(V[tris[:, a]] - V[tris[:, b]], axis=1)
            e1 = np.linalg.norm(X[tris[:, a]] - X[tris[:, b]], axis=1)
            assert np.max(e1 / e0) < 1.6, (k, np.max(e1 / e0))


def assert_rest_and_rigid(d, V, parts):
    """On the character's Deformer `d` with finger_pose's groups set: targets at rest give the rest
    pose, one rigid motion of every handle gives that motion. Returns the tolerance used (per unit
    of the hand's size)."""
    groups, _ = finger_pose(V, parts)
    tol = 1e-4 if d.device == "cuda" else 1e-7  # the device solves in float
    size = hand_size(V, parts)
    X = d.solve(transforms=np.stack([np.eye(4)] * len(groups)), iterations=5)
    assert np.abs(X - V).max() <= tol * size
    M = affine(rotation([1, 2, 3], 50), pivot=(0.8, 0.0, 1.4))
    X = d.solve(transforms=np.stack([M] * len(groups)), iterations=5)
    assert np.abs(X - (V @ M[:3, :3].T + M[:3, 3])).max() <= tol * size
    return tol


@pytest.mark.parametrize("device", DEVICES)
def test_junction_stencils_keep_rest_and_rigid(device):
    """On the character, whose finger roots read junction rows: targets at rest give the rest pose,
    one rigid motion of every handle gives that motion."""
    V, F, parts = shapes.character()
    d = larap.Deformer(V, F, weights="bspline", device=device)
    d.set_handle_groups(finger_pose(V, parts)[0])
    assert_rest_and_rigid(d, V, parts)


@CUDA
def test_junction_stencils_agree_on_both_devices():
    V, F, parts = shapes.character()
    groups, T = finger_pose(V, parts)
    out = {}
    for dev in ("cpu", "cuda"):
        d = larap.Deformer(V, F, weights="bspline", device=dev)
        d.set_handle_groups(groups)
        out[dev] = d.solve(transforms=T, iterations=200)
    err = np.linalg.norm(out["cpu"] - out["cuda"], axis=1).max()
    assert err < 1e-4 * hand_size(V, parts), err / hand_size(V, parts)
