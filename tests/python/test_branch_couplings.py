# Run: PYTHONPATH=python /usr/bin/python3 -m pytest tests/python/test_branch_couplings.py
"""Branch couplings in the engine's energy (issue 9, session 31; Lattice::couplings): a branch
copy's rotation also answers for the 12 edges of a trunk copy, at the coupling's weight. These tests
give them through the research hook that replaces a
lattice's copies (Lattice::replace_copies, `_lattice_copies`), as scripts/experiments/
branch_engine.py does. The energy stays an energy: rest and rigid motions are exact, flip-flops
never increase it, and a heavy coupling makes the branch copy turn with its trunk."""
import numpy as np
import pytest
from conftest import affine, need_cuda, rotation

import larap
from larap import shapes


def own_copies(d, couplings=(), weights=None):
    """The `_lattice_copies` arrays of `d`'s own lattice, with `couplings` ((branch, trunk,
    weight), ...) added."""
    w = d.cell_weights()
    cell, _ = d.trilinear_binding()
    k = np.array([(b, t) for b, t, _ in couplings], np.int32).reshape(-1, 2)
    return dict(cell_coords=d._core.cell_coords(), cell_nodes=d.cell_nodes(), cell_kind=d._core.cell_kinds(),
                cell_weight=np.ones(len(d.cell_nodes())) if weights is None and len(w) == 0 else
                (w if weights is None else weights),
                vertex_cell=cell, couplings=k, coupling_weights=np.array([c[2] for c in couplings], float))


def bar():
    """A 4 x 1 x 1 box, its ends as two handle groups."""
    V, F = shapes.box((0.0, 0.0, 0.0), (4.0, 1.0, 1.0), 8)
    return V, F, [np.flatnonzero(V[:, 0] < 0.3), np.flatnonzero(V[:, 0] > 3.7)]


def bend(V):
    """The far end turned 90 degrees about z through (3, 0.5, 0.5)."""
    return np.stack([np.eye(4), affine(rotation([0, 0, 1], 90.0), pivot=(3.0, 0.5, 0.5))])


def far_and_near(d):
    """Two copies: one at the far (turned) end and one at the held end."""
    coords = d._core.cell_coords()
    return int(np.argmax(coords[:, 0])), int(np.argmin(coords[:, 0]))


@pytest.mark.parametrize("weights", ["trilinear", "bspline"])
def test_replacing_the_copies_by_their_own_changes_nothing(weights):
    V, F, groups = bar()
    d0 = larap.Deformer(V, F, weights=weights, cell_size=0.25)
    d1 = larap.Deformer(V, F, weights=weights, cell_size=0.25, _lattice_copies=own_copies(d0))
    assert d1.num_nodes == d0.num_nodes
    for d in (d0, d1):
        d.set_handle_groups(groups)
    X0 = d0.solve(transforms=bend(V), iterations=10)
    X1 = d1.solve(transforms=bend(V), iterations=10)
    assert np.array_equal(X0, X1)


