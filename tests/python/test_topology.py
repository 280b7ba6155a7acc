# Run: PYTHONPATH=python /usr/bin/python3 -m pytest tests/python/test_topology.py
"""Cell splitting, the stencil shell and the topology-preserving hierarchy (issue 9): parts closer
than a cell do not move together, pinned parts stay put at every level count, and the real
lattice's pose does not depend on the weight kind. Poses are made with handle groups, as artists
make them."""
import os

import numpy as np
import pytest
from conftest import affine, apply, cpu_and_cuda, rotation

import larap
from larap import shapes
from larap.quality import diagonal

H = 1.0  # cell size of the generated models


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


@pytest.mark.parametrize("weights", ["trilinear", "bspline"])
@pytest.mark.parametrize("levels", [1, 2, 3, 4])
def test_comb_tine_turned_leaves_its_neighbours(weights, levels):
    """At the tests' cell size: each tine one cell thick, its faces on cell planes, the middle
    tine crossing two columns of cells (a sliver of it shares cells with its neighbour)."""
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


# The comb scaled to the cell: tines 1 to 4 cells thick, always 0.1 cell apart, so that the
# tines' faces fall at every position in their cells.
SWEEP_SIZES = tuple(np.round(np.linspace(0.25, 1.05, 17), 3))


def comb_sweep():
    """Per cell size h, (drag % of the diagonal, tip miss % of the tine) with the worse of the two
    weight kinds, for the pose above on comb(gap=0.1 h), cell_size=h."""
    if not hasattr(comb_sweep, "rows"):
        rows = []
        for h in SWEEP_SIZES:
            V, F, tine_ids, _ = comb(gap=0.1 * h)
            groups, T = comb_pose(V, tine_ids, moved=1)
            drag = miss = 0.0
            for weights in ("trilinear", "bspline"):
                d = larap.Deformer(V, F, cell_size=h, weights=weights)
                d.set_handle_groups(groups)
                X = d.solve(transforms=T, iterations=30)
                drag = max([drag] + [np.linalg.norm(X[tine_ids[t]] - V[tine_ids[t]], axis=1).max()
                                     / diagonal(V) for t in (0, 2)])
                miss = max(miss, np.linalg.norm(X[groups[2]] - apply(T[2], V[groups[2]]), axis=1).max() / 6.0)
            rows.append((100 * drag, 100 * miss))
        comb_sweep.rows = np.array(rows)
    return comb_sweep.rows


def test_comb_at_every_alignment_mostly_meets_the_target():
    """What cell weights by material bought (2026-11-22: median 2.35 -> 1.10 %, worst 4.25 ->
    2.69 %, 0 -> 7 of 17 sizes within 1 %), the stiffer default handles after them (gamma 0.1
    -> 0.03: median 0.95 %, worst 2.37 %, 11 of 17), B-spline stencils read from each part's
    side of a junction (median 0.65 %, 13 of 17) and one rotation per cell instead of per node
    (2026-11-24: median 0.49 %, worst 1.57 %, 15 of 17) and the junction braces (2026-11-24:
    median 0.40 %, worst 1.38 %, 15 of 17): the tip always reaches its target, and the drag stays
    within these bounds."""
    rows = comb_sweep()
    assert rows[:, 1].max() <= 3.0, rows[:, 1]
    assert np.median(rows[:, 0]) <= 0.45, rows[:, 0]
    assert rows[:, 0].max() <= 1.45, rows[:, 0]
    assert (rows[:, 0] <= 1.0).sum() >= 15, rows[:, 0]


@pytest.mark.xfail(strict=True, raises=AssertionError, reason="not met yet (2026-11-24): at 2 of 17 cell sizes the "
                   "neighbours move 1.07-1.38% of the diagonal with the junction braces (trilinear: "
                   "1 size, 1.23%). At h = 0.7 the gap between two tines holds a grid plane, so no "
                   "cell branches there, and the neighbour's root face still rises with the turned "
                   "tine (docs/method.md, 'Junction braces'). Per-part lattices glued where the parts "
                   "overlap met it on this comb in a reference solver (trilinear) but not on the "
                   "character (scripts/experiments/glued_parts.py); not built")
