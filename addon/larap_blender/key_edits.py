# SPDX-License-Identifier: GPL-3.0-or-later
"""Edits an artist makes to the pose key are never overwritten without a copy.

LARAP rewrites its pose key at every solve. An artist may sculpt on it, edit it in Edit Mode, or
change it with a script or an operator (Mirror Shape Key); the next solve would replace that work.
So every write of the pose key is recorded in the object (ID property ``RECORD_PROP``: a CRC-32 of
the positions written, and the hash of the rest shape they were solved on), and before LARAP
overwrites the key (a solve) or removes it (Unbind), :func:`keep` reads the key: when it no longer
holds what LARAP wrote, its positions are copied into a new shape key "<pose key> edits" (value 0,
relative to the Basis), which LARAP never writes, and the caller says so.

A Basis edit moves the pose key with it (Blender keeps the offsets of keys relative to the Basis),
so a key that differs while the rest shape differs too (its hash against the recorded one) is the
Basis edit's doing, not a hand edit of the pose key: nothing is kept. Edits of both, made before
the next solve, are therefore not told apart (the rest shape change rebinds; the pose is solved
again).

The record travels with the object: undo steps, the .blend, a drag's cancel (session.py) and a
failed Bind, Bake or Apply (transaction.py) restore it with the key. A key with no record (never
written by this version, or just created) is not checked. Cost: one read of the key per write, 45-70
ms at 1M vertices in Blender 3.4.1 on a 2-core machine (an interactive solve with its write took 65
ms without the check and 141 ms with it, 2026-11-24); with the GPU preview, Live writes only once
the moves pause.
"""
import zlib

import numpy as np

from .mesh_data import add_key_copy, array_hash, block_positions, rest_positions

RECORD_PROP = "_larap_key"  # object ID property: "<crc32 of the pose key as written>/<rest hash>"
EDITS_SUFFIX = " edits"


def _crc(co):
    return "%08x" % zlib.crc32(np.ascontiguousarray(co, dtype=np.float32))


def record(obj, co, rest_hash):
    """LARAP wrote ``co`` into the pose key, solved on the rest shape of hash ``rest_hash``."""
    obj[RECORD_PROP] = "%s/%s" % (_crc(co), rest_hash)


def get(obj):
    """The record as stored ("" when none), for a snapshot."""
    try:
        return str(obj.get(RECORD_PROP, ""))
    except (ReferenceError, TypeError):
        return ""


def put(obj, value):
    """Put back a record from :func:`get`."""
    if value:
        obj[RECORD_PROP] = value
    elif RECORD_PROP in obj:
        del obj[RECORD_PROP]


def edited(obj, kb):
    """The pose key ``kb`` holds positions LARAP did not write (and the rest shape is the one they
    were recorded on). None when there is no record to compare with."""
    stored = get(obj)
    if not stored or kb is None:
        return None
    crc, _, rest_hash = stored.partition("/")
    n = len(obj.data.vertices)
    if len(kb.data) != n or _crc(block_positions(kb, n)) == crc:
        return False
    return array_hash(rest_positions(obj)) == rest_hash


def pose_key(obj):
    """The pose key as LARAP owns it, or None."""
    s = obj.larap
    keys = obj.data.shape_keys
    kb = keys.key_blocks.get(s.shape_key) if keys is not None and s.shape_key else None
    if kb is None or kb == keys.reference_key or kb.name != s.owned_key_name:
        return None
    return kb


def keep(obj, kb=None):
    """Before LARAP writes or removes its pose key (``kb``, default :func:`pose_key`): copy hand
    edits (see :func:`edited`) into a new key "<name> edits" at value 0 and return its name (None:
    nothing to keep). The record is dropped, so the same edits are kept once."""
    kb = kb if kb is not None else pose_key(obj)
    if not edited(obj, kb):
        return None
    copy = add_key_copy(obj, kb.name + EDITS_SUFFIX, block_positions(kb, len(obj.data.vertices)))
    put(obj, "")
    return copy.name


def message(pose_key, kept):
    return ("The pose key %r held edits LARAP did not make (sculpt, Edit Mode or a script): they are "
            "kept in the shape key %r (value 0) before LARAP writes its pose; corrections belong on a "
            "key of their own" % (pose_key, kept))