def coupled(V, F, weight=5.0, **kw):
    d0 = larap.Deformer(V, F, cell_size=0.25, **kw)
    b, t = far_and_near(d0)
    n = len(d0.cell_nodes())
    pairs = [(b, t, weight), (n // 2, n // 2 + 1, weight), (n // 2 + 1, n // 3, 0.5 * weight)]
    return larap.Deformer(V, F, cell_size=0.25, _lattice_copies=own_copies(d0, pairs), **kw)


def test_coupled_lattice_keeps_rest_and_rigid_motions():
    V, F, groups = bar()
    d = coupled(V, F)
    d.set_handle_groups(groups)
    size = np.linalg.norm(V.max(0) - V.min(0))
    X = d.solve(transforms=np.stack([np.eye(4)] * 2), iterations=5)
    assert np.abs(X - V).max() <= 1e-9 * size
    M = affine(rotation([1, 2, 3], 50), t=(0.3, -0.2, 0.1), pivot=(2.0, 0.5, 0.5))
    X = d.solve(transforms=np.stack([M] * 2), iterations=5)
    assert np.abs(X - (V @ M[:3, :3].T + M[:3, 3])).max() <= 1e-7 * size


def test_coupled_energy_never_increases():
    V, F, groups = bar()
    d = coupled(V, F)
    d.set_handle_groups(groups)
    d.solve(transforms=bend(V), iterations=40)
    e = np.array(d.stats["energy"])
    assert e[-1] < e[0]
    assert np.all(np.diff(e) <= 1e-9 * e[0]), np.diff(e).max() / e[0]


def test_the_last_energy_is_the_coupled_one():
    """The energy a solve reports after its last flip-flop (evaluated with the last rotations) is
    the one the next flip-flop's rotation pass sums for that pose: both count the couplings."""
    V, F, groups = bar()
    d = coupled(V, F, weight=30.0)
    d.set_handle_groups(groups)
    d.solve(transforms=bend(V), iterations=10)
    e10 = d.stats["energy"]
    d.reset()
    d.solve(transforms=bend(V), iterations=11)
    e11 = d.stats["energy"]
    assert len(e10) == 10 and len(e11) == 11
    assert abs(e10[-1] - e11[9]) <= 1e-12 * e10[0], (e10[-1], e11[9])


def test_couplings_leave_the_lattice_as_stiff():
    """A coupling's weight is not material: it does not count in gamma's normalisation by the
    copies' edges. A coupling between two copies of a separate box that its handle keeps at rest
    (zero there) leaves the bar's bend exactly as it was; counted, it softened the whole lattice
    (the bar's pose moved 0.07% of the diagonal at this weight)."""
    V0, F0, groups = bar()
    B, FB = shapes.box((0.0, 3.0, 0.0), (1.0, 4.0, 1.0), 8)
    V, F = shapes.concat((V0, F0), (B, FB))
    held = np.arange(len(V0), len(V))
    d0 = larap.Deformer(V, F, cell_size=0.25)
    coords = d0._core.cell_coords()
    a, b = np.flatnonzero(coords[:, 1] >= 14)[:2]  # two copies of the box's cells
    X = []
    for pairs in ([], [(a, b, 200.0)]):
        d = larap.Deformer(V, F, cell_size=0.25, _lattice_copies=own_copies(d0, pairs))
        d.set_handle_groups(groups + [held])
        X.append(d.solve(transforms=np.concatenate([bend(V), [np.eye(4)]]), iterations=20))
    size = np.linalg.norm(V.max(0) - V.min(0))
    assert np.abs(X[0] - X[1]).max() <= 1e-9 * size, np.abs(X[0] - X[1]).max() / size


def turned_degrees(d, c):
    """How far copy c's edges turned from rest (degrees): the best rotation of its 12 edges."""
    P, C = d.lattice_deformed(), d.lattice_rest()
    n = d.cell_nodes()[c]
    S = np.zeros((3, 3))
    for q in range(8):
        for a in range(3):
            if not (q >> a) & 1:
                u = q | (1 << a)
                S += np.outer(P[n[u]] - P[n[q]], C[n[u]] - C[n[q]])
    U, _, Wt = np.linalg.svd(S)
    R = U @ np.diag([1, 1, np.linalg.det(U @ Wt)]) @ Wt
    return np.degrees(np.arccos(np.clip((np.trace(R) - 1) / 2, -1, 1)))


def test_a_heavy_coupling_turns_the_branch_copy_with_its_trunk():
    """The far end's copy coupled to a copy of the held end: the heavier the coupling, the less it
    turns with its own handles (its rotation answers for the held copy's edges too), and with no
    weight it turns as on the plain lattice."""
    V, F, groups = bar()
    d0 = larap.Deformer(V, F, cell_size=0.25)
    b, t = far_and_near(d0)
    turned = []
    for weight in (None, 0.0, 3.0, 30.0):
        pairs = [] if weight is None else [(b, t, weight)]
        d = larap.Deformer(V, F, cell_size=0.25, _lattice_copies=own_copies(d0, pairs))
        d.set_handle_groups(groups)
        d.solve(transforms=bend(V), iterations=60)
        turned.append(turned_degrees(d, b))
    plain, zero, some, heavy = turned
    assert abs(zero - plain) < 1e-9 and plain > 60.0, turned
    assert heavy < some < plain - 5.0, turned


def test_bad_copies_are_refused():
    V, F, _ = bar()
    d0 = larap.Deformer(V, F, cell_size=0.25)
    good = own_copies(d0)
    nodes = good["cell_nodes"].copy()
    nodes[1, 0] = nodes[0, 0] + 10 ** 5  # a label of its own: fine
    far = good["cell_nodes"].copy()
    far[5, 7] = far[0, 0]  # one label at two grid points
    twice = good["cell_nodes"].copy()
    twice[3, 1] = twice[3, 0]
    moved = good["vertex_cell"].copy()
    moved[0] = (moved[0] + 40) % len(good["cell_kind"])  # a copy of another cell
    for change in ({"couplings": np.array([[0, 10 ** 6]], np.int32), "coupling_weights": np.array([1.0])},
                   {"couplings": np.array([[0, 1]], np.int32), "coupling_weights": np.array([-1.0])},
                   {"couplings": np.array([[0, 1]], np.int32), "coupling_weights": np.array([np.inf])},
                   {"couplings": np.array([[2, 2]], np.int32), "coupling_weights": np.array([1.0])},
                   {"couplings": np.array([[0, 1, 2]], np.int32), "coupling_weights": np.array([1.0])},
                   {"cell_weight": np.full(len(good["cell_kind"]), np.nan)},
                   {"cell_weight": np.zeros(len(good["cell_kind"]))},
                   {"cell_nodes": far}, {"cell_nodes": twice}, {"vertex_cell": moved},
                   {"vertex_cell": good["vertex_cell"].astype(np.int64) + 2 ** 32},
                   {"vertex_cell": good["vertex_cell"][:-1]},
                   {"cell_coords": good["cell_coords"][::-1].copy()}):
        with pytest.raises(ValueError):
            larap.Deformer(V, F, cell_size=0.25, _lattice_copies=dict(good, **change))
    larap.Deformer(V, F, cell_size=0.25, _lattice_copies=dict(good, cell_nodes=nodes))
    with pytest.raises(ValueError, match="split_cells"):
        larap.Deformer(V, F, split_cells=False, _branch_copies=True)
    for bad in (-1.0, np.nan, np.inf):
        with pytest.raises(ValueError, match="branch_coupling"):
            larap.Deformer(V, F, _branch_copies=True, _branch_coupling=bad)


@need_cuda()
@pytest.mark.parametrize("weights", ["trilinear", "bspline"])
def test_cpu_and_cuda_agree_with_couplings(weights):
    """The device fits a coupled copy's rotation to its trunk's edges too (flip_flop.cuh, rot_cell)
    and gathers the couplings in its right-hand side: converged, both devices give one pose."""
    V, F, groups = bar()
    out = {}
    for dev in ("cpu", "cuda"):
        d = coupled(V, F, weights=weights, device=dev)
        d.set_handle_groups(groups)
        out[dev] = d.solve(transforms=bend(V), iterations=300)
        e = np.array(d.stats["energy"])
        assert np.all(np.diff(e) <= 1e-4 * e[0] + 1e-7), (dev, e)
    size = np.linalg.norm(V.max(0) - V.min(0))
    assert np.abs(out["cpu"] - out["cuda"]).max() <= 1e-4 * size
