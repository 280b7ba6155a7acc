# Run: PYTHONPATH=python /usr/bin/python3 -m pytest tests/python/test_inputs.py
"""Every kind of input binds and solves: open meshes, soups, flipped faces, non-manifold edges,
flat sheets, many parts, point clouds; and the inside test fills solids but not holes or gaps."""
import os

import numpy as np
import pytest

import larap
from larap import shapes
from larap.quality import diagonal


def cell_centres(d):
    c = d._core.cell_coords()
    return np.asarray(d._core.origin) + (c + 0.5) * d.cell_size


def kinds(d):
    return d._core.cell_kinds()


def solve_somehow(V, F, **kw):
    d = larap.Deformer(V, F, **kw)
    lo = np.flatnonzero(V[:, 0] <= np.quantile(V[:, 0], 0.1))
    hi = np.flatnonzero(V[:, 0] >= np.quantile(V[:, 0], 0.9))
    idx = np.concatenate([lo, hi])
    d.set_handles(idx)
    T = np.concatenate([V[lo], V[hi] + [0, 0.2 * diagonal(V), 0]])
    X = d.solve(T, iterations=10)
    assert X.shape == V.shape and np.isfinite(X).all()
    assert np.linalg.norm(X[idx] - T, axis=1).max() < 0.05 * diagonal(V)
    return d, X


def test_closed_sphere_is_solid():
    V, F = shapes.sphere((0, 0, 0), 1.0, 16, 32)
    d, _ = solve_somehow(V, F, cell_size=0.1)
    c = cell_centres(d)
    inside = np.linalg.norm(c, axis=1) < 0.8
    assert inside.sum() > 1000
    assert np.all(kinds(d)[inside] & 2)  # every deep cell is marked inside


def test_torus_hole_is_not_filled():
    V, F = shapes.torus(1.0, 0.3, 64, 24)
    d, _ = solve_somehow(V, F, cell_size=0.1)
    c = cell_centres(d)
    assert not np.any(np.linalg.norm(c[:, :2], axis=1) < 0.45)  # hole of radius 0.7


def test_gap_between_parts_is_not_filled():
    V, F = shapes.concat(shapes.box((0, 0, 0), (1, 1, 1), 4), shapes.box((2, 0, 0), (3, 1, 1), 4))
    d, _ = solve_somehow(V, F, cell_size=0.1)
    c = cell_centres(d)
    assert not np.any((c[:, 0] > 1.25) & (c[:, 0] < 1.75))
    assert d.num_components == 2


@pytest.mark.parametrize("flip", [False, True])
def test_soup_and_inconsistent_orientation_fill_the_inside(flip):
    V, F = shapes.sphere((0, 0, 0), 1.0, 16, 32)
    if flip:  # half the faces flipped, shared vertices kept
        F = [f[::-1] if k % 2 else f for k, f in enumerate(F)]
    else:
        V, F = shapes.soup(V, F)
    d, _ = solve_somehow(V, F, cell_size=0.1)
    c = cell_centres(d)
    inside = np.linalg.norm(c, axis=1) < 0.8
    assert np.all(kinds(d)[inside] & 2)


def test_open_mesh_with_a_hole_still_fills():
    """A sphere with its top cap removed: most of the inside is still inside (ray votes)."""
    V, F = shapes.sphere((0, 0, 0), 1.0, 16, 32)
    F = [f for f in F if V[f].mean(0)[2] < 0.9]
    d, _ = solve_somehow(V, F, cell_size=0.1)
    c = cell_centres(d)
    deep = np.linalg.norm(c, axis=1) < 0.6
    assert (kinds(d)[deep] & 2).mean() > 0.9


def test_open_tube_without_caps():
    V, F = shapes.tube(4, 0.5, 24, 32, caps=False)
    solve_somehow(V, F, cells=1500)


def test_non_manifold_edges():
    # three quads sharing one edge, plus a box
    V = np.array([[0, 0, 0], [0, 0, 1], [1, 0, 0], [1, 0, 1], [0, 1, 0], [0, 1, 1], [-1, -1, 0], [-1, -1, 1]], float)
    F = [[0, 2, 3, 1], [0, 4, 5, 1], [0, 6, 7, 1]]
    solve_somehow(V, F, cells=500)


def test_flat_sheet():
    V, F = shapes.sheet(20, 20)
    d, X = solve_somehow(V, F, cells=800)
    assert not np.any(kinds(d) & 2)  # zero thickness: nothing inside


def test_many_separate_parts():
    parts = [shapes.sphere((3 * i, 3 * j, 0), 0.5, 6, 12) for i in range(4) for j in range(4)]
    V, F = shapes.concat(*parts)
    d = larap.Deformer(V, F, cells=3000)
    assert d.num_components == 16


def test_point_cloud_and_loose_vertices():
    V = np.random.default_rng(0).random((500, 3))
    d = larap.Deformer(V, None, cells=400)
    d.set_handles(np.arange(10))
    X = d.solve(V[:10] + 0.1)
    assert np.isfinite(X).all()


def test_single_triangle_and_degenerate_faces():
    V = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [2, 2, 2]], float)
    F = [[0, 1, 2], [0, 0, 1], [3, 3, 3], [0, 1, 2, 2]]  # repeated indices, a zero-area face
    d = larap.Deformer(V, F, cells=100)
    d.set_handles([0, 3])
    X = d.solve(V[[0, 3]] + 0.5)
    assert np.isfinite(X).all()