def test_comb_at_every_alignment_meets_the_target():
    rows = comb_sweep()
    assert rows[:, 0].max() <= 1.0, rows[:, 0]


def test_split_copies_weigh_their_material():
    """Two plates 0.3 cell thick, 0.25 apart, both inside one layer of cells: every cell they
    cross is split in two, and each copy weighs about its plate's share of the cell (the engine
    counts surface voxels as material: up to two voxel layers more); cells kept whole weigh 1;
    an edge weighs half the sum over the copies it is an edge of (the energy sums each copy's 12
    edges); on the plain lattice every cell weighs 1, so an edge weighs half its cell count."""
    k = 24
    plates = [((0.05, 0.05, 0.1), (3.95, 0.95, 0.4)), ((0.05, 0.05, 0.65), (3.95, 0.95, 0.95))]
    V, F = shapes.concat(*[shapes.box(lo, hi, 4) for lo, hi in plates])
    d = larap.Deformer(V, F, cell_size=H, split_resolution=k)
    w, coords, cells = d.cell_weights(), d._core.cell_coords(), d.cell_nodes()
    _, where, count = np.unique(coords, axis=0, return_inverse=True, return_counts=True)
    copies = count[where.ravel()]  # copies of each cell's grid cell
    assert (copies == 2).sum() >= 8 and np.all(w[copies == 1] == 1.0)
    assert np.all(w >= 1.0 / k - 1e-15) and np.all(w <= 1.0)  # at least one layer of voxels
    origin, h = np.array(d._core.origin), d.cell_size
    cell_of, _ = d.trilinear_binding()
    for c in np.flatnonzero(copies == 2):
        lo = origin + h * coords[c]
        hi = lo + h
        plate = {0 if V[v, 2] < 0.5 else 1 for v in np.flatnonzero(cell_of == c)}
        assert len(plate) <= 1
        if not plate:
            continue
        plo, phi = map(np.asarray, plates[plate.pop()])
        share = np.prod(np.clip(np.minimum(hi, phi) - np.maximum(lo, plo), 0, None)) / h ** 3
        assert share - 0.5 / k <= w[c] <= share + 2.5 / k * (1 + 4 * share), (c, w[c], share)
    # edges: half the sum over the copies they belong to
    acc = {}
    for c, cn in enumerate(cells):
        for a in range(8):
            for axis in range(3):
                if not (a >> axis) & 1:
                    key = tuple(sorted((cn[a], cn[a | 1 << axis])))
                    acc.setdefault(key, []).append(w[c])
    E, ew = d.lattice_edges(), d.lattice_edge_weights()
    expect = np.array([0.5 * np.sum(acc[tuple(sorted(e))]) for e in E])
    assert np.allclose(ew, expect, rtol=1e-12, atol=0)
    plain = larap.Deformer(V, F, cell_size=H, split_cells=False)
    assert np.all(plain.cell_weights() == 1.0)
    counts = {}
    for cn in plain.cell_nodes():
        for a in range(8):
            for axis in range(3):
                if not (a >> axis) & 1:
                    key = tuple(sorted((cn[a], cn[a | 1 << axis])))
                    counts[key] = counts.get(key, 0) + 1
    pw = plain.lattice_edge_weights()
    assert np.array_equal(pw, [0.5 * counts[tuple(sorted(e))] for e in plain.lattice_edges()])
    assert pw.max() == 2.0 and pw.min() == 0.5  # inside (4 cells) and along the lattice's edges (1)


@pytest.mark.parametrize("device", cpu_and_cuda())
def test_weighted_lattice_keeps_rest_rigid_and_descent(device):
    """On the comb's weighted lattice: targets at rest give the rest pose, one rigid motion of
    every handle gives that motion, and the energy never increases."""
    V, F, tine_ids, _ = comb()
    d = larap.Deformer(V, F, cell_size=H, device=device)
    assert np.any(d.cell_weights() < 0.5)
    groups, T = comb_pose(V, tine_ids, moved=1)
    d.set_handle_groups(groups)
    X = d.solve(transforms=np.stack([np.eye(4)] * len(groups)), iterations=5)
    tol = 1e-4 if d.device == "cuda" else 1e-7  # the device solves in float
    assert np.abs(X - V).max() <= tol * diagonal(V)
    M = affine(rotation([1, 2, 3], 50), pivot=(1.0, 1.0, 0.5))
    X = d.solve(transforms=np.stack([M] * len(groups)), iterations=5)
    assert np.abs(X - apply(M, V)).max() <= tol * diagonal(V)
    d.reset()
    d.solve(transforms=T, iterations=30)
    E = np.array(d.stats["energy"])
    assert np.all(np.diff(E) <= tol * E[0]), E


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


