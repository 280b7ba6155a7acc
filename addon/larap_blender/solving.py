# SPDX-License-Identifier: GPL-3.0-or-later
"""One solve: from the handle targets, through the engine, to the pose key.

At each pose: :func:`targets.gather` gives the handle groups and one transform per group; the
runtime gives the engine only what changed (groups, weights, gamma); the engine solves into the
runtime's float32 buffer ``rt.out``; :func:`mesh_data.write_pose` copies it into the pose key
with one ``foreach_set``. :func:`current_pose` is the pose Bake and Apply use.

One pose per set of targets: a final solve forgets the engine's warm start first
(``Deformer.reset``) and iterates to convergence, so the pose it writes depends only on the
targets and the settings, never on the drag or live history (the engine is deterministic). It
records what it was solved from in the object (:func:`pose_signature`, stored in the object's ID
property ``POSE_SIGNATURE_PROP``, which travels with undo steps and the .blend): Bake, Apply, undo,
reload and Live compare it with the current targets to know whether the pose key is up to date.
The signature has two parts: the targets and settings (cheap to read anywhere), and the content
of the handle groups (their vertices and weights, ``rt.membership_hash``), which only a runtime
that read the vertex groups knows. Bake and Apply read them afresh (:func:`current_pose`), so a
weight painted after the pose makes them solve again; handlers with no runtime, or one whose
groups are not read yet, compare the first part only.

An interactive solve with ``lattice_only`` poses only the lattice (``Deformer.pose_lattice``) for
the GPU preview (preview.py); the mesh is written later by the catch-up (catchup.py).
"""
import hashlib
import time

import numpy as np

from . import key_edits, preview
from .errors import check_object, engine_errors
from .mesh_data import key_positions, write_pose
from .props import id_string, set_id_string, upgrade_settings
from .runtime import ensure_runtime, resolve_device, runtime
from .targets import gather, membership, target_signature

FINAL_TOLERANCE = 1e-5  # relative energy decrease at which a final solve stops
POSE_SIGNATURE_PROP = "_larap_pose"  # ID property: pose_signature() of the targets the pose key holds
INTERACTIVE = "interactive"  # ... or this: the pose key holds an interactive (unconverged) pose


def pose_signature(obj):
    """A digest of everything a final pose depends on besides the rest shape: the target matrices
    (and the object's), the handles, the final weights, gamma, the iterations, the lattice
    settings and the device, then "/" and the handle groups' content (vertices and weights) as
    the object's runtime last read it ("" when it has not: no runtime, or its groups are to be
    read again). Equal signatures give bit-identical final poses."""
    s = obj.larap
    h = hashlib.blake2b(digest_size=16)
    h.update(repr(target_signature(obj)).encode())
    h.update(repr([(x.vertex_group, x.enabled, x.has_rest, x.subtarget, tuple(x.rest_matrix), float(x.weight))
                   for x in s.handles]).encode())
    h.update(repr((s.weights_final, upgrade_settings(s), int(s.iterations), s.resolution_mode, int(s.cells),
                   float(s.cell_size), bool(s.split_cells), s.bind_topology, s.shape_key,
                   resolve_device(s))).encode())
    rt = runtime(obj)
    groups = rt.membership_hash if rt is not None and rt.membership_sig is not None else ""
    return h.hexdigest() + "/" + groups


def stored_signature(obj):
    """The pose_signature() the pose key was last solved for with the final weights ("" unknown)."""
    return id_string(obj, POSE_SIGNATURE_PROP)


def set_stored_signature(obj, value):
    set_id_string(obj, POSE_SIGNATURE_PROP, value)


def key_up_to_date(obj):
    """The pose key holds the converged final pose of the current targets (and of the handle
    groups' content, where the runtime has read it: see pose_signature)."""
    stored = stored_signature(obj)
    if not stored:
        return False
    head, _, groups = pose_signature(obj).partition("/")
    stored_head, _, stored_groups = stored.partition("/")
    return stored_head == head and (not groups or stored_groups == groups)


class SolveResult:
    def __init__(self, ms, engine_ms, warnings, weights, handles, kept=None):
        self.ms = ms
        self.kept = kept  # the name of the key that now holds hand edits of the pose key, or None
        self.engine_ms = engine_ms
        self.warnings = warnings
        self.weights = weights
        self.handles = handles


def _weights_name(s, which):
    if which in ("trilinear", "bspline"):
        return which
    return s.weights_final if which == "final" else s.weights_interactive


