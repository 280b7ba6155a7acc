"""Mesh files (OBJ, PLY, OFF) as numpy arrays, and the face-list conversion the engine uses.

    V, F = load_mesh("bunny.obj")         # V: (n, 3) float64, F: (m, 3) int64 for a triangle mesh
    save_mesh("out.ply", V, F)            # binary little-endian PLY
    save_mesh("posed.obj", X, F, template="bunny.obj")   # keeps UVs, normals, groups, materials
    offsets, indices = faces_to_csr(F, len(V))           # (m + 1,) and (k,) int64

Faces are either an (m, k) integer array (every face has k vertices) or a list of 1-D integer
sequences of any sizes (polygons). Vertex indices are 0-based.
"""
import os

import numpy as np

from . import _core

__all__ = ["load_mesh", "save_mesh", "faces_to_csr"]


def _path(name, path):
    """``path`` (str or bytes) for the engine, which reads it as a C string: a NUL would cut it
    short (and "x\0.obj" would write "x"), so it is refused as Python's open() refuses it."""
    text = os.fspath(path)
    if ("\0" if isinstance(text, str) else b"\0") in text:
        raise ValueError(f"{name} has an embedded null byte: {text!r}")
    return text


def load_mesh(path):
    """Read an OBJ, PLY (ascii or binary) or OFF file; the format comes from the extension.

    path: str or os.PathLike.
    Returns (vertices, faces):
      vertices: (n, 3) float64 positions.
      faces: (m, k) int64 array of 0-based vertex indices when every face has k vertices (an
        empty (0, 3) array for a point cloud), otherwise a list of m 1-D int64 arrays. An OBJ's
        polylines (`l`) come as faces of two vertices, one per segment, after the faces read
        before them (loose edges: docs/method.md), so triangles with lines give a list.
    Raises FileNotFoundError for a missing file, ValueError naming the file and line for malformed
    contents (truncated, lying counts, indices out of range, non-finite coordinates), OSError for
    other read failures.
    """
    vertices, offsets, indices = _core.load_mesh(_path("path", path))
    return vertices, csr_to_faces(offsets, indices)


def save_mesh(path, vertices, faces=None, *, template=None, ascii=False):
    """Write a mesh as OBJ, PLY or OFF (from the extension), atomically: through `path + ".tmp"`
    and a rename, so a failed write leaves an existing file untouched.

    vertices: (n, 3) real array (any float or integer dtype, any memory layout).
    faces: (m, k) integer array, a list of integer sequences (polygons), or None (point cloud).
    template: for OBJ output, an OBJ file (str or os.PathLike) whose lines are copied with only
      the `v` positions replaced when it has exactly n vertices, so UVs, normals, groups and
      materials survive a deformation; with another vertex count a plain OBJ is written.
    ascii: write ascii PLY instead of binary little endian (other formats are always text).
    OBJ positions are written with full double precision (they read back bit-exactly).
    """
    V = np.asarray(vertices)
    if V.ndim != 2 or V.shape[1] != 3:
        raise ValueError(f"vertices must have shape (n, 3), got {V.shape}")
    if not (np.issubdtype(V.dtype, np.floating) or np.issubdtype(V.dtype, np.integer)):
        raise TypeError(f"vertices must be a real array, got dtype {V.dtype}")
    V = np.ascontiguousarray(V, dtype=np.float64)
    if faces is None:
        offsets, indices = np.zeros(1, np.int64), np.zeros(0, np.int64)
    else:
        offsets, indices = faces_to_csr(faces, V.shape[0])
    tpl = "" if template is None else _path("template", template)
    _core.save_mesh(_path("path", path), V, offsets, indices, bool(ascii), tpl)


