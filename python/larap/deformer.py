"""The numpy-facing Deformer: converts every input to the engine's types and shapes (with errors
that name the argument), then hands it to the native engine, which checks the values (ranges,
finiteness, limits) once, for C++ and Python callers alike."""
from __future__ import annotations

import numbers
import warnings

import numpy as np

from ._native import _core
from .io import faces_to_csr

DEFAULT_GAMMA = _core.DEFAULT_GAMMA  # the engine's default stiffness (native/include/larap/deformer.h)
GAMMA_RANGE = tuple(_core.GAMMA_RANGE)  # (least, largest) gamma the engine accepts: (1e-08, 1e+08)
DEFAULT_JUNCTION_BRACE = _core.DEFAULT_JUNCTION_BRACE  # braces where the solid branches (docs/method.md)
MAX_JUNCTION_BRACE = _core.MAX_JUNCTION_BRACE  # the largest junction_brace the engine accepts (1e4)


def available_devices() -> list[str]:
    """Devices this build can use now: always "cpu", plus "cuda" when a usable GPU is present."""
    return list(_core.available_devices())


def set_num_threads(n: int) -> None:
    """Limit the CPU worker threads of every Deformer in this process (0 = all cores)."""
    _core.set_num_threads(_integer("the number of threads", n))


def num_threads() -> int:
    """The CPU worker threads the engine may use now."""
    return int(_core.num_threads())


def _points(name: str, array, rows: int | None = None) -> np.ndarray:
    """(rows, 3) float64 C-contiguous copy-or-view of `array`, with clear errors (the engine
    rejects non-finite values)."""
    try:
        a = np.asarray(array)
    except Exception as exc:  # ragged lists and the like
        raise ValueError(f"{name} must be an (n, 3) array of numbers: {exc}") from None
    if a.dtype == object or not (np.issubdtype(a.dtype, np.number) or a.dtype == np.bool_):
        raise TypeError(f"{name} must hold numbers, got dtype {a.dtype}")
    if a.dtype == np.bool_ or np.issubdtype(a.dtype, np.complexfloating):
        raise TypeError(f"{name} must hold real numbers, got dtype {a.dtype}")
    if a.ndim != 2 or a.shape[1] != 3:
        raise ValueError(f"{name} should have shape ({'n' if rows is None else rows}, 3), shape is {a.shape}")
    if rows is not None and a.shape[0] != rows:
        raise ValueError(f"{name} should have shape ({rows}, 3), shape is {a.shape}")
    return np.ascontiguousarray(a, dtype=np.float64)


def _positive_int(name: str, value) -> int:
    """A positive integer that fits the engine's 64-bit integers."""
    value = _integer(name, value, bits=64)
    if value <= 0:
        raise ValueError(f"{name} must be positive, got {value}")
    return value


def _real(name: str, value) -> float:
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        raise TypeError(f"{name} must be a number, got {value!r}")
    return float(value)


def _positive_float(name: str, value) -> float:
    """For cells and cell_size, where the engine reads 0 as "choose for me"."""
    value = _real(name, value)
    if not np.isfinite(value) or value <= 0.0:
        raise ValueError(f"{name} must be a positive finite number, got {value}")
    return value


def _boolean(name: str, value) -> bool:
    if not isinstance(value, (bool, np.bool_)):
        raise TypeError(f"{name} must be True or False, got {value!r}")
    return bool(value)


def _integer(name: str, value, bits: int = 32) -> int:
    """An integer that fits the engine's ``bits``-bit signed integers (the engine checks the
    ranges that matter; this keeps a huge Python int from reaching the binding)."""
    if isinstance(value, bool) or not isinstance(value, numbers.Integral):
        raise TypeError(f"{name} must be an integer, got {value!r}")
    value = int(value)
    if not -(1 << (bits - 1)) <= value < (1 << (bits - 1)):
        raise ValueError(f"{name} is out of range, got {value}")
    return value


