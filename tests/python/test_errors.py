# Run: PYTHONPATH=python /usr/bin/python3 -m pytest tests/python/test_errors.py
"""Every bad input to the Python API gets a clear exception of a fitting type (docs/robustness.md
lists the same table). Nothing here may crash the interpreter."""
import numpy as np
import pytest

import larap
from larap import shapes

V0, F0 = shapes.sphere((0, 0, 0), 1.0, 8, 16)
F0 = np.array([f + [f[-1]] if len(f) == 3 else f for f in F0])  # (m, 4), triangles padded


def make(**kw):
    args = dict(vertices=V0, faces=F0, cells=300)
    args.update(kw)
    V, F = args.pop("vertices"), args.pop("faces")
    return larap.Deformer(V, F, **args)


def bound(k=5):
    d = make()
    d.set_handles(np.arange(k))
    return d


CONSTRUCTION = [
    # (description, kwargs, exception, words the message must contain)
    ("empty mesh", dict(vertices=np.zeros((0, 3)), faces=None), ValueError, "empty"),
    ("vertices (n, 2)", dict(vertices=np.zeros((5, 2))), ValueError, "shape"),
    ("vertices 1-D", dict(vertices=np.zeros(9)), ValueError, "shape"),
    ("vertices of strings", dict(vertices=np.array([["a", "b", "c"]])), TypeError, "dtype"),
    ("vertices complex", dict(vertices=V0 + 0j), TypeError, "real"),
    ("NaN coordinate", dict(vertices=np.where(np.arange(len(V0))[:, None] == 7, np.nan, V0)), ValueError, "vertices[7]"),
    ("infinite coordinate", dict(vertices=np.where(np.arange(len(V0))[:, None] == 3, np.inf, V0)), ValueError, "vertices[3]"),
    ("face index out of range", dict(faces=np.array([[0, 1, len(V0)]])), ValueError, "out of range"),
    ("negative face index", dict(faces=np.array([[0, -1, 2]])), ValueError, "-1"),
    ("float faces", dict(faces=np.array([[0.0, 1.0, 2.0]])), TypeError, "integer"),
    ("all vertices coincide", dict(vertices=np.ones((4, 3)), faces=[[0, 1, 2]]), ValueError, "cell_size"),
    ("single point", dict(vertices=np.zeros((1, 3)), faces=None), ValueError, "cell_size"),
    ("cells zero", dict(cells=0), ValueError, "cells"),
    ("cells negative", dict(cells=-5), ValueError, "cells"),
    ("cells float", dict(cells=10.5), TypeError, "cells"),
    ("cells absurd", dict(cells=10**13), MemoryError, "cells"),
    ("cell_size zero", dict(cells=None, cell_size=0.0), ValueError, "cell_size"),
    ("cell_size negative", dict(cells=None, cell_size=-1.0), ValueError, "cell_size"),
    ("cell_size NaN", dict(cells=None, cell_size=float("nan")), ValueError, "cell_size"),
    ("cell_size absurdly small", dict(cells=None, cell_size=1e-7), MemoryError, "at cell size 1e-07 "),
    ("cells and cell_size", dict(cell_size=0.1), ValueError, "not both"),
    ("gamma zero", dict(gamma=0.0), ValueError, "gamma"),
    ("gamma NaN", dict(gamma=float("nan")), ValueError, "gamma"),
    ("gamma too large", dict(gamma=1e9), ValueError, "gamma must be between 1e-08 and 1e+08"),
    ("gamma too small", dict(gamma=1e-9), ValueError, "gamma must be between 1e-08 and 1e+08"),
    ("junction_brace negative", dict(junction_brace=-1.0), ValueError, "junction_brace must be between 0 and 10000"),
    ("junction_brace NaN", dict(junction_brace=float("nan")), ValueError, "junction_brace"),
    ("junction_brace too large", dict(junction_brace=1e5), ValueError, "0 turns the braces off"),
    ("junction_brace text", dict(junction_brace="50"), TypeError, "junction_brace must be a number"),
    ("levels beyond a C int", dict(levels=2**31), ValueError, "levels is out of range"),
    ("split_resolution beyond a C int", dict(split_resolution=2**40), ValueError, "split_resolution is out of range"),
    ("cells beyond int64", dict(cells=2**63), ValueError, "cells is out of range"),
    ("unknown weights", dict(weights="cubic"), ValueError, "weights"),
    ("unknown device", dict(device="tpu"), ValueError, "device"),
    ("memory limit", dict(cells=None, cell_size=0.01, max_bytes=1000), MemoryError, "MiB (limit 1000 B)"),
]


