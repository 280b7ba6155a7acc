# Run: PYTHONPATH=python /usr/bin/python3 -m pytest tests/python/test_hierarchy.py
"""The lattice hierarchy (levels > 1): 2x2x2 cells joined per level, solved coarse to fine."""
import numpy as np
import pytest
from conftest import rotation, tol

import larap
from larap import shapes
from larap.quality import diagonal


@pytest.fixture(scope="module")
def long_tube():
    V, F = shapes.tube(length=8.0, radius=0.5, segments=24, rings=96)
    base = np.flatnonzero(V[:, 0] < 0.5)
    tip = np.flatnonzero(V[:, 0] > 7.5)
    return V, F, base, tip


def test_levels_are_built_and_validated(long_tube):
    V, F, _, _ = long_tube
    d = larap.Deformer(V, F, cells=4000, levels=3)
    assert d.levels == 3
    for bad in (0, -1, 9):
        with pytest.raises(ValueError, match="levels"):
            larap.Deformer(V, F, cells=500, levels=bad)
    with pytest.raises(TypeError):
        larap.Deformer(V, F, cells=500, levels=2.0)


def test_rest_and_rigid_motion_are_exact_with_levels(long_tube, device):
    V, F, base, tip = long_tube
    idx = np.concatenate([base, tip])
    d = larap.Deformer(V, F, cells=4000, levels=3, device=device)
    d.set_handles(idx)
    X = d.solve(V[idx], iterations=5)
    # float32 on the GPU: 2.2e-6 of the diagonal on this 8-unit tube, with or without levels
    assert np.abs(X - V).max() <= tol(device, 1e-6, 1e-5) * diagonal(V)
    R, t = rotation([1, 2, 3], 60), np.array([0.5, -1.0, 2.0])
    X = d.solve(V[idx] @ R.T + t, iterations=30)
    assert np.abs(X - (V @ R.T + t)).max() <= 1e-3 * diagonal(V)


def test_hierarchy_carries_a_large_twist_faster(long_tube, device):
    V, F, base, tip = long_tube
    idx = np.concatenate([base, tip])
    T = np.concatenate([V[base], V[tip] @ rotation([1, 0, 0], 180).T])
    energy = {}
    for levels in (1, 3):
        d = larap.Deformer(V, F, cells=6000, levels=levels, device=device)
        d.set_handles(idx)
        d.solve(T, iterations=5)
        e = d.stats["energy"]
        assert np.all(np.diff(e) <= tol(device, 1e-9, 1e-5) * e[0])  # monotone within the fine solve
        energy[levels] = e[-1]
    assert energy[3] < 0.8 * energy[1], energy


def test_parts_without_handles_stay_at_rest_with_levels():
    a = shapes.sphere((0, 0, 0), 1.0, 12, 24)
    b = shapes.sphere((2.6, 0, 0), 1.0, 12, 24)  # close enough that coarse levels join them
    V, F = shapes.concat(a, b)
    n = len(a[0])
    d = larap.Deformer(V, F, cell_size=0.2, levels=3)
    idx = np.flatnonzero(V[:n, 2] > 0.8)
    d.set_handles(idx)
    X = d.solve(V[idx] + [0, 0, 0.5], iterations=10)
    assert np.abs(X[n:] - V[n:]).max() < 1e-9 * diagonal(V)
    assert X[:n, 2].mean() > 0.2