def _polygons(faces, face_offsets, n: int) -> tuple[np.ndarray, np.ndarray]:
    """(offsets, indices) of the faces: from `faces` as given, or, with `face_offsets`, `faces`
    is already the flat index array (the engine checks the ranges)."""
    if face_offsets is None:
        if faces is None:
            return np.zeros(1, np.int64), np.zeros(0, np.int64)
        return faces_to_csr(faces, n)
    offsets = np.asarray(face_offsets)
    indices = np.asarray(faces) if faces is not None else np.zeros(0, np.int64)
    for name, a in (("face_offsets", offsets), ("faces", indices)):
        if a.ndim != 1:
            raise ValueError(f"with face_offsets, {name} must be a 1-D integer array, shape is {a.shape}")
        if a.size and (a.dtype == np.bool_ or not np.issubdtype(a.dtype, np.integer)):
            raise TypeError(f"{name} must hold integers, got dtype {a.dtype}")
    offsets = np.ascontiguousarray(offsets, dtype=np.int64)
    indices = np.ascontiguousarray(indices, dtype=np.int64)
    if offsets.size == 0 or offsets[-1] != indices.size:
        raise ValueError(f"face_offsets must end at len(faces) = {indices.size} "
                         f"(one entry more than the number of faces)")
    return offsets, indices


