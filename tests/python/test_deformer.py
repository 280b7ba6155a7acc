# Run: PYTHONPATH=python /usr/bin/python3 -m pytest tests/python/test_deformer.py
"""Properties of the CPU engine: rest pose, rigid motions, energy, volume, separate parts."""
import time

import numpy as np
import pytest
from conftest import rotation, tol

import larap
from larap import shapes
from larap.quality import diagonal, triangles, volume

WEIGHTS = ["trilinear", "bspline"]


@pytest.fixture(scope="module")
def tube():
    return shapes.tube(length=4.0, radius=0.5, segments=32, rings=64)


def spread_handles(V, k=40, seed=1):
    return np.random.default_rng(seed).choice(len(V), k, replace=False)


@pytest.mark.parametrize("weights", WEIGHTS)
def test_rest_targets_give_rest_pose(tube, weights, device):
    V, F = tube
    d = larap.Deformer(V, F, cells=2000, weights=weights, device=device)
    idx = spread_handles(V)
    d.set_handles(idx)
    X = d.solve(V[idx], iterations=5)
    assert np.abs(X - V).max() <= 1e-6 * diagonal(V)


@pytest.mark.parametrize("weights", WEIGHTS)
def test_rigid_motion_of_handles_gives_rigid_pose(tube, weights, device):
    V, F = tube
    R, t = rotation([1, 2, 3], 60), np.array([1.0, -2.0, 0.5])
    d = larap.Deformer(V, F, cells=2000, weights=weights, device=device)
    idx = spread_handles(V)
    d.set_handles(idx)
    X = d.solve(V[idx] @ R.T + t, iterations=60)
    assert np.abs(X - (V @ R.T + t)).max() <= 1e-3 * diagonal(V)


def bend_setup(V, angle=90.0):
    """Base fixed, tip turned about z around the pivot that keeps the centreline length."""
    base = np.flatnonzero(V[:, 0] < 0.45)
    tip = np.flatnonzero(V[:, 0] > 3.55)
    free = 3.55 - 0.45
    r = free / np.radians(angle)
    pivot = np.array([2.0, r - free / 2.0, 0.0]) if angle == 90.0 else np.array([2.0, 0.0, 0.0])
    R = rotation([0, 0, 1], angle)
    idx = np.concatenate([base, tip])
    T = np.concatenate([V[base], (V[tip] - pivot) @ R.T + pivot])
    return idx, T


def test_rigid_jump_after_earlier_solves(tube, device):
    V, F = tube
    d = larap.Deformer(V, F, cells=2000, device=device)
    idx, T = bend_setup(V)
    d.set_handles(idx)
    d.solve(T, iterations=10)  # a bent pose first
    R, t = rotation([1, 2, 3], 60), np.array([1.0, -2.0, 0.5])
    X = d.solve(V[idx] @ R.T + t, iterations=60)
    assert np.abs(X - (V @ R.T + t)).max() <= 1e-3 * diagonal(V)


@pytest.mark.parametrize("weights", WEIGHTS)
def test_energy_never_increases(tube, weights, device):
    V, F = tube
    d = larap.Deformer(V, F, cells=2000, weights=weights, device=device)
    idx, T = bend_setup(V)
    d.set_handles(idx)
    d.solve(T, iterations=25)
    e = np.array(d.stats["energy"])
    assert len(e) == 25
    assert e[0] > 0
    assert np.all(np.diff(e) <= tol(device, 1e-9, 1e-5) * e[0]), e
    # and the warm start continues downhill
    d.solve(T, iterations=5)
    assert d.stats["energy"][0] <= e[-1] * (1 + tol(device, 1e-9, 1e-5))


def test_bend_keeps_volume_and_round_sections(tube, device):
    V, F = tube
    d = larap.Deformer(V, F, weights="bspline", device=device)  # default resolution
    idx, T = bend_setup(V)
    d.set_handles(idx)
    X = d.solve(T, iterations=40)
    tris = triangles(F)
    assert abs(volume(X, tris) / volume(V, tris) - 1.0) < 0.05
    # handles reach their targets
    assert np.linalg.norm(X[idx] - T, axis=1).max() < 0.01 * diagonal(V)
    # the bend happened: the tip points along +y now
    tip = X[np.flatnonzero(V[:, 0] > 3.9)].mean(0) - X[np.flatnonzero((V[:, 0] > 3.5) & (V[:, 0] < 3.6))].mean(0)
    assert tip[1] > 0.9 * np.linalg.norm(tip)
    # cross-sections in the bend stay round: each ring keeps its radius within 5%
    segments = 32
    for ring in (24, 32, 40):  # rings along the free part
        ids = np.arange(ring * segments, (ring + 1) * segments)
        P = X[ids]
        r = np.linalg.norm(P - P.mean(0), axis=1)
        assert r.std() / r.mean() < 0.05, (ring, r.std() / r.mean())
        assert abs(r.mean() / 0.5 - 1.0) < 0.05, (ring, r.mean())


