"""Chunk manifests: the record that a chunk finished, and the check that its files are intact.

A chunk writes ``chunks/<object>.<start>-<end>.pc2`` for each object, then
``chunks/chunk.<start>-<end>.json`` (atomically, last): the manifest names each file with its
size, SHA-256 and bind-state fingerprint, and the bake's signature (plan.BakeJob.signature: the
.blend's path and content hash, and the settings). No manifest: the chunk did not
finish. A file whose size or checksum differs from its manifest is corrupt, and a manifest whose
signature differs is a left-over of another bake: :func:`verify_chunk` says which.
"""
from __future__ import annotations

import hashlib
import json
import os
import re

from .pc2 import PC2Error, read_pc2, read_pc2_header, write_atomic

FORMAT = "larap-farm-chunk"
VERSION = 1
CHUNK_DIR = "chunks"


class ChunkError(ValueError):
    """A chunk that is missing, incomplete, corrupt or from another bake."""


def object_stem(name: str) -> str:
    """A file-name-safe, collision-free stem for an object name."""
    safe = re.sub(r"[^A-Za-z0-9_.-]", "_", name).strip(".") or "object"
    if safe != name:
        safe += "-" + hashlib.sha1(name.encode("utf-8")).hexdigest()[:8]
    return safe


def chunk_dir(out_dir: str) -> str:
    return os.path.join(out_dir, CHUNK_DIR)


def chunk_pc2_path(out_dir: str, obj: str, chunk) -> str:
    return os.path.join(chunk_dir(out_dir), f"{object_stem(obj)}.{chunk.name}.pc2")


def manifest_path(out_dir: str, chunk) -> str:
    return os.path.join(chunk_dir(out_dir), f"chunk.{chunk.name}.json")


def sha256(path: str) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def write_manifest(out_dir: str, chunk, signature: dict, objects: dict, timing: dict, binds=None) -> str:
    """Record a finished chunk. ``objects``: name -> vertex count (its PC2 already written);
    ``binds``: name -> the object's bind-state fingerprint in this chunk (_blender.bind_state)."""
    entries = {}
    for name, points in objects.items():
        path = chunk_pc2_path(out_dir, name, chunk)
        entries[name] = {"file": os.path.basename(path), "points": int(points),
                         "bytes": os.path.getsize(path), "sha256": sha256(path),
                         "bind": (binds or {}).get(name)}
    doc = {"format": FORMAT, "version": VERSION, "chunk": [chunk.start, chunk.end],
           "solve_start": chunk.solve_start, "signature": signature, "objects": entries, "timing": timing}
    path = manifest_path(out_dir, chunk)
    write_atomic(path, [json.dumps(doc, indent=1, sort_keys=True).encode("utf-8")])
    return path


def read_manifest(out_dir: str, chunk) -> dict:
    path = manifest_path(out_dir, chunk)
    try:
        with open(path, "rb") as f:
            doc = json.loads(f.read().decode("utf-8"))
    except FileNotFoundError:
        raise ChunkError(f"chunk {chunk}: not finished (no {os.path.basename(path)})") from None
    except (ValueError, UnicodeDecodeError) as exc:
        raise ChunkError(f"chunk {chunk}: unreadable manifest {os.path.basename(path)}: {exc}") from None
    if not isinstance(doc, dict) or doc.get("format") != FORMAT or doc.get("version") != VERSION:
        raise ChunkError(f"chunk {chunk}: {os.path.basename(path)} is not a version-{VERSION} chunk manifest")
    return doc


def verify_chunk(out_dir: str, chunk, signature: dict, load=False) -> dict:
    """Check a finished chunk against the bake's signature and its files against the manifest.
    Reads each file once for its checksum and its header, not its positions; with ``load``, each
    object entry also gets "positions" (frames, points, 3), checked finite.
    Raises ChunkError naming the chunk and what is wrong."""
    doc = read_manifest(out_dir, chunk)
    if doc.get("chunk") != [chunk.start, chunk.end] or doc.get("solve_start") != chunk.solve_start:
        raise ChunkError(f"chunk {chunk}: manifest describes frames {doc.get('chunk')} solved from "
                         f"{doc.get('solve_start')}, the plan {chunk.start}-{chunk.end} from {chunk.solve_start}")
    if doc.get("signature") != signature:
        diff = sorted(k for k in set(signature) | set(doc.get("signature") or {})
                      if (doc.get("signature") or {}).get(k) != signature.get(k))
        if any(k in diff for k in ("blend", "blend_sha256")):
            raise ChunkError(f"chunk {chunk}: baked from another .blend or another version of it "
                             f"({', '.join(diff)} differ{'s' if len(diff) == 1 else ''}: the file changed since)")
        raise ChunkError(f"chunk {chunk}: left over from another bake (settings differ: {', '.join(diff)})")
    objects = doc.get("objects") or {}
    for name in signature.get("objects", []):
        entry = objects.get(name)
        if entry is None:
            raise ChunkError(f"chunk {chunk}: object {name!r} missing from its manifest")
        path = os.path.join(chunk_dir(out_dir), entry["file"])
        if not os.path.exists(path):
            raise ChunkError(f"chunk {chunk}: {entry['file']} is missing")
        size = os.path.getsize(path)
        if size != entry["bytes"]:
            raise ChunkError(f"chunk {chunk}: {entry['file']} is {size} bytes, {entry['bytes']} when written "
                             f"(truncated or overwritten)")
        if sha256(path) != entry["sha256"]:
            raise ChunkError(f"chunk {chunk}: {entry['file']} is corrupt (checksum differs from its manifest)")
        try:
            head = read_pc2_header(path)  # a few bytes: the positions are read only with ``load``
            if load:
                head, entry["positions"] = read_pc2(path)
        except PC2Error as exc:
            raise ChunkError(f"chunk {chunk}: {exc}") from None
        if head["samples"] != chunk.frames or int(head["start"]) != chunk.start or head["points"] != entry["points"]:
            raise ChunkError(f"chunk {chunk}: {entry['file']} holds {head['samples']} frames from "
                             f"{head['start']:g} of {head['points']} points, not frames {chunk} of "
                             f"{entry['points']} points")
    return doc