def solve(obj, *, weights="final", validate="full", overrides=None, write=True, lattice_only=False, tol=None,
          max_iterations=None, from_rest=True, posed=None, rest=None):
    """One solve from the current target transforms; writes the pose key. Returns SolveResult.

    ``weights``: "final", "interactive" or a weights name; ``validate``: see ensure_runtime;
    ``overrides``: {(target name, bone): world matrix} (a drag in progress); ``lattice_only``
    (interactive): pose the lattice only, into ``rt.lattice_nodes``, and write nothing (the
    preview draws it; the pose key is then behind: ``rt.needs_catchup``).

    A final solve starts from rest (reset; ``from_rest=False``: from the engine's last pose, for
    a farm chunk's later frames), converges until the energy changes by less than ``tol``
    (default FINAL_TOLERANCE) relative in at most ``max_iterations`` flip-flops (default
    max(30, 10 x the object's iterations)), writes the pose key, records pose_signature() in the
    object, and ends the object's preview (the mesh now holds the pose).

    ``posed``: the positions of the pose key LARAP owns (``key_edits.pose_key``) when the caller
    has just read them, nothing written to it since: the check for hand edits before the write
    (``key_edits.keep``) does not read the key again. ``rest``: likewise the rest positions
    (``mesh_data.rest_positions``), nothing written to the rest shape since: when that check finds
    hand edits, it tells whether the Basis changed too from these, not reading it again. A full
    validation has just read them itself (``rt.rest``), which then serve when none are given."""
    check_object(obj, need_bound=True)
    s = obj.larap
    t0 = time.perf_counter()
    rt = ensure_runtime(obj, validate)
    d = rt.deformer
    # A full validation has just read the rest shape (rt.rest): reading the vertex groups reuses it.
    pose = gather(obj, rt, overrides, rt.rest if validate == "full" else None)
    warnings = pose.warnings
    wname = _weights_name(s, weights)
    final = weights == "final"
    lattice_only = lattice_only and not final and pose.count > 0
    engine_ms = 0.0
    kept = None
    # Until this solve succeeds the engine's lattice is not the shown pose's (the overlay says so,
    # and a drag's cancel does not put back what a failed solve left).
    rt.lattice_current = False
    rt.lattice_nodes = None
    with engine_errors("Solve failed"):
        if pose.count == 0:
            warnings.append("no usable handles: rest pose written")
            np.copyto(rt.out, rt.rest)
            d.reset()  # the engine's lattice is the rest pose written
        else:
            rt.set_engine_state(pose, wname, upgrade_settings(s))
            if final:
                # One pose per set of targets: from rest, to convergence (up to 10x the
                # interactive iterations), so the same targets always give the same pose.
                if from_rest:
                    d.reset()
                cap = max(30, 10 * int(s.iterations)) if max_iterations is None else int(max_iterations)
                d.solve(transforms=pose.transforms, iterations=cap, out=rt.out,
                        tol=FINAL_TOLERANCE if tol is None else float(tol))
                rt.lattice_nodes = None
            elif lattice_only:
                rt.lattice_nodes = np.asarray(d.pose_lattice(transforms=pose.transforms, iterations=int(s.iterations)),
                                              dtype=np.float32)
            else:
                d.solve(transforms=pose.transforms, iterations=int(s.iterations), out=rt.out)
                rt.lattice_nodes = None
            stats = dict(d.stats)
            rt.stats = stats
            engine_ms = float(stats.get("ms_total", 0.0))
    rt.engine_calls += 1
    rt.weights = wname
    rt.lattice_current = True
    if lattice_only:
        rt.needs_catchup = True
    elif write:
        if rest is None and validate == "full":
            rest = rt.rest  # nothing has written the rest shape since (the groups mix temporary keys)
        kept = key_edits.keep(obj, co=posed, rest=rest)
        if kept:
            warnings.insert(0, key_edits.describe(kept))
            rt.kept_edits = kept
        write_pose(obj, rt.out)
        key_edits.record(obj, rt.out, rt.rest_hash)
        rt.needs_catchup = not final
        # An interactive pose is recorded as such: a final pose of no targets (catch up on reload).
        set_stored_signature(obj, pose_signature(obj) if final and from_rest and not overrides else INTERACTIVE)
        preview.stop(obj)  # the mesh holds the pose now: Blender draws it again
    rt.pose_version += 1
    rt.last_ms = (time.perf_counter() - t0) * 1e3
    rt.last_error = ""
    rt.warnings = warnings
    rt.target_sig = target_signature(obj) if not overrides else None
    return SolveResult(rt.last_ms, engine_ms, warnings, wname, pose.count, kept)


def current_pose(obj, posed=None, rest=None):
    """The pose to bake/apply: the pose key as it is when it holds the final pose of the current
    targets (key_up_to_date: what the artist sees once the moves pause), else the final solve of
    the current targets, written first (the catch-up), so Bake and Apply change nothing visible.
    Returns (n,3) float32: the pose key as read (``posed`` itself, given one), or a copy of the solve.

    ``posed``: the pose key's positions (``mesh_data.key_positions`` of ``shape_key``) when the
    caller has just read them, nothing written to it since (Bake and Apply: their snapshot's):
    neither this nor the solve's check for hand edits reads the key again. ``rest``: likewise the
    rest positions (``mesh_data.rest_positions``), nothing written to the rest shape since: the
    full validation takes them (``ensure_runtime(rest=)``), and they are ``rt.rest`` afterwards:
    the rest shape as it still is when this returns (the catch-up writes the pose key, and may add
    a copy of hand edits; a Basis it adds to a mesh left without keys is a copy of the mesh)."""
    check_object(obj, need_bound=True)
    s = obj.larap
    rt = ensure_runtime(obj, "full", rest=rest)
    membership(obj, rt, rt.rest)  # the handle groups as they are now (a weight painted since the pose)
    if posed is None:
        posed = key_positions(obj, s.shape_key)
    if posed is not None and not rt.needs_catchup and key_up_to_date(obj):
        return posed
    # Nothing has written the key since it was read: the solve's check for hand edits, of the key
    # LARAP owns, takes these positions when that key is the one read (the name it is posed into).
    owned = key_edits.pose_key(obj)
    read = posed if owned is not None and owned.name == s.shape_key else None
    # Nor has anything written the rest shape since the full validation read it (rt.rest): the
    # check's look at the Basis, when it finds hand edits, takes it too.
    solve(obj, weights="final", validate="fast", posed=read, rest=rt.rest)
    return runtime(obj).out.copy()