@pytest.mark.parametrize("what,kw,exc,words", CONSTRUCTION, ids=[c[0] for c in CONSTRUCTION])
def test_construction_errors(what, kw, exc, words):
    with pytest.raises(exc) as info:
        make(**kw)
    assert words in str(info.value), str(info.value)


def test_junction_brace_is_accepted_up_to_its_published_bound():
    assert larap.MAX_JUNCTION_BRACE == 1e4
    assert make(junction_brace=larap.MAX_JUNCTION_BRACE).junction_brace == larap.MAX_JUNCTION_BRACE
    with pytest.raises(ValueError, match="junction_brace must be between 0 and 10000"):
        make(junction_brace=np.nextafter(larap.MAX_JUNCTION_BRACE, np.inf))


def test_cuda_without_gpu_is_a_clear_error():
    if "cuda" in larap.available_devices():
        pytest.skip("a GPU is present")
    with pytest.raises(RuntimeError, match="cuda"):
        make(device="cuda")
    assert make(device="auto").device == "cpu"


def test_non_contiguous_and_read_only_inputs_are_read_correctly():
    ref = make().lattice_rest()
    Vf = np.asfortranarray(V0)
    Vr = V0.copy()
    Vr.setflags(write=False)
    Vs = np.concatenate([V0, V0], axis=1)[:, :3]  # strided view
    Vi = V0.astype(np.float32)
    for V in (Vf, Vr, Vs):
        np.testing.assert_array_equal(make(vertices=V).lattice_rest(), ref)
    assert make(vertices=Vi).num_nodes > 0
    Fr = F0.copy()
    Fr.setflags(write=False)
    assert make(faces=Fr[:, ::1]).num_nodes == make().num_nodes
    d = make()
    idx = np.arange(10)[::2]  # non-contiguous handle array
    d.set_handles(idx)
    T = np.asfortranarray(V0[idx])
    assert np.isfinite(d.solve(T)).all()


HANDLES = [
    ("index out of range", [0, len(V0)], ValueError, "out of range"),
    ("negative index", [0, -1], ValueError, "out of range"),
    ("repeated index", [3, 4, 3], ValueError, "twice"),
    ("float indices", np.array([0.0, 1.0]), TypeError, "integers"),
    ("2-D indices", np.array([[0, 1]]), ValueError, "1-D"),
    ("bool mask", np.ones(len(V0), bool), TypeError, "integers"),
]


@pytest.mark.parametrize("what,idx,exc,words", HANDLES, ids=[h[0] for h in HANDLES])
def test_handle_errors(what, idx, exc, words):
    d = make()
    with pytest.raises(exc) as info:
        d.set_handles(idx)
    assert words in str(info.value)


def test_solve_errors():
    d = make()
    with pytest.raises(RuntimeError, match="set_handles"):
        d.solve(np.zeros((0, 3)))
    d = bound(5)
    with pytest.raises(ValueError, match=r"\(5, 3\)"):
        d.solve(np.zeros((4, 3)))
    with pytest.raises(ValueError, match="targets\\[2\\]"):
        T = V0[:5].copy()
        T[2, 1] = np.nan
        d.solve(T)
    with pytest.raises(ValueError, match="iterations"):
        d.solve(V0[:5], iterations=-1)
    with pytest.raises(TypeError, match="out"):
        d.solve(V0[:5], out=np.zeros((len(V0), 3), np.int32))
    with pytest.raises(ValueError, match="shape"):
        d.solve(V0[:5], out=np.zeros((len(V0) + 1, 3)))
    with pytest.raises(ValueError, match="contiguous"):
        d.solve(V0[:5], out=np.zeros((3, len(V0))).T)
    # after all these errors the deformer still works
    X = d.solve(V0[:5] + 0.1)
    assert np.isfinite(X).all()