def plate_with_hole(hole):
    """A closed plate 9.4 x 9.4 x 0.4 at cell size 1 (its cells hold its top and bottom, so they are
    analysed); `hole`: one quad of the top (0.47 x 0.47, about half a cell) left out."""
    V, F = shapes.box((0.3, 0.3, 0.3), (9.7, 9.7, 0.7), 20)
    V = np.asarray(V)
    if hole:
        F = [f for f in F if not (np.allclose(V[f][:, 2], 0.7) and np.abs(V[f][:, :2].mean(0) - 4.765).max() < 0.1)]
    return V, F


def split_cell_count(d):
    _, copies = np.unique(np.asarray(d._core.cell_coords()), axis=0, return_counts=True)
    return int((copies > 1).sum())


def test_a_closed_plate_is_one_copy_per_cell():
    V, F = plate_with_hole(False)
    assert split_cell_count(larap.Deformer(V, F, cell_size=1.0)) == 0


def test_a_plate_with_a_small_hole_is_one_copy_per_cell():
    """A hole half a cell wide does not make the plate two sheets: the cell-level inside test
    (parity votes) keeps it solid, and the pieces of its cells agree (the voxels' inside test
    holds the plate's inside out of the air's flood; before it, 64 cells split into top and bottom
    sheets)."""
    V, F = plate_with_hole(True)
    assert split_cell_count(larap.Deformer(V, F, cell_size=1.0)) == 0


def test_a_box_grazing_another_within_the_cell_tolerance_stays_one_component():
    """Two boxes a tenth of a nanometre apart at cell size 1: the cells above the contact count the
    lower box's top as theirs (the cells' tolerance) but none of their voxels (the voxels'): such
    a cell has no surface voxel, and its held inside stays material (turned to air, each was a
    lattice component of its own: 17 instead of 1)."""
    A = shapes.box((0.0, 0.0, 0.0), (6.0, 6.0, 2.0 + 3e-10), 6)
    B = shapes.box((0.0, 0.0, 2.0 + 4e-10), (6.0, 6.0, 3.0), 6)
    V, F = shapes.concat(A, B)
    assert larap.Deformer(V, F, cell_size=1.0).num_components == 1


@pytest.mark.parametrize("name", ["stanford-bunny.obj", "suzanne.obj", "teapot.obj"])
def test_a_mesh_with_holes_stays_one_lattice_component(shared_meshes, name):
    """One-part meshes with holes in their surface (the bunny's open bottom, Suzanne's eyes, the
    teapot's lid): air let in where two holes see a voxel cuts held cores off from the skin, and
    such a core, kept, is a lattice component with no vertex (the bunny had 10)."""
    path = os.path.join(shared_meshes, name)
    if not os.path.exists(path):
        pytest.skip(f"{name} not present")
    V, F = larap.load_mesh(path)
    assert larap.Deformer(V, F).num_components == 1


def test_a_bar_in_an_open_sleeve_stays_apart():
    """The gap between a bar and an open sleeve around it (0.2 cells) is crossed by the sleeve along
    the four radial rays only: not inside, so the air reaches it from the sleeve's ends and the
    two are separate lattice components that share no cell copy; the bar turns inside the pinned
    sleeve without dragging it."""
    bar = shapes.tube(length=6.0, radius=0.3, segments=24, rings=12)
    sleeve = shapes.tube(length=4.0, radius=0.5, segments=24, rings=8, caps=False)
    sleeve = (np.asarray(sleeve[0]) + [1.0, 0, 0], sleeve[1])
    V, F = shapes.concat(bar, sleeve)
    n = len(bar[0])
    d = larap.Deformer(V, F, cell_size=1.0)
    assert d.num_components == 2
    assert split_cell_count(d) > 0
    ids = np.arange(len(V))
    bar_ids, sleeve_ids = ids[:n], ids[n:]
    far = bar_ids[V[bar_ids, 0] >= 5.5]
    near = bar_ids[V[bar_ids, 0] <= 0.5]
    d.set_handle_groups([near, far, sleeve_ids])
    T = np.stack([np.eye(4), affine(rotation([1, 0, 0], 60), pivot=(3.0, 0, 0)), np.eye(4)])
    X = d.solve(transforms=T, iterations=5)
    assert np.linalg.norm(X[sleeve_ids] - V[sleeve_ids], axis=1).max() < 1e-3 * 6.0


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


