"""Merge a bake's chunks into one PC2 cache per object, or say exactly what is missing.

Every planned chunk is verified (plan.BakeJob.signature, sizes, checksums, headers, finite values:
manifest.verify_chunk) before anything is written; the merged files are written atomically. A bake
with a missing, corrupt or foreign chunk raises MergeError naming the chunks and the frames, and
leaves any earlier merged cache untouched.
"""
from __future__ import annotations

import json
import os

import numpy as np

from .manifest import ChunkError, object_stem, verify_chunk
from .pc2 import write_atomic, write_pc2

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


def merge_bake(job) -> dict:
    """Write ``<out>/<object>.pc2`` for every object of ``job`` (plan.BakeJob) and ``<out>/bake.json``
    (object -> file, frames, points). Returns that summary; MergeError when anything is missing."""
    good, problems = check_chunks(job, load=True)
    if problems:
        missing = sorted(f for chunk, _ in problems for f in range(chunk.start, chunk.end + 1))
        lines = "\n".join(f"  {msg}" for _, msg in problems)
        raise MergeError(f"merge refused: frames {frame_ranges(missing)} of {job.frame_start}-{job.frame_end} "
                         f"are not available ({len(problems)} of {len(job.chunks())} chunks):\n{lines}",
                         problems, missing)
    for name in job.objects:
        binds = {}
        for chunk, doc in good.items():
            binds.setdefault(doc["objects"][name].get("bind"), []).append(str(chunk))
        if len(binds) != 1:
            groups = "; ".join(f"chunks {', '.join(c)}" for c in binds.values())
            raise MergeError(f"merge refused: object {name!r} was bound differently in different chunks ({groups}); "
                             f"do all farm machines run the same LARAP add-on? Re-run the odd chunks", [], [])
    frames = job.frame_end - job.frame_start + 1
    summary = {"frames": [job.frame_start, job.frame_end], "mode": job.mode, "objects": {}}
    for name in job.objects:
        counts = {doc["objects"][name]["points"] for doc in good.values()}
        if len(counts) != 1:
            raise MergeError(f"merge refused: object {name!r} has different vertex counts in different "
                             f"chunks ({sorted(counts)}); was the file changed during the bake?", [], [])
        points = counts.pop()
        out = np.empty((frames, points, 3), dtype=np.float32)
        for chunk, doc in good.items():
            out[chunk.start - job.frame_start:chunk.end - job.frame_start + 1] = doc["objects"][name]["positions"]
        path = merged_path(job.out_dir, name)
        write_pc2(path, out, job.frame_start)
        summary["objects"][name] = {"file": os.path.basename(path), "points": points,
                                    "start": job.frame_start, "samples": frames}
    write_atomic(os.path.join(job.out_dir, SUMMARY), [json.dumps(summary, indent=1).encode("utf-8")])
    return summary
