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


def affine(R=np.eye(3), t=(0, 0, 0), pivot=(0, 0, 0)):
    """4x4 map x -> R (x - pivot) + pivot + t."""
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = np.asarray(pivot, float) - R @ np.asarray(pivot, float) + np.asarray(t, float)
    return T


def apply(T, X):
    """Points X (n by 3) through the 4x4 map T."""
    return X @ T[:3, :3].T + T[:3, 3]


def need_cuda():
    """A mark that skips a test where no usable CUDA device or build exists."""
    import larap
    return pytest.mark.skipif("cuda" not in larap.available_devices(), reason="no usable CUDA device/build")


def cpu_and_cuda():
    """Device parameters: "cpu", and "cuda" (skipped without a usable device)."""
    return ["cpu", pytest.param("cuda", marks=need_cuda())]


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