def test_handles_reach_targets_scale_free(tube, device):
    """The same gamma behaves the same on a tiny and a huge model. On the device within 5e-4 of the
    diagonal: its float solves differ by up to 1.4e-4 between two runs of the same solves (H100,
    2026-11-23), and this test once measured 1.13e-4 against its earlier bound of 1e-4; a gamma
    that depended on the scale would move the pose by percents."""
    V, F = tube
    idx, T = bend_setup(V)
    results = []
    for scale in (0.025, 100.0):
        d = larap.Deformer(V * scale, F, cells=2000, device=device)
        d.set_handles(idx)
        X = d.solve(T * scale, iterations=20)
        results.append(X / scale)
    assert np.abs(results[0] - results[1]).max() < tol(device, 1e-6, 5e-4) * diagonal(V)


def test_gamma_is_resolution_independent(tube, device):
    V, F = tube
    idx, T = bend_setup(V)
    errs = []
    for cells in (1500, 8000):
        d = larap.Deformer(V, F, cells=cells, device=device)
        d.set_handles(idx)
        X = d.solve(T, iterations=30)
        errs.append(np.linalg.norm(X[idx] - T, axis=1).mean())
    assert 0.5 < errs[0] / errs[1] < 2.0, errs


def head_with_eyes():
    head = shapes.sphere((0, 0, 0), 1.0, 24, 48)
    eyes = [shapes.sphere((0.8, s * 0.35, 0.3), 0.25, 10, 20) for s in (-1, 1)]
    V, F = shapes.concat(head, *eyes)
    n_head = len(head[0])
    return V, F, n_head