def test_large_triangles_are_never_missed():
    """Two huge triangles spanning many cells: every cell they cross is kept."""
    V = np.array([[0, 0, 0], [10, 0, 0], [0, 10, 0], [10, 10, 0.0]])
    F = [[0, 1, 2], [1, 3, 2]]
    d = larap.Deformer(V, F, cell_size=0.5)
    c = cell_centres(d)
    surface = c[(kinds(d) & 1) > 0]
    # the plane z=0 lies on cell faces or inside one layer: the 20x20 footprint is covered
    xy = np.unique(np.floor(surface[:, :2] / 0.5).astype(int), axis=0)
    assert len(xy) >= 400


def test_cells_and_cell_size():
    V, F = shapes.sphere((0, 0, 0), 1.0, 16, 32)
    d = larap.Deformer(V, F, cells=3000)
    assert 2000 < d.num_cells < 4500
    d = larap.Deformer(V, F, cell_size=0.25)
    assert d.cell_size == 0.25


def test_public_meshes_bind_and_solve(shared_meshes):
    for name in sorted(os.listdir(shared_meshes)):
        if not name.endswith((".obj", ".off", ".ply")):
            continue
        V, F = larap.load_mesh(os.path.join(shared_meshes, name))
        d, X = solve_somehow(V, F, cells=2000)
        assert d.num_nodes > 100, name


def test_polygon_csr_gives_the_same_deformer_as_a_polygon_list():
    """Blender hands its polygons over as CSR (loops.vertex_index, polygons.loop_start): passed
    on as they are, they give the same lattice and pose as the same polygons given as a list."""
    V, F = shapes.sphere((0, 0, 0), 1.0, 8, 16)  # quads and triangle fans at the poles
    offsets = np.concatenate([[0], np.cumsum([len(f) for f in F])])
    flat = np.concatenate([np.asarray(f) for f in F])
    a = larap.Deformer(V, F, cells=400)
    b = larap.Deformer(V, flat.astype(np.int32), face_offsets=offsets.astype(np.int32), cells=400)
    np.testing.assert_array_equal(a.lattice_rest(), b.lattice_rest())
    idx = np.arange(6)
    for d in (a, b):
        d.set_handles(idx)
    T = V[idx] + [0.2, 0, 0]
    np.testing.assert_array_equal(a.solve(T, 5), b.solve(T, 5))


@pytest.mark.parametrize("offsets,flat,exc,words", [
    ([0, 3, 5], [0, 1, 2, 3], ValueError, "end at"),
    ([[0, 3]], [0, 1, 2], ValueError, "1-D"),
    ([0, 3], [0.0, 1.0, 2.0], TypeError, "integers"),
    ([0, 3], [0, 1, 10**6], ValueError, "out of range"),
    ([0, 3, 2, 3], [0, 1, 2], ValueError, "offsets"),
])
def test_polygon_csr_errors(offsets, flat, exc, words):
    V, _ = shapes.sphere((0, 0, 0), 1.0, 8, 16)
    with pytest.raises(exc) as info:
        larap.Deformer(V, np.asarray(flat), face_offsets=np.asarray(offsets), cells=200)
    assert words in str(info.value), str(info.value)


def test_limits_are_the_engines():
    """One definition of each limit: the engine's, which Python reports as it is."""
    V, F = shapes.sphere((0, 0, 0), 1.0, 8, 16)
    with pytest.raises(ValueError, match=f"between 1 and {larap._core.MAX_LEVELS}"):
        larap.Deformer(V, F, cells=200, levels=larap._core.MAX_LEVELS + 1)
    d = larap.Deformer(V, F, cells=200)
    d.set_handles([0])
    with pytest.raises(ValueError, match=str(larap._core.MAX_ITERATIONS)):
        d.solve(V[:1], iterations=larap._core.MAX_ITERATIONS + 1)


@pytest.mark.parametrize("scale", [1e-40, 1e-6, 1e6, 1e40])
def test_a_scaled_mesh_gives_the_scaled_pose(scale):
    """ARAP has no length scale: a mesh scaled by s, posed by targets scaled by s, gives the pose
    scaled by s, from nanometres to light years (no overflow or underflow in the solve)."""
    from larap import shapes
    V, F = shapes.box((0, 0, 0), (4, 1, 1), 6)
    ends = [np.flatnonzero(V[:, 0] < 0.5), np.flatnonzero(V[:, 0] > 3.5)]
    T = np.stack([np.eye(4), np.eye(4)])
    T[1, :3, 3] = (0.0, 0.8, 0.3)
    poses = []
    for s in (1.0, scale):
        d = larap.Deformer(V * s, F, cells=200)
        d.set_handle_groups(ends)
        Ts = T.copy()
        Ts[:, :3, 3] *= s
        poses.append(d.solve(transforms=Ts, iterations=10) / s)
    assert np.isfinite(poses[1]).all()
    assert np.abs(poses[1] - poses[0]).max() <= 1e-6 * 4.0


@pytest.mark.parametrize("where", ["huge vertex", "tiny mesh", "span beyond doubles", "huge cell"])
def test_sizes_beyond_the_solver_are_refused_with_a_reason(where):
    """A stray vertex at 1e300, a mesh of 1e-300 units, coordinates spanning more than the double
    range or a cell of 1e100: a clear ValueError, never a crash or a non-finite pose."""
    from larap import shapes
    V, F = shapes.box((0, 0, 0), (1, 1, 1), 2)
    kw = {}
    if where == "huge vertex":
        V[3, 0] = 1e300
    elif where == "tiny mesh":
        V = V * 1e-300
    elif where == "span beyond doubles":
        V[0, 0], V[1, 0] = -1.5e308, 1.5e308
    else:
        kw = {"cell_size": 1e100}
    with pytest.raises(ValueError, match="scale"):
        larap.Deformer(V, F, **kw)