class Deformer:
    """As-rigid-as-possible deformation of a mesh through a volumetric lattice.

    vertices: (n, 3) rest positions (any real dtype; copied to float64).
    faces: (m, k) integer array, a list of polygons of any sizes, or None for a point cloud.
        A face of two distinct vertices is a loose edge (a wire mesh, a Skin modifier's
        skeleton): the lattice keeps the cells it passes through, so the wire stays one piece.
    face_offsets: optional (m + 1,) integer array: then `faces` is the flat 1-D array of the
        polygons' vertex ids and face f is faces[face_offsets[f]:face_offsets[f + 1]] (Blender's
        loops.vertex_index with polygons.loop_start plus the loop count), passed on as it is.
    cells: approximate number of lattice cells (default about 6000), or
    cell_size: the lattice cell edge length (give one of the two).
    weights: "trilinear" (8 nodes, fast, for dragging) or "bspline" (27 nodes, C1, final quality).
    gamma: rigidity, scale-free: the same value behaves the same at any model size, lattice
        resolution and handle count (docs/method.md). Larger is stiffer; handles are soft, and
        pull harder the smaller gamma is (default DEFAULT_GAMMA = 0.03; 0.1 before 2026-11-22);
        within GAMMA_RANGE (1e-8 to 1e8), beyond which double precision no longer gives the rest
        pose back.
    device: "cpu", "cuda" or "auto" (CUDA when a usable GPU exists, else the CPU; see .device).
    levels: lattice levels solved coarse to fine, each joining 2x2x2 cells of the one below (the
        paper's hierarchy; coarser levels run on the CPU). 1 = the fine lattice alone. More levels
        carry large moves across big lattices in fewer iterations. Coarse levels keep the pieces
        apart that the fine level keeps apart (one coarse copy per connected group).
    split_cells: keep a cell once per connected piece of the solid inside it (default True), so
        parts closer than a cell (fingers, tines) do not share lattice nodes; False keeps the
        plain lattice, where everything in one cell moves together.
    split_resolution: voxels per cell edge used to find the pieces (default 24, 4..64): two
        surfaces of one part farther apart than 3.5 / split_resolution of a cell (0.15 cell at
        24; 2 / split_resolution when they face along an axis) separate wherever the air between
        them reaches the outside through the analysed cells; surfaces of separate parts (not
        joined by faces or shared vertex positions) separate closer: measured from 1.25 /
        split_resolution along an axis to about 2.7 / split_resolution at the worst angle (0.05
        to 0.11 cell at 24; docs/method.md). Each analysed cell takes split_resolution^3 bytes
        while the lattice is built, a few times more where several parts meet in it.
    junction_brace: where the solid branches inside a cell (fingers leaving a palm, tines leaving
        a fork's joint, closer than a cell), the lattice cell that holds every root is braced: its
        node columns along the branching are held straight, so a turned finger does not tilt its
        neighbours' roots. The weight, per unit of the lattice's stiffness (default
        DEFAULT_JUNCTION_BRACE = 50, between 0 and 1e4): zero under every affine map, so rigid
        and affine poses stay exact; 0 turns the braces off.
    max_bytes: memory the lattice's grid and cell splitting's voxels may take (default half the
        machine's memory); over it, MemoryError says what to lower, before allocating.
    """

    def __init__(self, vertices, faces=None, *, face_offsets=None, cells=None, cell_size=None,
                 weights="trilinear", gamma=DEFAULT_GAMMA, device="cpu", max_bytes=None, levels=1,
                 split_cells=True, split_resolution=24, junction_brace=DEFAULT_JUNCTION_BRACE,
                 _lattice_copies=None, _branch_copies=False, _branch_coupling=10.0):
        V = _points("vertices", vertices)
        if V.shape[0] == 0:
            raise ValueError("vertices is empty: the mesh needs at least one vertex")
        offsets, indices = _polygons(faces, face_offsets, V.shape[0])
        if cells is not None and cell_size is not None:
            raise ValueError("give cells or cell_size, not both")
        n_cells = _positive_int("cells", cells) if cells is not None else 0
        size = _positive_float("cell_size", cell_size) if cell_size is not None else 0.0
        limit = 0 if max_bytes is None else _positive_int("max_bytes", max_bytes)
        self._n = V.shape[0]
        self._core = _core.Deformer(V, offsets, indices, n_cells, size, str(weights), _real("gamma", gamma),
                                    str(device), limit, _integer("levels", levels),
                                    _boolean("split_cells", split_cells),
                                    _integer("split_resolution", split_resolution),
                                    _real("junction_brace", junction_brace), _lattice_copies,
                                    _boolean("_branch_copies", _branch_copies), _real("_branch_coupling", _branch_coupling))
        self._handles_set = False
        self._warned = ""
        self._warn_fallback()

    def _warn_fallback(self):
        reason = self._core.fallback_reason
        if reason and reason != self._warned:
            self._warned = reason
            warnings.warn(reason, RuntimeWarning, stacklevel=3)

    # ------------------------------------------------------------------ posing
    def set_handles(self, indices) -> None:
        """Handle vertices: a 1-D array of unique vertex ids. Factorises the linear system once;
        every later solve() with this set reuses it. An empty set gives the rest pose."""
        a = np.asarray(indices)
        if a.dtype == np.bool_ or not (np.issubdtype(a.dtype, np.integer) or a.size == 0):
            raise TypeError(f"handle indices must be integers, got dtype {a.dtype}")
        if a.ndim != 1:
            raise ValueError(f"handle indices must be a 1-D array, shape is {a.shape}")
        self._core.set_handles(np.ascontiguousarray(a, dtype=np.int64))
        self._handles_set = True
        self._warn_fallback()

    def set_handle_groups(self, groups, weights=None, vertex_weights=None) -> None:
        """Handle groups, each moved by one transform at solve time (a vertex group driven by an
        Empty or a bone). `groups`: a list of 1-D arrays of vertex ids, disjoint (a vertex in two
        groups is a ValueError naming it and both groups). `weights`: one pull strength per group
        (default 1: every group pulls the same whatever its size). `vertex_weights`: optional list
        of per-vertex weights inside each group (same lengths; e.g. Blender's vertex-group
        weights, a soft falloff at a group's edge; 0 = not a handle). Prefactorises like
        set_handles; handles lists the vertices group by group."""
        try:
            parts = [np.asarray(g) for g in groups]
        except TypeError:
            raise TypeError(f"groups must be a list of 1-D integer arrays, got {type(groups).__name__}") from None
        for g, a in enumerate(parts):
            if a.ndim != 1:
                raise ValueError(f"groups[{g}] must be a 1-D array of vertex ids, shape is {a.shape}")
            if a.size and (a.dtype == np.bool_ or not np.issubdtype(a.dtype, np.integer)):
                raise TypeError(f"groups[{g}] must hold integer vertex ids, got dtype {a.dtype}")
        sizes = np.array([a.size for a in parts], dtype=np.int64)
        offsets = np.concatenate([[0], np.cumsum(sizes)]).astype(np.int64)
        ids = np.concatenate(parts).astype(np.int64) if parts else np.zeros(0, np.int64)
        w = np.zeros(0) if weights is None else self._numbers("weights", weights, (len(parts),))
        if vertex_weights is None:
            vw = np.zeros(0)
        else:
            vw_parts = list(vertex_weights)
            if len(vw_parts) != len(parts):
                raise ValueError(f"vertex_weights has {len(vw_parts)} arrays for {len(parts)} groups")
            vw = np.concatenate([self._numbers(f"vertex_weights[{g}]", a, (parts[g].size,))
                                 for g, a in enumerate(vw_parts)] or [np.zeros(0)])
        self._core.set_handle_groups(ids, offsets, w, vw)
        self._handles_set = True
        self._warn_fallback()

    @staticmethod
    def _numbers(name, values, shape) -> np.ndarray:
        a = np.asarray(values)
        if a.dtype == object or a.dtype == np.bool_ or not np.issubdtype(a.dtype, np.number) \
                or np.issubdtype(a.dtype, np.complexfloating):
            raise TypeError(f"{name} must hold real numbers, got dtype {a.dtype}")
        if a.shape != shape:
            raise ValueError(f"{name} should have shape {shape}, shape is {a.shape}")
        return np.ascontiguousarray(a, dtype=np.float64)

    @property
    def num_groups(self) -> int:
        """Handle groups (set_handles makes one per vertex)."""
        return self._core.num_groups

    def solve(self, targets=None, iterations: int = 5, *, transforms=None, out=None, tol=None) -> np.ndarray:
        """Deformed vertices (n, 3) for the handles' targets: `targets` (len(handles), 3), one per
        handle vertex in the order of handles, or `transforms` (num_groups, 4, 4), one affine map
        per group in the mesh's coordinates (each group's targets are its rest positions mapped
        by its transform; a pose then costs nothing per handle vertex). Warm-starts from the
        previous pose; `iterations` flip-flop steps (3-8 for interaction, more for a converged
        result). `out`: optional C-contiguous (n, 3) float32 or float64 array written in place
        and returned (float32 suits Blender's foreach_set). `tol`: iterate until an iteration
        lowers the energy by less than tol * energy, at most `iterations` times
        (stats["iterations"] says how many ran); for converged final poses."""
        T, iterations, tol, maps = self._solve_args("solve", targets, transforms, iterations, tol)
        if out is not None:
            if not isinstance(out, np.ndarray) or out.dtype not in (np.float32, np.float64):
                raise TypeError("out must be a float32 or float64 numpy array")
            if out.shape != (self._n, 3):
                raise ValueError(f"out should have shape ({self._n}, 3), shape is {out.shape}")
            if not out.flags.c_contiguous or not out.flags.writeable:
                raise ValueError("out must be C-contiguous and writeable")
        return self._core.solve(T, iterations, out, tol, maps)

    def pose_lattice(self, targets=None, iterations: int = 5, *, transforms=None, tol=None) -> np.ndarray:
        """The same solve without the transfer to the vertices: poses the lattice only and returns
        its (N, 3) node positions (what a preview draws from, with cell_nodes() and
        trilinear_binding()). The next solve() warm-starts from this pose."""
        T, iterations, tol, maps = self._solve_args("pose_lattice", targets, transforms, iterations, tol)
        return self._core.pose(T, iterations, tol, maps)  # one locked call: the pose it made

    def solve_on_device(self, targets=None, iterations: int = 5, *, transforms=None, tol=None):
        """The same solve, leaving the positions on the GPU (device="cuda" only): returns a
        DeviceArray, (n, 3) float32 in device memory owned by this Deformer and valid until its
        next solve, with __cuda_array_interface__ (cupy.asarray / torch.as_tensor read it without a
        copy). RuntimeError on the CPU backend."""
        T, iterations, tol, maps = self._solve_args("solve_on_device", targets, transforms, iterations, tol)
        return self._core.solve_on_device(T, iterations, tol, maps)

    def _solve_args(self, what, targets, transforms, iterations, tol):
        """(targets (m, 3) or transforms (G, 4, 4) as float64, iterations, tolerance, whether
        they are transforms) of a solve call, converted."""
        if not self._handles_set:
            raise RuntimeError(f"{what}() needs set_handles() or set_handle_groups() first")
        if (targets is None) == (transforms is None):
            raise TypeError(f"{what}() takes targets or transforms (one of the two)")
        iterations = _integer("iterations", iterations)
        tol = 0.0 if tol is None else _real("tol", tol)
        if targets is not None:
            return _points("targets", targets, rows=len(self._core.handles)), iterations, tol, False
        G = self._core.num_groups
        return self._numbers("transforms", transforms, (G, 4, 4)), iterations, tol, True

    def reset(self) -> None:
        """Forget the pose: the next solve starts from the rest lattice."""
        self._core.reset()

    @property
    def weights(self) -> str:
        return self._core.weights

    @weights.setter
    def weights(self, value: str) -> None:
        self._core.weights = str(value)

    @property
    def gamma(self) -> float:
        return self._core.gamma

    @gamma.setter
    def gamma(self, value: float) -> None:
        self._core.gamma = _real("gamma", value)

    # ------------------------------------------------------------------ inspection
    num_vertices = property(lambda self: self._core.num_vertices, doc="number of mesh vertices")
    num_nodes = property(lambda self: self._core.num_nodes, doc="number of lattice nodes")
    num_cells = property(lambda self: self._core.num_cells, doc="number of lattice cells")
    num_components = property(lambda self: self._core.num_components, doc="connected lattice parts")
    cell_size = property(lambda self: self._core.cell_size, doc="lattice cell edge length")
    device = property(lambda self: self._core.device, doc='"cpu" or "cuda": the backend that runs')
    handles = property(lambda self: self._core.handles, doc="handle vertex ids (1-D int64)")
    diagonal = property(lambda self: self._core.diagonal, doc="bounding-box diagonal of the mesh")
    levels = property(lambda self: self._core.levels, doc="lattice levels built (coarse to fine)")
    junction_brace = property(lambda self: self._core.junction_brace,
                              doc="weight of the braces where the solid branches (0: none)")

    @property
    def stats(self) -> dict:
        """Last solve: "energy" (list, one per iteration, non-increasing), "iterations",
        milliseconds "ms_rotations", "ms_rhs", "ms_solve", "ms_transfer", "ms_total"; and
        "ms_factorize" (last set_handles), "ms_lattice", "ms_binding" (construction)."""
        return self._core.stats

    def lattice_rest(self) -> np.ndarray:
        """(N, 3) rest positions of the lattice nodes."""
        return self._core.lattice_rest()

    def lattice_deformed(self) -> np.ndarray:
        """(N, 3) lattice node positions of the current pose."""
        return self._core.lattice_deformed()

    def lattice_state(self) -> list:
        """The lattice pose of every level (the fine lattice first, then the coarser levels of the
        hierarchy), as (N_l, 3) arrays: what :meth:`set_lattice_state` puts back."""
        return self._core.lattice_state()

    def set_lattice_state(self, state) -> None:
        """Put back a :meth:`lattice_state`: the next solve warm-starts from it (where
        :meth:`reset` would start from rest). A cancelled drag uses it. ValueError (nothing
        changed) unless ``state`` has one finite (N_l, 3) array per level of this Deformer."""
        self._core.set_lattice_state([np.asarray(a, dtype=np.float64) for a in state])

    def cell_nodes(self) -> np.ndarray:
        """(C, 8) int32 corner node ids of every lattice cell; corner c = (c & 1, c >> 1 & 1, c >> 2)."""
        return self._core.cell_nodes()

    def trilinear_binding(self) -> tuple[np.ndarray, np.ndarray]:
        """The trilinear binding as arrays, for drawing the pose on the GPU: per vertex its cell
        (n,) int32 and its position in that cell (n, 3) float32 in [0, 1]^3. A vertex moves by
        the trilinear blend of its cell's corner displacements (cell_nodes)."""
        return self._core.trilinear_binding()

    def lattice_edges(self) -> np.ndarray:
        """(E, 2) node index pairs of the lattice edges (the ARAP neighbourhood)."""
        return self._core.lattice_edges()

    def lattice_edge_weights(self) -> np.ndarray:
        """(E,) weight w_ij of each lattice edge in the global step's Laplacian (2 g w_ij): half
        the sum of cell_weights over the cells (copies) it is an edge of, since the energy sums
        each cell's 12 edges with the cell's own rotation (2 inside a plain lattice)."""
        return self._core.lattice_edge_weights()

    def junction_braces(self) -> np.ndarray:
        """(K, 3) lattice node ids (a, b, c) of the braced columns: where the solid branches inside a
        cell, each corner column of the cell that holds every branch's root, through three
        consecutive nodes (one cell on the trunk's side, the cell's near and its far face; a < c,
        so either end may be the trunk's); the brace keeps a - 2 b + c at zero. Empty when junction_brace is 0 or nothing branches."""
        return self._core.junction_braces()

    def cell_weights(self) -> np.ndarray:
        """(C,) stiffness of each lattice cell (order of cell_nodes): 1 for a cell kept whole; a
        copy of a split cell weighs its piece's share of the cell's material (at least
        1 / split_resolution, one layer of voxels)."""
        return self._core.cell_weights()

    def __repr__(self) -> str:
        return (f"<larap.Deformer {self.num_vertices} vertices, {self.num_nodes} nodes, "
                f"{self.num_cells} cells of {self.cell_size:.4g}, {self.weights}, {self.device}>")