def test_weights_and_gamma_setters_validate():
    d = bound()
    with pytest.raises(ValueError):
        d.weights = "linear"
    with pytest.raises(ValueError):
        d.gamma = -1
    with pytest.raises(ValueError, match="between"):
        d.gamma = 1e12
    d.gamma = 0.5
    assert d.gamma == 0.5


@pytest.mark.parametrize("gamma", [1e-8, 1e8])
def test_the_rest_pose_comes_back_at_either_end_of_the_gamma_range(gamma):
    """Handles at rest give the rest pose at the least and the largest gamma accepted (beyond
    them, double precision did not: 1e-4 of the size at 1e12, 1.6e-5 at 1e-12)."""
    assert larap.GAMMA_RANGE == (1e-8, 1e8)
    V, F = larap.shapes.sphere(rings=20, segments=40)
    for weights in ("trilinear", "bspline"):
        d = larap.Deformer(V, F, cells=500, gamma=gamma, weights=weights)
        d.set_handle_groups([np.arange(0, len(V), 20), np.arange(5, len(V), 20)])
        X = d.solve(transforms=np.stack([np.eye(4)] * 2), iterations=10)
        assert np.abs(X - V).max() < 1e-6 * np.ptp(V, axis=0).max()


def test_a_system_that_cannot_be_factorised_says_why(capfd):
    """Handle weights 1e300 apart: the factorisation fails with a message naming gamma and the
    handles' pull, and CHOLMOD prints nothing of its own."""
    d = bound()
    with pytest.raises(RuntimeError, match=r"gamma\) and the handles' pull are too far apart.*factor of 1e\+"):
        d.set_handle_groups([np.arange(5), np.arange(60, 65)], weights=[1e300, 1.0])
    assert "CHOLMOD" not in capfd.readouterr().out


def test_solve_on_device_needs_cuda():
    d = bound()
    if d.device == "cuda":
        pytest.skip("runs on a GPU")
    with pytest.raises(RuntimeError, match="CUDA"):
        d.solve_on_device(V0[:5])


def test_cell_splitting_over_the_memory_limit_is_a_clear_error():
    """What cell splitting holds (split_resolution^3 bytes of voxels per analysed cell and more)
    counts against max_bytes with the grid: over it, a MemoryError naming the analysed cells and
    what to lower, never an allocation that takes the machine down. The smallest limit accepted
    grows by at least split_resolution^3 per analysed cell over the plain lattice's (a limit
    between one cell's voxels and all of them is refused). Upper bound on the real memory:
    tests/cpp/memory/test_split_memory.cpp."""
    import re
    V, F = shapes.concat(shapes.box((0, 0, 0), (4, 1, 1), 4), shapes.box((0, 0, 1.3), (4, 1, 2.3), 4))

    def smallest_limit(**kw):  # and the message just under it
        lo, hi, message = 1, 1 << 33, None
        while hi - lo > 1:
            mid = (lo + hi) // 2
            try:
                larap.Deformer(V, F, cell_size=1.0, max_bytes=mid, **kw)
                hi = mid
            except MemoryError as exc:
                lo, message = mid, str(exc)
        return hi, message

    plain, _ = smallest_limit(split_cells=False)
    limits = {}
    for k in (8, 24):
        limits[k], message = smallest_limit(split_resolution=k)
        assert "split_resolution (%d now)" % k in message and "split_cells=False" in message, message
        cells = int(re.search(r"analyse (\d+) cells", message).group(1))
        assert cells >= 8  # the cells between the two boxes
        assert limits[k] - plain >= cells * k ** 3, (k, limits[k], plain, cells)
        # Both sizes as read, never "0.0 MiB" for a limit of a few KiB.
        need, left = re.search(r"up to ([\d.]+ [KMG]?i?B) of .* over the ([\d.]+ [KMG]?i?B) the grid", message).groups()
        assert float(need.split()[0]) > 0 and float(left.split()[0]) > 0, message
        d = larap.Deformer(V, F, cell_size=1.0, split_resolution=k, max_bytes=limits[k])
        assert d.num_cells > larap.Deformer(V, F, cell_size=1.0, split_cells=False).num_cells  # it split
    assert plain < limits[8] < limits[24]