def faces_to_csr(faces, num_vertices=None):
    """Faces to compressed rows: (offsets, indices), face f = indices[offsets[f]:offsets[f + 1]].

    faces: (m, k) integer array (converted without a Python loop), or a sequence of 1-D integer
      sequences of any lengths (polygons).
    num_vertices: when given, every index must lie in [0, num_vertices).
    Returns offsets: (m + 1,) int64 starting at 0; indices: (offsets[-1],) int64.
    Raises TypeError for non-integer faces (float, bool, object), ValueError naming the face and
    index for a negative or out-of-range index, an empty face, or a wrong shape.
    """
    if isinstance(faces, np.ndarray) and faces.dtype != object:
        if faces.ndim == 2:
            return _rect_to_csr(faces, num_vertices)
        if faces.ndim == 1 and faces.size == 0:
            return np.zeros(1, np.int64), np.zeros(0, np.int64)
        raise ValueError(f"faces must be an (m, k) array or a list of polygons, got shape {faces.shape}")
    try:
        rows = list(faces)
    except TypeError:
        raise TypeError(f"faces must be an (m, k) array or a list of polygons, got {type(faces).__name__}") from None
    sizes = np.zeros(len(rows) + 1, np.int64)
    parts = []
    for f, row in enumerate(rows):
        a = np.asarray(row)
        if a.ndim != 1:
            raise ValueError(f"face {f} must be a 1-D sequence of vertex indices, got shape {a.shape}")
        if a.size == 0:
            raise ValueError(f"face {f} is empty")
        _check_integer(a, f"face {f}")
        if a.dtype == np.uint64:  # mixing uint64 with int64 would promote to float64
            _check_range(a, num_vertices, lambda i, f=f, a=a: f"face {f} {a.tolist()}")
        parts.append(a.astype(np.int64, copy=False))
        sizes[f + 1] = a.size
    offsets = np.cumsum(sizes)
    if not parts:
        return offsets, np.zeros(0, np.int64)
    flat = np.concatenate(parts)

    def face_of(i):
        f = int(np.searchsorted(offsets, i, side="right")) - 1
        return f"face {f} {parts[f].tolist()}"

    _check_range(flat, num_vertices, face_of)
    return offsets, flat


def csr_to_faces(offsets, indices):
    """Inverse of faces_to_csr: an (m, k) int64 array when all faces have k vertices (an empty
    (0, 3) array when there are none), else a list of 1-D int64 arrays."""
    offsets = np.asarray(offsets, np.int64)
    indices = np.asarray(indices, np.int64)
    m = offsets.size - 1
    if m <= 0:
        return np.zeros((0, 3), np.int64)
    sizes = np.diff(offsets)
    k = int(sizes[0])
    if np.all(sizes == k):
        return indices[offsets[0]:offsets[-1]].reshape(m, k)
    return np.split(indices[offsets[0]:offsets[-1]], offsets[1:-1] - offsets[0])


def _check_integer(a, what):
    if a.dtype == np.bool_ or not np.issubdtype(a.dtype, np.integer):
        raise TypeError(f"{what}: vertex indices must be integers, got dtype {a.dtype}")


def _check_range(flat, num_vertices, face_of):
    """ValueError naming the first index below 0 or (when num_vertices is given) past the end."""
    bad = flat < 0
    if num_vertices is not None:
        bad |= flat >= num_vertices
    elif flat.dtype == np.uint64:
        bad |= flat > np.iinfo(np.int64).max
    if bad.any():
        i = int(np.flatnonzero(bad)[0])
        limit = f" (valid: 0 to {num_vertices - 1})" if num_vertices is not None else ""
        raise ValueError(f"{face_of(i)} has vertex index {flat[i]}, out of range{limit}")


def _rect_to_csr(faces, num_vertices):
    m, k = faces.shape
    _check_integer(faces, "faces")
    if k == 0 and m > 0:
        raise ValueError(f"faces has shape {faces.shape}: faces need at least one vertex")
    flat = faces.reshape(-1)
    _check_range(flat, num_vertices, lambda i: f"face {i // k} {faces[i // k].tolist()}")
    offsets = np.arange(0, m * k + 1, k, dtype=np.int64) if k else np.zeros(1, np.int64)
    return offsets, np.ascontiguousarray(flat, dtype=np.int64)