def arm_in_sleeve(gap):
    """An arm (closed tube along x, radius 1.5, 12 long) and an open sleeve around its middle
    third, `gap` cells off its surface; the arm's two ends are the handle groups (18% of the
    vertices), the sleeve has none. Returns V, F, arm ids, sleeve ids, groups, the elbow bend."""
    arm = shapes.tube(length=12.0, radius=1.5, segments=32, rings=48)
    sleeve = shapes.tube(length=4.0, radius=1.5 + gap * H, segments=32, rings=16, caps=False)
    sleeve = (np.asarray(sleeve[0]) + [4.0, 0.0, 0.0], sleeve[1])
    V, F = shapes.concat(arm, sleeve)
    n = len(arm[0])
    ids = np.arange(n)
    groups = [ids[V[ids, 0] < 1.5], ids[V[ids, 0] > 10.5]]
    T = np.stack([np.eye(4), affine(rotation([0, 0, 1], 60), pivot=(6.0, 0.0, 0.0))])
    return V, F, ids, np.arange(n, len(V)), groups, T


@pytest.mark.parametrize("gap", [0.1, 0.3, 0.8])
@pytest.mark.parametrize("weights,levels", [("trilinear", 1), ("bspline", 1), ("trilinear", 3)])
@pytest.mark.parametrize("device", cpu_and_cuda())
def test_a_part_without_handles_follows_the_part_it_sits_on(gap, weights, levels, device):
    """A sleeve a tenth of a cell to most of a cell off an arm has cells of its own and no handle:
    it follows the arm's bend (carried_parts.h) instead of staying where it was. Each sleeve
    vertex lies straight out from an arm vertex at rest; posed, their distance stays within a
    quarter of the gap (measured: within 16%; a sleeve left behind is units away)."""
    V, F, arm, sleeve, groups, T = arm_in_sleeve(gap)
    d = larap.Deformer(V, F, cell_size=H, weights=weights, levels=levels, device=device)
    assert d.num_components == 2  # the sleeve has cells of its own
    d.set_handle_groups(groups)
    X = d.solve(transforms=T, iterations=30)
    rest = np.linalg.norm(V[sleeve][:, None, :] - V[arm][None, :, :], axis=2)
    under = arm[rest.argmin(axis=1)]  # the arm vertex straight under each sleeve vertex
    assert np.allclose(rest.min(axis=1), gap * H)
    posed = np.linalg.norm(X[sleeve] - X[under], axis=1)
    assert np.abs(posed - gap * H).max() <= 0.25 * gap * H, (posed.min(), posed.max())
    assert np.linalg.norm(X[sleeve] - V[sleeve], axis=1).mean() > 0.1 * 12.0  # it did move


def test_a_part_far_from_every_handled_part_stays_at_rest():
    """A part more than a cell from everything that moves has nothing to follow: held at rest."""
    V, F, arm, sleeve, groups, T = arm_in_sleeve(0.3)
    far = shapes.box((30.0, 0.0, 0.0), (32.0, 2.0, 2.0), 4)
    V, F = shapes.concat((V, F), far)
    d = larap.Deformer(V, F, cell_size=H)
    assert d.num_components == 3
    d.set_handle_groups(groups)
    X = d.solve(transforms=T, iterations=10)
    far_ids = np.arange(len(V) - len(far[0]), len(V))
    assert np.abs(X[far_ids] - V[far_ids]).max() <= 1e-12 * diagonal(V)
    assert np.linalg.norm(X[sleeve] - V[sleeve], axis=1).mean() > 0.1 * 12.0


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
