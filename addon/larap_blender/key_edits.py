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
so after one the key no longer holds what LARAP wrote either. It is kept all the same (a rounding
of the moved key cannot be told from a hand edit, and the record's rest hash is not fresh after
Live's fast solves), and the message says the Basis changed too. A false copy is cheap; a lost
edit is not.

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
from .props import id_string, set_id_string

RECORD_PROP = "_larap_key"  # object ID property: "<crc32 of the pose key as written>/<rest hash>"
EDITS_SUFFIX = " edits"


def _crc(co):
    return "%08x" % zlib.crc32(np.ascontiguousarray(co, dtype=np.float32))


def record(obj, co, rest_hash):
    """LARAP wrote ``co`` into the pose key, solved on the rest shape of hash ``rest_hash``."""
    obj[RECORD_PROP] = "%s/%s" % (_crc(co), rest_hash)


def get(obj):
    """The record as stored ("" when none), for a snapshot."""
    return id_string(obj, RECORD_PROP)


def put(obj, value):
    """Put back a record from :func:`get` ("" drops it)."""
    set_id_string(obj, RECORD_PROP, value)


def edited(obj, kb, co=None):
    """The pose key ``kb`` holds positions LARAP did not write. None when there is no record to
    compare with. ``co``: its positions when the caller has just read them (not read again)."""
    stored = get(obj)
    if not stored or kb is None:
        return None
    n = len(obj.data.vertices)
    if len(kb.data) != n:
        return False
    return _crc(block_positions(kb, n) if co is None else co) != stored.partition("/")[0]


def _basis_changed(obj, rest=None):
    """The rest shape differs from the one recorded with the last write (as far as the record
    knows: after fast solves it may name an older rest). ``rest``: its positions when the caller
    has just read them (not read again)."""
    rest_hash = get(obj).partition("/")[2]
    return bool(rest_hash) and array_hash(rest_positions(obj) if rest is None else rest) != rest_hash


def pose_key(obj):
    """The pose key LARAP owns (the one it last wrote and Unbind removes), or None."""
    s = obj.larap
    keys = obj.data.shape_keys
    name = s.owned_key_name
    kb = keys.key_blocks.get(name) if keys is not None and name else None
    if kb is None or kb == keys.reference_key:
        return None
    return kb


def keep(obj, kb=None, co=None, rest=None):
    """Before LARAP writes or removes its pose key (``kb``, default :func:`pose_key`): copy hand
    edits (see :func:`edited`) into a new key "<name> edits" at value 0 and return its name (None:
    nothing to keep). The record is dropped, so the same edits are kept once. ``co``: that key's
    positions when the caller has just read them, nothing written to it since (not read again);
    ``rest``: likewise the rest positions (``mesh_data.rest_positions``), for the message's
    "the Basis was edited too"."""
    kb = kb if kb is not None else pose_key(obj)
    n = len(obj.data.vertices)
    if co is None and kb is not None and get(obj) and len(kb.data) == n:
        co = block_positions(kb, n)  # when edited() would read it: read once, for it and the copy
    if not edited(obj, kb, co):
        return None
    basis = _basis_changed(obj, rest)
    copy = add_key_copy(obj, kb.name + EDITS_SUFFIX, co)
    put(obj, "")
    _KEPT.append((kb.name, copy.name, basis))
    del _KEPT[:-20]  # Live's copies are told by the panel; operators take theirs (take_messages)
    return copy.name


_KEPT = []  # (pose key, copy, the Basis changed too) since the last take_messages()


def describe(copy):
    """The message for the copy ``copy`` made by :func:`keep`."""
    for key, name, basis in reversed(_KEPT):
        if name == copy:
            return message(key, name, basis)
    return message("", copy)


def message(pose_key, kept, basis_changed=False):
    why = ("the Basis was edited too, which moves it" if basis_changed
           else "sculpt, Edit Mode or a script")
    return ("The pose key %r held positions LARAP did not write (%s): they are kept in the shape key "
            "%r (value 0: set it to 1 and %r to 0 to see them); corrections belong on a key of their "
            "own" % (pose_key, why, kept, pose_key))


def take_messages():
    """The messages of every copy made since the last call (operators report them)."""
    out = [message(key, copy, basis) for key, copy, basis in _KEPT]
    _KEPT.clear()
    return out
