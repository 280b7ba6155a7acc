"""PC2 point caches: read, and write atomically.

Layout (little-endian; the format Blender's Mesh Cache modifier reads): a 32-byte header
``char[12] "POINTCACHE2\\0"``, ``int32 version = 1``, ``int32 points``, ``float32 start frame``,
``float32 sample rate``, ``int32 samples``; then ``samples`` x ``points`` x 3 float32 positions
(object-local coordinates), one frame after another.

Writes go to a unique temporary name in the same folder, are flushed to disk, then renamed over
the final name (atomic on one file system): a killed writer or a duplicated farm task never leaves
half a file under the final name.
"""
from __future__ import annotations

import os
import struct
import uuid

import numpy as np

SIGNATURE = b"POINTCACHE2\0"
HEADER = struct.Struct("<12siiffi")
TEMP_MARK = ".tmp-"  # temporary files: <final name>.tmp-<unique>; never read as results


class PC2Error(ValueError):
    """A file that is not a complete, well-formed PC2 cache (the message says what is wrong)."""


def temp_name(path: str) -> str:
    return f"{path}{TEMP_MARK}{os.getpid()}-{uuid.uuid4().hex[:8]}"


def write_atomic(path: str, chunks) -> None:
    """Write the byte strings ``chunks`` to ``path`` through a temporary file and a rename."""
    tmp = temp_name(path)
    try:
        with open(tmp, "wb") as f:
            for b in chunks:
                f.write(b)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        try:
            os.remove(tmp)
        except OSError:
            pass
        raise


def encode_pc2(positions, start_frame: float, sample_rate: float = 1.0) -> tuple[bytes, bytes]:
    """(header, body) bytes of a PC2 file for ``positions`` (frames, points, 3)."""
    P = np.asarray(positions)
    if P.ndim != 3 or P.shape[2] != 3:
        raise ValueError(f"positions should have shape (frames, points, 3), shape is {P.shape}")
    if P.shape[0] == 0 or P.shape[1] == 0:
        raise ValueError(f"positions is empty: shape {P.shape}")
    body = np.ascontiguousarray(P, dtype="<f4")
    if not np.isfinite(body).all():
        frame = int(np.argwhere(~np.isfinite(body))[0][0])
        raise ValueError(f"positions of sample {frame} are not finite")
    header = HEADER.pack(SIGNATURE, 1, P.shape[1], float(start_frame), float(sample_rate), P.shape[0])
    return header, body.tobytes()


def write_pc2(path: str, positions, start_frame: float, sample_rate: float = 1.0) -> None:
    """Write (frames, points, 3) positions as a PC2 file, atomically."""
    write_atomic(path, encode_pc2(positions, start_frame, sample_rate))


def read_pc2_header(path: str) -> dict:
    """The header as a dict (points, start, rate, samples); PC2Error when the file is not a complete PC2."""
    try:
        size = os.path.getsize(path)
        with open(path, "rb") as f:
            raw = f.read(HEADER.size)
    except FileNotFoundError:
        raise PC2Error(f"{path}: no such file") from None
    if len(raw) < HEADER.size:
        raise PC2Error(f"{path}: truncated header ({len(raw)} of {HEADER.size} bytes)")
    sig, version, points, start, rate, samples = HEADER.unpack(raw)
    if sig != SIGNATURE:
        raise PC2Error(f"{path}: not a PC2 file (signature {sig!r})")
    if version != 1 or points <= 0 or samples <= 0:
        raise PC2Error(f"{path}: bad header (version {version}, {points} points, {samples} samples)")
    expected = HEADER.size + 12 * points * samples
    if size != expected:
        what = "truncated" if size < expected else "has trailing bytes"
        raise PC2Error(f"{path}: {what}: {size} bytes, {expected} expected for {samples} samples of "
                       f"{points} points")
    return {"points": points, "start": start, "rate": rate, "samples": samples}


def read_pc2(path: str) -> tuple[dict, np.ndarray]:
    """(header, positions (samples, points, 3) float32); PC2Error when incomplete or not finite."""
    head = read_pc2_header(path)
    data = np.fromfile(path, dtype="<f4", offset=HEADER.size)
    data = data.reshape(head["samples"], head["points"], 3)
    bad = ~np.isfinite(data)
    if bad.any():
        raise PC2Error(f"{path}: sample {int(np.argwhere(bad)[0][0])} holds non-finite positions")
    return head, data
