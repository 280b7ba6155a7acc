"""Meshes, handle groups and poses of the report, shared by every part so that all methods see
the same meshes and the same handle displacements.

A Case holds rest positions V, faces F, handle groups (lists of vertex ids, as an artist paints
vertex groups), and a pose as a sequence of group transforms (G, 4, 4) from rest to the final
pose: every method is driven through the same steps, as an artist drags.
"""
from __future__ import annotations

import os
from dataclasses import dataclass, field

import numpy as np

import larap
from larap import quality, shapes

REPO = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


def meshes_dir() -> str | None:
    """The public test meshes: $LARAP_MESHES, else ../shared/data/meshes beside the checkout."""
    for d in (os.environ.get("LARAP_MESHES"), os.path.join(REPO, "..", "shared", "data", "meshes")):
        if d and os.path.isdir(d):
            return os.path.abspath(d)
    return None


def load(name):
    """(V, F) of a public mesh, or None when the folder or file is absent."""
    d = meshes_dir()
    if d is None or not os.path.exists(os.path.join(d, name)):
        return None
    return larap.load_mesh(os.path.join(d, name))


# ---------------------------------------------------------------- transforms
def rotation(axis, degrees):
    k = np.asarray(axis, float) / np.linalg.norm(axis)
    t = np.radians(degrees)
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + np.sin(t) * K + (1 - np.cos(t)) * K @ K


def affine(R=np.eye(3), t=(0, 0, 0), pivot=(0, 0, 0)):
    """4x4 map x -> R (x - pivot) + pivot + t."""
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = np.asarray(pivot, float) - R @ np.asarray(pivot, float) + np.asarray(t, float)
    return T


# ---------------------------------------------------------------- meshes
def subdivide(V, F, times=1):
    """Midpoint 1-to-4 subdivision of a triangle mesh (the shape stays; faces x4 per step)."""
    V, F = np.asarray(V, float), quality.triangles(F)
    for _ in range(times):
        e = np.sort(np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]]), axis=1)
        uniq, inv = np.unique(e, axis=0, return_inverse=True)
        mid = len(V) + inv.reshape(3, -1).T  # (m, 3): midpoints of edges 01, 12, 20
        V = np.concatenate([V, 0.5 * (V[uniq[:, 0]] + V[uniq[:, 1]])])
        a, b, c = F.T
        ab, bc, ca = mid.T
        F = np.concatenate([np.stack(x, 1) for x in ((a, ab, ca), (ab, b, bc), (ca, bc, c), (ab, bc, ca))])
    return V, F


