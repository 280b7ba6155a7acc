# SPDX-License-Identifier: GPL-3.0-or-later
"""Python side of the surface-ARAP peer (surface_arap.cpp, CGAL's Surface_mesh_deformation).

    from peers import surface_arap
    exe = surface_arap.build("build-evidence")          # compiles once; RuntimeError if CGAL is missing
    result = surface_arap.deform(exe, V, tris, controls, [targets0, targets1], iterations=30)

The region of interest is every connected component that holds a control vertex (a component
without one would make CGAL's system singular; it stays where it is, as it would for an artist
who selects only what moves). Poses run in order, each warm-started from the one before, as an
artist drags. The program is built into a build folder only, never linked into the product.
"""
from __future__ import annotations

import json
import os
import shutil
import subprocess
import tempfile

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
SOURCE = os.path.join(HERE, "surface_arap.cpp")
HEADER = "/usr/include/CGAL/Surface_mesh_deformation.h"


def build(build_dir: str) -> str:
    """Path of the compiled program (rebuilt when the source is newer). RuntimeError with the
    reason when it cannot be built (libcgal-dev missing: scripts/setup installs it)."""
    if not os.path.exists(HEADER):
        raise RuntimeError("CGAL headers missing (Debian package libcgal-dev; scripts/setup installs it)")
    compiler = shutil.which("g++") or shutil.which("c++")
    if compiler is None:
        raise RuntimeError("no C++ compiler (g++) on PATH")
    os.makedirs(build_dir, exist_ok=True)
    exe = os.path.join(build_dir, "surface_arap")
    if os.path.exists(exe) and os.path.getmtime(exe) >= os.path.getmtime(SOURCE):
        return exe
    cmd = [compiler, "-O2", "-DNDEBUG", "-std=c++17", "-DCGAL_EIGEN3_ENABLED", "-I/usr/include/eigen3",
           SOURCE, "-o", exe, "-lgmp", "-lmpfr"]
    r = subprocess.run(cmd, capture_output=True, text=True)
    if r.returncode:
        raise RuntimeError("building the CGAL peer failed:\n" + r.stderr[-2000:])
    return exe


def components(n: int, tris: np.ndarray) -> np.ndarray:
    """Component label per vertex over the triangles' connectivity: every vertex takes the
    smallest label among its neighbours until nothing changes, with pointer jumping (labels only
    ever point at a vertex of the same component)."""
    label = np.arange(n)
    u = np.concatenate([tris[:, 0], tris[:, 1], tris[:, 2]])
    v = np.concatenate([tris[:, 1], tris[:, 2], tris[:, 0]])
    while True:
        m = np.minimum(label[u], label[v])
        new = label.copy()
        np.minimum.at(new, u, m)
        np.minimum.at(new, v, m)
        new = new[new]
        if np.array_equal(new, label):
            return label
        label = new


def deform(exe: str, V: np.ndarray, tris: np.ndarray, controls: np.ndarray, poses, iterations=30,
           tol=1e-4, timeout=None) -> dict:
    """Runs the peer: `poses` a list of (len(controls), 3) targets. Returns {"ok", "X": list of
    (n, 3) positions, "preprocess_ms", "pose_ms", "skipped_faces", "roi"} or {"ok": False,
    "error"}."""
    V = np.ascontiguousarray(V, np.float64)
    tris = np.ascontiguousarray(tris, np.int64)
    controls = np.ascontiguousarray(controls, np.int64)
    label = components(len(V), tris)
    roi = np.flatnonzero(np.isin(label, np.unique(label[controls])))
    with tempfile.TemporaryDirectory(prefix="surface_arap_") as tmp:
        mesh_path, poses_path, out_path = (os.path.join(tmp, f) for f in ("mesh.bin", "poses.bin", "out.bin"))
        with open(mesh_path, "wb") as f:
            for part in (np.array([len(V), len(tris)], np.int64), V.ravel(), tris.ravel(),
                         np.array([len(roi)], np.int64), roi.astype(np.int64),
                         np.array([len(controls)], np.int64), controls):
                f.write(np.ascontiguousarray(part).tobytes())
        with open(poses_path, "wb") as f:
            f.write(np.array([len(poses)], np.int64).tobytes())
            for T in poses:
                f.write(np.ascontiguousarray(T, np.float64).reshape(len(controls), 3).tobytes())
        try:
            r = subprocess.run([exe, mesh_path, poses_path, out_path, str(int(iterations)), repr(float(tol))],
                               capture_output=True, text=True, timeout=timeout)
        except subprocess.TimeoutExpired:
            return dict(ok=False, error=f"timed out after {timeout} s")
        try:
            res = json.loads(r.stdout.strip().splitlines()[-1])
        except (ValueError, IndexError):
            return dict(ok=False, error=f"exit {r.returncode}: {r.stderr[-500:]}")
        if not res.get("ok"):
            return res
        X = np.fromfile(out_path, np.float64).reshape(len(poses), len(V), 3)
    res.update(X=list(X), roi=int(len(roi)))
    return res
