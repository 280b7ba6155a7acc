# Run: PYTHONPATH=python /usr/bin/python3 -m pytest tests/python
import os
import sys

import numpy as np
import pytest

REPO = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
sys.path.insert(0, os.path.join(REPO, "python"))
SHARED_MESHES = os.path.join(REPO, "..", "shared", "data", "meshes")


def rotation(axis, degrees):
    k = np.asarray(axis, float)
    k = k / np.linalg.norm(k)
    t = np.radians(degrees)
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + np.sin(t) * K + (1 - np.cos(t)) * K @ K


def diagonal(V):
    return float(np.linalg.norm(V.max(0) - V.min(0)))


def triangles(F):
    return np.array([[f[0], f[k], f[k + 1]] for f in F for k in range(1, len(f) - 1)])


def volume(X, tris):
    a, b, c = X[tris[:, 0]], X[tris[:, 1]], X[tris[:, 2]]
    return float(np.einsum("ij,ij->i", a, np.cross(b, c)).sum() / 6.0)


@pytest.fixture
def shared_meshes():
    if not os.path.isdir(SHARED_MESHES):
        pytest.skip(f"public meshes not present at {SHARED_MESHES}")
    return SHARED_MESHES


@pytest.fixture(params=["cpu", "cuda"])
def device(request):
    """Every solver test runs on each backend: the CPU always, CUDA where a GPU is usable."""
    import larap

    if request.param not in larap.available_devices():
        pytest.skip(f"no usable CUDA device here (larap.available_devices() == {larap.available_devices()})")
    return request.param


def tol(device, cpu, cuda):
    """Tolerance for a backend: the CUDA path computes in float32."""
    return cpu if device == "cpu" else cuda
