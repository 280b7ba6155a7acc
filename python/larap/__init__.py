"""LARAP: as-rigid-as-possible deformation of meshes through a volumetric lattice.

    import larap
    V, F = larap.load_mesh("bunny.obj")
    d = larap.Deformer(V, F)                 # lattice + binding
    d.set_handles([10, 200, 3000])           # handle vertex ids (prefactorises)
    X = d.solve(targets)                     # targets: (3, 3) -> X: (n, 3) deformed vertices

See README.md and docs/method.md.
"""
from ._native import _core  # clear ImportError when the build is missing
from .deformer import DEFAULT_GAMMA, DEFAULT_JUNCTION_BRACE, GAMMA_RANGE, MAX_JUNCTION_BRACE, Deformer, available_devices, num_threads, set_num_threads
from .io import faces_to_csr, load_mesh, save_mesh

__all__ = ["Deformer", "DEFAULT_GAMMA", "DEFAULT_JUNCTION_BRACE", "GAMMA_RANGE", "MAX_JUNCTION_BRACE", "available_devices", "set_num_threads", "num_threads", "load_mesh", "save_mesh", "faces_to_csr"]
__version__ = _core.__version__  # CMakeLists.txt project(VERSION)
