"""Merge a bake's chunks into one PC2 cache per object, or say exactly what is missing.

Every planned chunk is verified (plan.BakeJob.signature, sizes, checksums, headers, one vertex
count and bind state per object: manifest.verify_chunk) before anything is written, without
loading the positions; then each object's chunks are streamed (one chunk in memory at a time) into
a temporary file, and all merged files are renamed into place at the end (:func:`merge_bake` says
exactly what is not atomic). A bake with a missing, corrupt or foreign chunk raises MergeError
naming the chunks and the frames, and leaves any earlier merged cache untouched.
"""
from __future__ import annotations

import hashlib
import json
import os

import numpy as np

from .manifest import ChunkError, chunk_dir, object_stem, verify_chunk
from .pc2 import HEADER, SIGNATURE, temp_name

SUMMARY = "bake.json"


class MergeError(RuntimeError):
    """Chunks missing, corrupt or from another bake. ``.problems``: [(chunk, message)];
    ``.missing_frames``: the frames not available, ascending."""

    def __init__(self, message, problems, missing_frames):
        super().__init__(message)
        self.problems = problems
        self.missing_frames = missing_frames


def frame_ranges(frames) -> str:
    """[1, 2, 3, 7, 9, 10] -> '1-3, 7, 9-10'."""
    frames = sorted(frames)
    parts, i = [], 0
    while i < len(frames):
        j = i
        while j + 1 < len(frames) and frames[j + 1] == frames[j] + 1:
            j += 1
        parts.append(str(frames[i]) if i == j else f"{frames[i]}-{frames[j]}")
        i = j + 1
    return ", ".join(parts)


def merged_path(out_dir: str, obj: str) -> str:
    return os.path.join(out_dir, object_stem(obj) + ".pc2")


def check_chunks(job, load=False):
    """(manifests by chunk, problems [(chunk, message)])."""
    good, problems = {}, []
    signature = job.signature()  # OSError when the .blend cannot be read: nothing to compare with
    for chunk in job.chunks():
        try:
            good[chunk] = verify_chunk(job.out_dir, chunk, signature, load=load)
        except (ChunkError, OSError) as exc:
            problems.append((chunk, str(exc)))
    return good, problems


def _refuse_inconsistent(job, good):
    """Every object must have one vertex count and one bind state across all chunks."""
    for name in job.objects:
        for key, what, hint in (("points", "different vertex counts", "was the file changed during the bake?"),
                                ("bind", "was bound differently", "do all farm machines run the same LARAP "
                                 "add-on? Re-run the odd chunks")):
            seen = {}
            for chunk, doc in good.items():
                seen.setdefault(doc["objects"][name].get(key), []).append(str(chunk))
            if len(seen) != 1:
                groups = "; ".join(f"chunks {', '.join(c)}" + (f": {v}" if key == "points" else "")
                                   for v, c in seen.items())
                verb = "has" if key == "points" else ""
                raise MergeError(f"merge refused: object {name!r} {verb + ' ' if verb else ''}{what} in different "
                                 f"chunks ({groups}); {hint}", [], [])


def _read_chunk(path, entry):
    """One chunk file's positions (samples, points, 3) float32, read once: its bytes must still
    be the ones the manifest names (SHA-256) and all positions finite; ChunkError otherwise."""
    with open(path, "rb") as f:
        raw = f.read()
    if hashlib.sha256(raw).hexdigest() != entry["sha256"]:
        raise ChunkError(f"{entry['file']} changed while merging (checksum differs from its manifest)")
    P = np.frombuffer(raw, dtype="<f4", offset=HEADER.size).reshape(-1, entry["points"], 3)
    bad = ~np.isfinite(P)
    if bad.any():
        raise ChunkError(f"{entry['file']}: sample {int(np.argwhere(bad)[0][0])} holds non-finite positions")
    return P


def merge_bake(job) -> dict:
    """Write ``<out>/<object>.pc2`` for every object of ``job`` (plan.BakeJob) and ``<out>/bake.json``
    (object -> file, frames, points). Returns that summary; MergeError when anything is missing.

    All or nothing as far as the file system allows: every chunk of every object is verified
    (manifest, settings, size, checksum, PC2 header, one vertex count and one bind state per
    object) before anything is written; then each object's chunks are streamed, one chunk in
    memory at a time (re-checked against their checksums and for finite values), into a temporary
    file next to its final name; only when all of them and bake.json are complete and flushed are
    they renamed over the final names, bake.json last. What is not atomic: that sequence of renames
    (one per object, then bake.json). A process killed between two renames, or a rename that fails
    (e.g. the folder turned read-only), leaves some objects' new .pc2 beside the older ones and the
    older bake.json; re-running the merge completes it. Temporary files are removed on any error."""
    good, problems = check_chunks(job)
    if problems:
        missing = sorted(f for chunk, _ in problems for f in range(chunk.start, chunk.end + 1))
        lines = "\n".join(f"  {msg}" for _, msg in problems)
        raise MergeError(f"merge refused: frames {frame_ranges(missing)} of {job.frame_start}-{job.frame_end} "
                         f"are not available ({len(problems)} of {len(job.chunks())} chunks):\n{lines}",
                         problems, missing)
    _refuse_inconsistent(job, good)
    frames = job.frame_end - job.frame_start + 1
    summary = {"frames": [job.frame_start, job.frame_end], "mode": job.mode, "objects": {}}
    temps = []  # (temporary, final), in rename order
    try:
        for name in job.objects:
            points = next(iter(good.values()))["objects"][name]["points"]
            path = merged_path(job.out_dir, name)
            tmp = temp_name(path)
            temps.append((tmp, path))
            with open(tmp, "wb") as f:
                f.write(HEADER.pack(SIGNATURE, 1, points, float(job.frame_start), 1.0, frames))
                for chunk in sorted(good, key=lambda c: c.start):
                    entry = good[chunk]["objects"][name]
                    try:
                        P = _read_chunk(os.path.join(chunk_dir(job.out_dir), entry["file"]), entry)
                    except (ChunkError, OSError) as exc:
                        raise MergeError(f"merge refused: chunk {chunk}: {exc}", [(chunk, str(exc))],
                                         list(range(chunk.start, chunk.end + 1))) from None
                    f.write(P.data)
                    del P  # one chunk in memory at a time
                f.flush()
                os.fsync(f.fileno())
            summary["objects"][name] = {"file": os.path.basename(path), "points": points,
                                        "start": job.frame_start, "samples": frames}
        path = os.path.join(job.out_dir, SUMMARY)
        tmp = temp_name(path)
        temps.append((tmp, path))
        with open(tmp, "wb") as f:
            f.write(json.dumps(summary, indent=1).encode("utf-8"))
            f.flush()
            os.fsync(f.fileno())
        for tmp, path in temps:
            os.replace(tmp, path)
    except BaseException:
        for tmp, _ in temps:
            try:
                os.remove(tmp)
            except OSError:
                pass
        raise
    _fsync_dir(job.out_dir)
    return summary


def _fsync_dir(path):
    """Make the renames durable (POSIX; a no-op where folders cannot be opened)."""
    try:
        fd = os.open(path, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)