def torus_with_faces(faces_wanted: int):
    """A torus of about `faces_wanted` triangles (quads counted as two), as scripts/bench.py."""
    quads = faces_wanted // 2
    n_minor = max(8, int(np.sqrt(quads / 3.0)))
    n_major = max(8, quads // n_minor)
    return shapes.torus(1.0, 0.35, n_major, n_minor)


def torus_groups(V):
    """Three sectors of the torus, each the whole rings nearest its angle holding at least 2.1%
    of the vertices (6% or more together): held, lifted and turned, nudged."""
    ang = np.arctan2(V[:, 1], V[:, 0])
    groups = []
    for centre in (0.0, np.pi, np.pi / 2):
        dist = np.abs((ang - centre + np.pi) % (2 * np.pi) - np.pi)
        groups.append(np.flatnonzero(dist <= np.quantile(dist, 0.021) + 1e-12))
    return groups


def torus_move(step):
    """Group transforms of the torus for drag step `step` (a small move per step)."""
    return np.stack([np.eye(4),
                     affine(rotation([1, 0, 0], 3.0 * step), t=(0, 0, 0.03 * step), pivot=(-1, 0, 0)),
                     affine(t=(0.01 * step, 0, 0))])


def bar(resolution=1):
    """The 4 x 1 bar (closed tube, radius 0.5) of the bend experiments."""
    return shapes.tube(length=4.0, radius=0.5, segments=32 * resolution, rings=64 * resolution)


@dataclass
class Case:
    name: str
    title: str
    V: np.ndarray
    F: object
    groups: list
    group_names: list
    steps: list                     # list of (G, 4, 4), rest -> final pose
    still: dict = field(default_factory=dict)   # name -> vertex ids that should not move
    rigid: bool = False
    cells: int | None = None
    note: str = ""

    @property
    def tris(self):
        return quality.triangles(self.F)

    @property
    def final(self):
        return self.steps[-1]

    @property
    def handle_count(self):
        return int(sum(len(g) for g in self.groups))


def ramp(final_fn, steps):
    """Transforms for steps 1..n of a pose whose parameter t goes 0 -> 1."""
    return [final_fn((k + 1) / steps) for k in range(steps)]


def bar_case(kind, resolution=1):
    V, F = bar(resolution)
    L = 4.0
    base, tip = np.flatnonzero(V[:, 0] <= 0.4 + 1e-9), np.flatnonzero(V[:, 0] >= L - 0.4 - 1e-9)
    groups, names = [base, tip], ["base", "tip"]
    if kind in ("bend90", "bend135"):
        deg = 90 if kind == "bend90" else 135

        def pose(t):
            th = np.radians(deg * t)
            R = rotation([0, 0, 1], np.degrees(th))
            if th == 0:
                return np.stack([np.eye(4), np.eye(4)])
            r = L / th
            end = np.array([r * np.sin(th), r * (1 - np.cos(th)), 0])  # the arc of length L
            return np.stack([np.eye(4), affine(R, t=end - R @ [L, 0, 0])])
        title = f"{deg}° bend of a 4:1 bar (arc of the bar's length)"
        steps = ramp(pose, 6 if deg == 90 else 9)
    elif kind == "twist180":
        steps = ramp(lambda t: np.stack([np.eye(4), affine(rotation([1, 0, 0], 180 * t), pivot=(L, 0, 0))]), 6)
        title = "180° twist of a 4:1 bar"
    else:  # rigid: both groups by one rigid motion
        R = rotation([1, 1, 0.3], 40)
        steps = [np.stack([affine(R, t=(0.5, 0.2, 0.1), pivot=(2, 0, 0))] * 2)]
        title = "one rigid motion of all handles (40° turn + shift)"
    return Case(f"bar_{kind}", title, V, F, groups, names, steps, rigid=(kind == "rigid"))


def plate_case(n=48):
    """A 4 x 1 x 0.5 plate, every face a fine n x n grid, bent 90° about y (its flat top face
    curves): for the dihedral change at lattice cell boundaries (the paper's Figure 4)."""
    V, F = shapes.box(lo=(0.0, -0.5, -0.25), hi=(4.0, 0.5, 0.25), n=n)
    base, tip = np.flatnonzero(V[:, 0] <= 0.4 + 1e-9), np.flatnonzero(V[:, 0] >= 3.6 - 1e-9)

    def pose(t):
        th = np.radians(90 * t)
        R = rotation([0, -1, 0], 90 * t)
        r = 4.0 / th
        end = np.array([r * np.sin(th), 0, r * (1 - np.cos(th))])
        return np.stack([np.eye(4), affine(R, t=end - R @ [4.0, 0, 0])])
    return Case("plate_bend90", "4 x 1 x 0.5 plate bent 90° on a coarse lattice (Figure 4)", V, F,
                [base, tip], ["base", "tip"], ramp(pose, 6))


def two_bars_case():
    """Two bars side by side, 0.08 apart (less than a lattice cell): one bends, the other is held
    at both ends; its free middle should not move (separate-part drag)."""
    A = bar()
    B = (A[0] + [0, 1.08, 0], A[1])
    V, F = shapes.concat(A, B)
    n = len(A[0])
    x = V[:, 0]
    a_base = np.flatnonzero((np.arange(len(V)) < n) & (x <= 0.4))
    a_tip = np.flatnonzero((np.arange(len(V)) < n) & (x >= 3.6))
    b_ends = np.flatnonzero((np.arange(len(V)) >= n) & ((x <= 0.4) | (x >= 3.6)))
    b_free = np.flatnonzero((np.arange(len(V)) >= n) & (x > 1.0) & (x < 3.0))
    steps = ramp(lambda t: np.stack([np.eye(4), affine(t=(0, 0, 1.2 * t)), np.eye(4)]), 4)
    return Case("two_bars", "two bars 0.08 apart: one tip lifted 1.2, the other bar held at both ends",
                V, F, [a_base, a_tip, b_ends], ["bar A base", "bar A tip", "bar B ends"], steps,
                still={"bar B middle": b_free})


def hand_case(palm_top=0.58):
    """hand_lowres.obj: one finger bent 60° about its knuckle, the other fingertips and the palm
    held. The fingers start at y = 0.6; by default the palm is held up to just below them
    (y < 0.58), as in issue 9's measurement, where surface ARAP leaves the other fingers at 0.00%.
    With palm_top=0.40 ("hand_finger_free_palm") a band of the palm is free: it bends with the
    finger in every method, and the other fingers' roots move with it (surface ARAP included)."""
    mesh = load("hand_lowres.obj")
    if mesh is None:
        return None
    V, F = mesh
    from peers.surface_arap import components
    tris = quality.triangles(F)
    up = np.flatnonzero(V[:, 1] > 0.6)
    keep = np.all(np.isin(tris, up), axis=1)
    lab = components(len(V), tris[keep])
    fingers = sorted((np.flatnonzero(np.isin(np.arange(len(V)), up) & (lab == l)) for l in np.unique(lab[up])),
                     key=lambda ids: V[ids, 0].mean())
    fingers = [f for f in fingers if len(f) > 20]
    palm = np.flatnonzero(V[:, 1] < palm_top)
    tips = [f[V[f, 1] >= V[f, 1].max() - 0.06] for f in fingers]
    bent = int(np.argmin([abs(V[f, 0].mean() - 0.03) for f in fingers]))
    f = fingers[bent]
    knuckle = np.array([V[f, 0].mean(), 0.6, V[f, 2].mean()])

    def pose(t):
        T = [np.eye(4)] + [np.eye(4)] * len(tips)
        T[1 + bent] = affine(rotation([1, 0, 0], 60 * t), pivot=knuckle)
        return np.stack(T)
    neighbours = np.concatenate([np.setdiff1d(fingers[k], tips[k]) for k in (bent - 1, bent + 1)
                                 if 0 <= k < len(fingers)])
    name, title = "hand_finger", "hand: one finger bent 60° at its base, palm and the other tips held"
    if palm_top < 0.58:
        name, title = "hand_finger_free_palm", f"hand: one finger bent 60° at its base, the palm below y={palm_top:g} and the other tips held"
    return Case(name, title,
                V, F, [palm] + tips, ["palm"] + [f"tip {k}" for k in range(len(tips))], ramp(pose, 4),
                still={"neighbouring fingers": neighbours})


def armadillo_groups(V):
    x, y = V[:, 0], V[:, 1]
    feet = np.flatnonzero(y < -0.45)
    torso = np.flatnonzero((np.abs(x) < 0.12) & (y > -0.1) & (y < 0.2))
    rhand = np.flatnonzero((x > 0.29) & (y > 0.0))
    lhand = np.flatnonzero((x < -0.29) & (y > 0.0))
    head = np.flatnonzero((np.abs(x) < 0.15) & (y > 0.3))
    return [feet, torso, rhand, lhand, head], ["feet", "torso", "right hand", "left hand", "head"]


def armadillo_case(kind, V=None, F=None, name=None):
    if V is None:
        mesh = load("armadillo.obj")
        if mesh is None:
            return None
        V, F = mesh
    groups, names = armadillo_groups(V)
    x, y = V[:, 0], V[:, 1]
    elbow = V[(x > 0.18) & (x < 0.23) & (y > 0.0)].mean(0)
    lelbow = V[(x < -0.18) & (x > -0.23) & (y > 0.0)].mean(0)

    def pose(t):
        T = [np.eye(4)] * 5
        if kind in ("arm", "mix", "big"):
            T[2] = affine(rotation([0, 0, 1], 80 * t), pivot=elbow)
        if kind in ("wave", "mix"):
            T[3] = affine(rotation([0, 0, 1], -70 * t), pivot=lelbow)
            T[4] = affine(rotation([0, 1, 0], 30 * t), pivot=V[groups[4]].mean(0))
        return np.stack(T)
    titles = {"arm": "character: elbow bent 80° (limb bend)", "wave": "character: other arm raised, head turned 30°",
              "mix": "character: both arms and the head posed", "big": "1M-vertex character (armadillo, subdivided 3x): elbow bent 80°"}
    return Case(name or f"armadillo_{kind}", titles[kind], V, F, groups, names, ramp(pose, 4))


def truck_case():
    mesh = load("truck.obj")
    if mesh is None:
        return None
    V, F = mesh
    x = V[:, 0]
    rear, front = np.flatnonzero(x < -0.5), np.flatnonzero(x > 0.5)
    steps = ramp(lambda t: np.stack([np.eye(4), affine(rotation([0, 1, 0], -20 * t), t=(0, 0, 0.1 * t),
                                                       pivot=(0.5, 0, 0))]), 4)
    return Case("truck_multipart", "multi-part truck (50 parts, open, non-manifold): front lifted and tilted 20°",
                V, F, [rear, front], ["rear", "front"], steps)


def quality_cases(quick=False):
    """The poses of the quality comparison, with a note for each one that is skipped."""
    cases, skipped = [bar_case("bend90"), bar_case("bend135"), bar_case("twist180"), bar_case("rigid"),
                      two_bars_case()], []
    for make, what in ((hand_case, "hand_lowres.obj"), (lambda: hand_case(palm_top=0.40), "hand_lowres.obj"), (lambda: armadillo_case("arm"), "armadillo.obj"),
                       (lambda: armadillo_case("wave"), "armadillo.obj"), (lambda: armadillo_case("mix"), "armadillo.obj"),
                       (truck_case, "truck.obj")):
        c = make()
        if c is None:
            skipped.append(f"{what} not found (set LARAP_MESHES or provide ../shared/data/meshes)")
        elif not (quick and c.name in ("armadillo_wave",)):
            cases.append(c)
    return cases, sorted(set(skipped))