def test_separate_parts_follow_the_body(device):
    V, F, n_head = head_with_eyes()
    d = larap.Deformer(V, F, cells=4000, device=device)
    assert d.num_components == 1  # the eyes' cells are inside the head's: one lattice
    Vh = V[:n_head]
    top = np.flatnonzero(Vh[:, 2] > 0.75)
    bottom = np.flatnonzero(Vh[:, 2] < -0.75)
    idx = np.concatenate([top, bottom])
    R = rotation([0, 1, 0], -40)
    T = np.concatenate([V[top] @ R.T, V[bottom] @ R.T])  # the whole head turns: rigid
    d.set_handles(idx)
    X = d.solve(T, iterations=30)
    assert np.abs(X - V @ R.T).max() < 1e-3 * diagonal(V)
    # now a non-rigid move: the top turns, the bottom stays; eyes move with the head around them
    T = np.concatenate([V[top] @ R.T, V[bottom]])
    X = d.solve(T, iterations=30)
    for eye in (slice(n_head, n_head + (len(V) - n_head) // 2), slice(n_head + (len(V) - n_head) // 2, len(V))):
        E0, E1 = V[eye], X[eye]
        centre = E0.mean(0)
        near = np.flatnonzero(np.linalg.norm(Vh - centre, axis=1) < 0.5)
        head_motion = (X[near] - V[near]).mean(0)
        eye_motion = (E1 - E0).mean(0)
        assert np.linalg.norm(eye_motion) > 0.05
        assert np.linalg.norm(eye_motion - head_motion) < 0.25 * np.linalg.norm(head_motion)
        # the eye stays an eye: its radius is kept within 10%
        r0 = np.linalg.norm(E0 - E0.mean(0), axis=1).mean()
        r1 = np.linalg.norm(E1 - E1.mean(0), axis=1).mean()
        assert abs(r1 / r0 - 1) < 0.1


def test_parts_without_handles_stay_at_rest(device):
    a = shapes.sphere((0, 0, 0), 1.0, 12, 24)
    b = shapes.sphere((5, 0, 0), 1.0, 12, 24)
    V, F = shapes.concat(a, b)
    d = larap.Deformer(V, F, cells=2000, device=device)
    assert d.num_components == 2
    idx = np.flatnonzero(V[:len(a[0]), 2] > 0.8)
    d.set_handles(idx)
    X = d.solve(V[idx] + [0, 0, 0.5], iterations=10)
    assert np.abs(X[len(a[0]):] - V[len(a[0]):]).max() < tol(device, 1e-9, 1e-6) * diagonal(V)
    assert X[: len(a[0]), 2].mean() > 0.2


def test_no_handles_gives_rest_pose(tube, device):
    V, F = tube
    d = larap.Deformer(V, F, cells=1000, device=device)
    d.set_handles(np.zeros(0, np.int64))
    X = d.solve(np.zeros((0, 3)))
    assert np.array_equal(X, V)


def test_out_buffer_float32(tube, device):
    V, F = tube
    d = larap.Deformer(V, F, cells=1000, device=device)
    idx = spread_handles(V, 10)
    d.set_handles(idx)
    out = np.full((len(V), 3), np.nan, np.float32)
    r = d.solve(V[idx] + 0.1, out=out)
    assert r is out and np.isfinite(out).all()
    X = d.solve(V[idx] + 0.1, iterations=0)
    assert np.abs(out - X).max() < tol(device, 1e-5, 1e-4) * diagonal(V)


def test_switch_weights_keeps_pose(tube, device):
    V, F = tube
    d = larap.Deformer(V, F, cells=1500, device=device)
    idx, T = bend_setup(V)
    d.set_handles(idx)
    Xt = d.solve(T, iterations=30)
    d.weights = "bspline"
    Xb = d.solve(T, iterations=0)  # same lattice pose, other weights
    assert np.abs(Xt - Xb).max() < 0.02 * diagonal(V)
    assert d.weights == "bspline"


def test_deterministic(tube):
    V, F = tube
    idx, T = bend_setup(V)
    out = []
    for _ in range(2):
        d = larap.Deformer(V, F, cells=1500)
        d.set_handles(idx)
        out.append(d.solve(T, iterations=8))
    assert np.array_equal(out[0], out[1])


def test_lattice_accessors(tube, device):
    V, F = tube
    d = larap.Deformer(V, F, cells=1500, device=device)
    rest, edges = d.lattice_rest(), d.lattice_edges()
    assert rest.shape == (d.num_nodes, 3) and edges.shape[1] == 2
    assert edges.min() >= 0 and edges.max() < d.num_nodes
    lengths = np.linalg.norm(rest[edges[:, 0]] - rest[edges[:, 1]], axis=1)
    assert np.allclose(lengths, d.cell_size)
    assert np.abs(d.lattice_deformed() - rest).max() <= tol(device, 0.0, 1e-6) * diagonal(V)
    # the lattice covers the mesh
    assert (rest.min(0) <= V.min(0)).all() and (rest.max(0) >= V.max(0)).all()


def test_tolerance_stops_when_converged(tube, device):
    V, F = tube
    d = larap.Deformer(V, F, cells=1500, device=device)
    idx, T = bend_setup(V)
    d.set_handles(idx)
    X = d.solve(T, iterations=200, tol=1e-6)
    n = d.stats["iterations"]
    e = d.stats["energy"]
    assert 2 <= n < 200 and len(e) == n
    assert e[-2] - e[-1] <= 1e-6 * e[-1]
    # converged: solving again with the same targets barely moves the pose
    Y = d.solve(T, iterations=5)
    assert np.abs(Y - X).max() < 1e-3 * diagonal(V)
    with pytest.raises(ValueError):
        d.solve(T, tol=-1.0)


def test_one_deformer_from_several_threads(tube):
    """Calls from several Python threads are serialised, never a crash or a torn result."""
    import threading
    V, F = tube
    d = larap.Deformer(V, F, cells=1000)
    idx, T = bend_setup(V)
    d.set_handles(idx)
    ref = d.solve(T, iterations=3)
    d.reset()
    errors, results = [], []

    def work(k):
        try:
            for _ in range(5):
                if k % 2:
                    d.weights = "bspline" if d.weights == "trilinear" else "trilinear"
                results.append(d.solve(T, iterations=3))
                d.stats
        except Exception as exc:  # pragma: no cover - a failure is reported below
            errors.append(exc)

    threads = [threading.Thread(target=work, args=(k,)) for k in range(4)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert not errors
    assert all(np.isfinite(r).all() and r.shape == ref.shape for r in results)


def test_pose_lattice_returns_the_pose_it_made_while_another_thread_resets(tube):
    """pose_lattice poses and reads the lattice in one locked call: a reset() from another thread
    never lands between the two (it did: the preview then drew the rest lattice as the pose)."""
    import sys
    import threading
    import time
    V, F = tube
    d = larap.Deformer(V, F, cells=300)
    idx, T = bend_setup(V)
    d.set_handles(idx)
    rest = d.lattice_rest()
    stop, seen_rest = [False], [0]

    def resets():
        while not stop[0]:
            d.reset()

    old = sys.getswitchinterval()
    sys.setswitchinterval(1e-6)
    worker = threading.Thread(target=resets)
    worker.start()
    try:
        end = time.perf_counter() + 1.0
        calls = 0
        while time.perf_counter() < end:
            X = d.pose_lattice(T, iterations=1)
            calls += 1
            if np.abs(X - rest).max() < 1e-9:  # (reset() leaves the rest within rounding)
                seen_rest[0] += 1
    finally:
        stop[0] = True
        worker.join()
        sys.setswitchinterval(old)
    assert calls > 20 and seen_rest[0] == 0, (calls, seen_rest[0])


def test_a_point_cloud_moved_rigidly_is_rigid_at_once(device):
    """A point cloud (no faces): most lattice components hold one or two points. Every point a
    handle, one rigid map: the warm start turns each component onto its targets (two points: the
    least rotation taking their line onto the targets'), so 5 iterations give the rigid pose (the
    two-point components were translated only, 1.2% of the size off after 5 iterations)."""
    rng = np.random.default_rng(1)
    V = rng.random((300, 3))
    M = np.eye(4)
    M[:3, :3] = rotation([1, -2, 0.5], 115)
    M[:3, 3] = [3, -1, 7]
    d = larap.Deformer(V, device=device)
    assert d.num_components > 100
    d.set_handle_groups([np.arange(len(V))])
    X = d.solve(transforms=M[None], iterations=5)
    assert np.abs(X - (V @ M[:3, :3].T + M[:3, 3])).max() < tol(device, 1e-7, 1e-4) * np.sqrt(3)


def test_a_part_held_by_one_vertex_is_carried_without_a_turn(device):
    """A detached button held by a single vertex, everything translated: the button translates.
    Its one point's spread is rounding noise, and a rotation fitted to it turned the button by
    98-180 degrees in 60 of 60 random cases (turning it costs no energy, so no iteration undid it)."""
    import itertools
    cube = np.array(list(itertools.product([0, 1], [0, 1], [0, 1])), float)
    quads = [[0, 1, 3, 2], [4, 6, 7, 5], [0, 4, 5, 1], [2, 3, 7, 6], [0, 2, 6, 4], [1, 5, 7, 3]]
    rng = np.random.default_rng(7)
    for _ in range(10):
        V = np.vstack([cube * 2.0, cube * 0.3 + np.array([2.5, 0.7, 0.9]) + rng.random(3) * 0.1])
        F = np.array(quads + [[q + 8 for q in f] for f in quads])
        d = larap.Deformer(V, F, cells=500, device=device)
        d.set_handle_groups([np.arange(8), np.array([13])])
        M = np.eye(4)
        M[:3, 3] = rng.normal(size=3) * 0.3
        X = d.solve(transforms=np.stack([M, M]), iterations=5)
        assert np.abs(X - (V + M[:3, 3])).max() < tol(device, 1e-6, 1e-4)


def _guarded(count):
    """A float64 array of ``count`` values ending at an unreadable page: reading past its end
    faults (a segfault kills the test run: the failure is loud)."""
    import ctypes
    import mmap
    buf = mmap.mmap(-1, 2 * mmap.PAGESIZE, prot=mmap.PROT_READ | mmap.PROT_WRITE)
    addr = ctypes.addressof(ctypes.c_char.from_buffer(buf))
    if ctypes.CDLL(None).mprotect(ctypes.c_void_p(addr + mmap.PAGESIZE), mmap.PAGESIZE, 0) != 0:
        pytest.skip("mprotect unavailable")
    page = np.frombuffer(buf, dtype=np.float64, count=mmap.PAGESIZE // 8)
    return buf, page[-count:]


@pytest.mark.parametrize("transforms", [False, True])
def test_a_solve_racing_a_handle_change_reads_only_its_own_targets(transforms):
    """Another thread changes the handles (their count) while this one solves: each solve either
    poses with targets of the right shape or raises ValueError naming the shape; it never reads
    past the end of its targets (the shape was checked before the instance's lock)."""
    import threading
    V, F = larap.shapes.sphere(rings=20, segments=40)
    d = larap.Deformer(V, F, cells=300)
    if transforms:
        buf, flat = _guarded(16)
        t = flat.reshape(1, 4, 4)
        t[:] = np.eye(4)
        small, large = [np.arange(10)], [np.array([i]) for i in range(600)]
        change = d.set_handle_groups
    else:
        buf, flat = _guarded(3)
        t = flat.reshape(1, 3)
        t[:] = V[0]
        small, large = np.array([0]), np.arange(64)
        change = d.set_handles
    change(small)
    stop = threading.Event()

    def flip():
        while not stop.is_set():
            change(large)
            change(small)
    other = threading.Thread(target=flip)
    other.start()
    posed = refused = 0
    end = time.monotonic() + 2.0  # a race: the longer, the likelier it shows (~1 in 20,000 solves before the fix)
    try:
        while time.monotonic() < end:
            try:
                # the binding itself, past the Python-level check, which refuses most mismatches first
                X = d._core.solve(t, 1, None, 0.0, transforms)
                assert np.isfinite(X).all()
                posed += 1
            except ValueError as exc:
                assert "should have shape" in str(exc) and "changed?" in str(exc)
                refused += 1
    finally:
        stop.set()
        other.join()
    assert refused > 0
    assert len(d.handles) == (10 if transforms else 1)


@pytest.mark.parametrize("weights", ["trilinear", "bspline"])
def test_trilinear_binding_arrays_reproduce_the_trilinear_solve(tube, weights):
    """What a GPU preview evaluates (cell corners, fractions, node displacements) gives exactly
    the trilinear pose, whichever weights the Deformer solves with."""
    V, F = tube
    d = larap.Deformer(V, F, cells=600, weights=weights)
    idx = np.flatnonzero(V[:, 0] > V[:, 0].max() - 0.3)
    d.set_handles(idx)
    d.solve(V[idx] + [0, 0.3, 0], 5)
    cells, frac = d.trilinear_binding()
    corners = d.cell_nodes()[cells]                       # (n, 8)
    disp = d.lattice_deformed() - d.lattice_rest()
    f = frac.astype(np.float64)
    w = np.ones((len(V), 8))
    for c in range(8):
        for a in range(3):
            w[:, c] *= f[:, a] if (c >> a) & 1 else 1 - f[:, a]
    X = V + np.einsum("nk,nkd->nd", w, disp[corners])
    d.weights = "trilinear"
    ref = d.solve(V[idx] + [0, 0.3, 0], 0)
    # pose_lattice poses exactly what solve would, without touching the vertices
    e = larap.Deformer(V, F, cells=600, weights=weights)
    e.set_handles(idx)
    np.testing.assert_array_equal(e.pose_lattice(V[idx] + [0, 0.3, 0], 5), d.lattice_deformed())
    assert np.abs(X - ref).max() < 1e-5 * np.ptp(V, axis=0).max()


@pytest.mark.parametrize("levels", [1, 3])
def test_lattice_state_put_back_undoes_a_drag(tube, device, levels):
    """A cancelled drag: the state taken before it, put back, makes the next solve the one that
    would have followed without the drag, on every level of the hierarchy: on the CPU bit for bit;
    on the device within its run-to-run rounding (the same sequence twice on an H100 differs by up
    to 1.4e-4 of the diagonal; the state put back 1.4e-4, a reset instead 3.6e-2 and 6.0e-3)."""
    V, F = tube
    idx, T = bend_setup(V, angle=45.0)
    T2 = T + [0.0, 0.05, 0.0]
    drag = T + [0.0, 0.0, 0.8]
    d = larap.Deformer(V, F, cells=2000, levels=levels, device=device)
    d.set_handles(idx)
    d.solve(T, iterations=10)
    state = d.lattice_state()
    assert len(state) == d.levels and all(s.shape[1] == 3 for s in state)
    d.solve(drag, iterations=10)
    d.set_lattice_state(state)
    X = d.solve(T2, iterations=5)
    e = larap.Deformer(V, F, cells=2000, levels=levels, device=device)
    e.set_handles(idx)
    e.solve(T, iterations=10)
    Y = e.solve(T2, iterations=5)
    assert np.abs(X - Y).max() <= tol(device, 0.0, 1e-3) * diagonal(V)


def test_lattice_state_of_another_shape_is_refused(tube):
    V, F = tube
    d = larap.Deformer(V, F, cells=2000, levels=2)
    state = d.lattice_state()
    moved = state[0] + 0.25  # valid: a partial update would keep it
    for bad in ([moved], [moved, state[1], state[0]], [moved, state[1][:-1]], [moved, state[1] * np.nan],
                [moved, state[1][:, :2]]):
        with pytest.raises(ValueError):
            d.set_lattice_state(bad)
    assert all(np.array_equal(a, b) for a, b in zip(d.lattice_state(), state))
