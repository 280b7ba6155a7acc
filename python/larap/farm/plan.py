"""Frame chunks of a bake, and the settings every chunk of one bake shares.

A chunk bakes frames ``start..end`` (inclusive). Its first solved frame starts from rest: either
``start`` itself, or ``solve_start = max(job start, start - preroll)`` whose pre-roll frames are
solved (warm-starting the ones after) and discarded. The first chunk never has a pre-roll, so a
bake in one chunk is exactly the one-process bake.
"""
from __future__ import annotations

import dataclasses
import os
import re

from .manifest import sha256

MODES = ("warm", "rest")  # warm: later frames warm-start within the chunk; rest: every frame from rest


@dataclasses.dataclass(frozen=True)
class Chunk:
    start: int
    end: int
    solve_start: int  # first frame solved (from rest); < start with a pre-roll

    @property
    def frames(self) -> int:
        return self.end - self.start + 1

    @property
    def name(self) -> str:
        """Stable file-name part: ``000011-000020``."""
        return f"{self.start:06d}-{self.end:06d}"

    def __str__(self) -> str:
        return f"{self.start}-{self.end}"


def parse_frames(text) -> tuple[int, int]:
    """``"1-100"`` or ``"47"`` -> (first, last); a clear ValueError for anything else."""
    m = re.fullmatch(r"\s*(-?\d+)\s*(?:(?:-|\.\.)\s*(-?\d+)\s*)?", str(text))
    if not m:
        raise ValueError(f"frames must look like '1-100' or '47', got {text!r}")
    first = int(m.group(1))
    last = int(m.group(2)) if m.group(2) is not None else first
    if last < first:
        raise ValueError(f"frame range {text!r} is empty (last frame before the first)")
    if max(abs(first), abs(last)) > MAX_FRAME:
        raise ValueError(f"frame range {text!r} goes beyond Blender's frames (-{MAX_FRAME} to {MAX_FRAME})")
    return first, last


MAX_FRAME = 1048574  # Blender's frames lie in [-MAX_FRAME, MAX_FRAME] (MAXFRAME in DNA_scene_types.h)


def _int(name, value, minimum, maximum=None):
    if isinstance(value, bool) or not isinstance(value, int):
        raise TypeError(f"{name} must be an integer, got {value!r}")
    if value < minimum:
        raise ValueError(f"{name} must be at least {minimum}, got {value}")
    if maximum is not None and value > maximum:
        raise ValueError(f"{name} must be at most {maximum}, got {value}")
    return value


def plan_chunks(frame_start: int, frame_end: int, chunk_size: int, preroll: int = 0) -> list[Chunk]:
    """Consecutive chunks of at most ``chunk_size`` frames covering frame_start..frame_end."""
    frame_start = _int("frame_start", frame_start, -MAX_FRAME, MAX_FRAME)
    frame_end = _int("frame_end", frame_end, -MAX_FRAME, MAX_FRAME)
    if frame_end < frame_start:
        raise ValueError(f"frame range {frame_start}-{frame_end} is empty")
    chunk_size = _int("chunk_size", chunk_size, 1)
    preroll = _int("preroll", preroll, 0)
    chunks = []
    for s in range(frame_start, frame_end + 1, chunk_size):
        e = min(s + chunk_size - 1, frame_end)
        chunks.append(Chunk(s, e, max(frame_start, s - preroll)))
    return chunks


@dataclasses.dataclass
class BakeJob:
    """Everything a bake needs. ``objects``: names of bound meshes in ``blend``.
    ``tol``: relative energy decrease at which a from-rest solve stops (a chunk's first solved
    frame; every frame in "rest" mode), after at most ``max_iterations``. ``warm_tol``: the same
    for warm-started frames (default 1e-7: with the default pre-roll of 3, a chunked bake is then
    within ~3e-8 of the bounding-box diagonal of a one-process bake, docs/farm.md); None keeps
    the add-on's own final solve (core.FINAL_TOLERANCE 1e-5, at most 10x the object's
    iterations), as its one-machine bake does, up to ~1e-4 of the diagonal from a one-process
    bake. ``preroll``: frames solved before each chunk and discarded, so that the warm start at
    the chunk's first frame is the one a single process would have had.
    ``device``: "" keeps each object's own setting."""
    blend: str
    objects: list
    frame_start: int
    frame_end: int
    out_dir: str
    chunk_size: int = 25
    preroll: int = 3
    mode: str = "warm"
    tol: float = 1e-10
    warm_tol: float = 1e-7
    max_iterations: int = 1000
    device: str = ""
    _blend_sha256: str = dataclasses.field(default=None, init=False, repr=False, compare=False)

    def __post_init__(self):
        if not self.objects:
            raise ValueError("a bake needs at least one object")
        if self.mode not in MODES:
            raise ValueError(f"mode must be one of {MODES}, got {self.mode!r}")
        for name in ("tol", "warm_tol"):
            v = getattr(self, name)
            if not (v is None and name == "warm_tol") and not (
                    isinstance(v, (int, float)) and not isinstance(v, bool) and 0.0 < float(v) < 1.0):
                raise ValueError(f"{name} must be a number in (0, 1), got {v!r}")
        _int("max_iterations", self.max_iterations, 1)
        if self.device not in ("", "cpu", "cuda", "auto"):
            raise ValueError(f"device must be '', 'cpu', 'cuda' or 'auto', got {self.device!r}")
        self.chunks()  # validates the frame range, chunk size and pre-roll

    def chunks(self) -> list[Chunk]:
        return plan_chunks(self.frame_start, self.frame_end, self.chunk_size,
                           self.preroll if self.mode == "warm" else 0)

    def settings(self) -> dict:
        """The solver settings every chunk of this bake shares (part of :meth:`signature`)."""
        return {"frames": [self.frame_start, self.frame_end], "preroll": self.preroll if self.mode == "warm" else 0,
                "mode": self.mode, "tol": float(self.tol), "max_iterations": self.max_iterations,
                "warm_tol": None if self.warm_tol is None else float(self.warm_tol), "device": self.device,
                "objects": list(self.objects)}

    def blend_sha256(self) -> str:
        """SHA-256 of the .blend's content, read once per BakeJob (the first call); OSError naming
        the file when it cannot be read."""
        if self._blend_sha256 is None:
            self._blend_sha256 = file_sha256(self.blend)
        return self._blend_sha256

    def signature(self) -> dict:
        """What every chunk of this bake must share (checked by the merge and by ``--resume``): the
        shot (the .blend's absolute path and the SHA-256 of its content, so a chunk baked before
        the artist changed the file is never merged) and the settings. A chunk left over from
        another bake, or from another version of the shot, is never merged."""
        return {"blend": os.path.abspath(self.blend), "blend_sha256": self.blend_sha256(), **self.settings()}


def file_sha256(path: str) -> str:
    try:
        return sha256(path)
    except OSError as exc:
        raise OSError(f"cannot read the bake's .blend {path!r} to identify the shot: {exc.strerror or exc}") from None
