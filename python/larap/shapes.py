"""Meshes generated on the fly: the demo's default input and the tests' fixtures.

Every function returns (vertices (n, 3) float64, faces (m, k) int64 or a list of polygons).
"""
from __future__ import annotations

import numpy as np


def tube(length=4.0, radius=0.5, segments=32, rings=64, caps=True):
    """Closed cylinder along +x from x=0 to x=length: quads on the side, triangle fans on the caps."""
    x = np.linspace(0.0, length, rings + 1)
    a = np.linspace(0.0, 2 * np.pi, segments, endpoint=False)
    ring = np.stack([np.zeros_like(a), radius * np.cos(a), radius * np.sin(a)], axis=1)
    V = np.concatenate([ring + [xi, 0, 0] for xi in x])
    i = np.arange(rings)[:, None] * segments
    j = np.arange(segments)[None, :]
    j1 = (j + 1) % segments
    quads = np.stack([i + j, i + j1, i + segments + j1, i + segments + j], axis=-1).reshape(-1, 4)
    faces = [q for q in quads.tolist()]
    if caps:
        c0, c1 = len(V), len(V) + 1
        V = np.concatenate([V, [[0, 0, 0], [length, 0, 0]]])
        last = rings * segments
        for s in range(segments):
            faces.append([c0, (s + 1) % segments, s])
            faces.append([c1, last + s, last + (s + 1) % segments])
    return V, faces


def sphere(center=(0.0, 0.0, 0.0), radius=1.0, rings=16, segments=32):
    """UV sphere, closed and consistently oriented (outward)."""
    th = np.pi * np.arange(1, rings) / rings
    ph = 2 * np.pi * np.arange(segments) / segments
    T, P = np.meshgrid(th, ph, indexing="ij")
    body = np.stack([np.sin(T) * np.cos(P), np.sin(T) * np.sin(P), -np.cos(T)], -1).reshape(-1, 3)
    V = np.concatenate([[[0, 0, -1], [0, 0, 1]], body]) * radius + np.asarray(center, float)

    def ring(i, j):
        return 2 + (i - 1) * segments + (j % segments)

    faces = [[0, ring(1, j + 1), ring(1, j)] for j in range(segments)]
    for i in range(1, rings - 1):
        faces += [[ring(i, j), ring(i, j + 1), ring(i + 1, j + 1), ring(i + 1, j)] for j in range(segments)]
    faces += [[1, ring(rings - 1, j), ring(rings - 1, j + 1)] for j in range(segments)]
    return V, faces


def box(lo=(0.0, 0.0, 0.0), hi=(1.0, 1.0, 1.0), n=8):
    """Closed box with each face split into n x n quads (shared vertices)."""
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    verts, faces, index = [], [], {}

    def vid(p):
        key = tuple(np.round(p, 12))
        if key not in index:
            index[key] = len(verts)
            verts.append(p)
        return index[key]

    t = np.linspace(0, 1, n + 1)
    for axis in range(3):
        for side in (0, 1):
            u, v = (axis + 1) % 3, (axis + 2) % 3
            for a in range(n):
                for b in range(n):
                    quad = []
                    for da, db in ((0, 0), (1, 0), (1, 1), (0, 1)):
                        p = np.empty(3)
                        p[axis] = side
                        p[u], p[v] = t[a + da], t[b + db]
                        quad.append(vid(lo + p * (hi - lo)))
                    faces.append(quad if side else quad[::-1])
    return np.array(verts), np.array(faces, dtype=np.int64)


def sheet(nx=20, ny=20, size=(2.0, 2.0)):
    """Flat (zero-thickness) grid of quads in the z=0 plane."""
    x = np.linspace(0, size[0], nx + 1)
    y = np.linspace(0, size[1], ny + 1)
    X, Y = np.meshgrid(x, y, indexing="ij")
    V = np.stack([X.ravel(), Y.ravel(), np.zeros(X.size)], 1)
    i = np.arange(nx)[:, None] * (ny + 1)
    j = np.arange(ny)[None, :]
    F = np.stack([i + j, i + ny + 1 + j, i + ny + 2 + j, i + j + 1], -1).reshape(-1, 4)
    return V, F


def concat(*meshes):
    """Several meshes as one (separate parts)."""
    verts, faces, base = [], [], 0
    for V, F in meshes:
        verts.append(np.asarray(V, float))
        faces += [[int(i) + base for i in f] for f in F]
        base += len(V)
    return np.concatenate(verts), faces


def soup(V, F, seed=0):
    """Every polygon triangulated with its own vertices, half of them flipped, in random order:
    no shared vertices, inconsistent orientation (a "polygon soup")."""
    rng = np.random.default_rng(seed)
    tris = [[f[0], f[k], f[k + 1]] for f in F for k in range(1, len(f) - 1)]
    tris = np.asarray(tris)[rng.permutation(len(tris))]
    flip = rng.random(len(tris)) < 0.5
    tris[flip] = tris[flip][:, ::-1]
    return np.asarray(V, float)[tris.ravel()], np.arange(tris.size).reshape(-1, 3)


def torus(major=1.0, minor=0.35, n_major=64, n_minor=32):
    """Torus around the z axis, all quads, as arrays (fast at millions of vertices)."""
    u = 2 * np.pi * np.arange(n_major) / n_major
    v = 2 * np.pi * np.arange(n_minor) / n_minor
    U, W = np.meshgrid(u, v, indexing="ij")
    rho = major + minor * np.cos(W)
    V = np.stack([rho * np.cos(U), rho * np.sin(U), minor * np.sin(W)], -1).reshape(-1, 3)
    i = np.arange(n_major)[:, None]
    j = np.arange(n_minor)[None, :]
    i1, j1 = (i + 1) % n_major, (j + 1) % n_minor
    F = np.stack([i * n_minor + j, i1 * n_minor + j, i1 * n_minor + j1, i * n_minor + j1], -1)
    return V, F.reshape(-1, 4).astype(np.int64)


def tube_between(p0, p1, radius, segments=12, rings=8):
    """Closed cylinder from point p0 to point p1 (tube() turned onto the segment)."""
    p0, p1 = np.asarray(p0, float), np.asarray(p1, float)
    length = float(np.linalg.norm(p1 - p0))
    V, F = tube(length=length, radius=radius, segments=segments, rings=rings)
    d = (p1 - p0) / length
    x = np.array([1.0, 0.0, 0.0])
    v, c = np.cross(x, d), float(x @ d)
    if np.linalg.norm(v) < 1e-12:
        R = np.eye(3) if c > 0 else np.diag([-1.0, -1.0, 1.0])
    else:
        K = np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])
        R = np.eye(3) + K + K @ K / (1 + c)
    return V @ R.T + p0, F


def stick_figure(edge=0.12):
    """A wire mesh (edges only, no faces): a standing figure's skeleton as a Skin modifier's base
    mesh is drawn, a spine with a neck, two arms from the shoulders and two legs from the hips,
    each limb a chain of edges about `edge` long. Faces are two-vertex polygons (loose edges).
    Returns (V, F, limbs): limbs maps "spine", "left_arm", "right_arm", "left_leg", "right_leg"
    to the vertex ids of each chain (shared joints belong to the spine)."""
    V, F, limbs = [], [], {}

    def chain(name, p0, p1, start=None):
        p0, p1 = np.asarray(p0, float), np.asarray(p1, float)
        n = max(1, int(round(np.linalg.norm(p1 - p0) / edge)))
        ids = [] if start is None else [start]
        for k in range(0 if start is None else 1, n + 1):
            V.append(p0 + (p1 - p0) * k / n)
            ids.append(len(V) - 1)
        F.extend([a, b] for a, b in zip(ids[:-1], ids[1:]))
        limbs[name] = ids if start is None else ids[1:]
        return ids

    spine = chain("spine", (0, 0, 1.0), (0, 0, 2.6))
    top = spine[int(round(0.8 * (len(spine) - 1)))]  # the shoulders' height
    chain("left_arm", V[top], V[top] + np.array([0, 1.1, -0.1]), start=top)
    chain("right_arm", V[top], V[top] + np.array([0, -1.1, -0.1]), start=top)
    chain("left_leg", V[spine[0]], (0, 0.35, 0.0), start=spine[0])
    chain("right_leg", V[spine[0]], (0, -0.35, 0.0), start=spine[0])
    return np.array(V), F, limbs


def character(finger_gap=0.004, finger_rings=6):
    """A figure in T-pose, 1.77 tall, made of separate closed parts as characters often are:
    torso, head, legs, arms, and on each arm a palm with four fingers pushed into it (tubes 18 mm
    thick, `finger_gap` apart, 90 mm long). On the default lattice its fingers are about half a
    cell thick and a tenth of a cell apart. Returns (V, F, parts): parts maps "fingers" to the
    right hand's four finger vertex ids (in y order), "hand" to the vertices at x >= 0.70 (the
    right palm and fingers) and "root_x" to the x where the right fingers leave the palm."""
    pieces = [box((-0.18, -0.1, 0.9), (0.18, 0.1, 1.5), 6),            # torso
              sphere((0.0, 0.0, 1.65), 0.12, 10, 16),                   # head
              box((-0.17, -0.08, 0.0), (-0.03, 0.08, 0.92), 6),         # legs
              box((0.03, -0.08, 0.0), (0.17, 0.08, 0.92), 6)]
    width = 0.018
    pitch = width + finger_gap
    y0 = -2 * pitch + finger_gap / 2
    right = []
    for s in (-1.0, 1.0):
        pieces.append(tube_between((s * 0.15, 0, 1.42), (s * 0.72, 0, 1.42), 0.045))  # arm
        lo, hi = sorted((s * 0.70, s * 0.80))
        pieces.append(box((lo, y0 - 0.005, 1.405), (hi, -y0 + 0.005, 1.435), 4))      # palm
        for k in range(4):
            y = y0 + k * pitch + width / 2
            pieces.append(tube_between((s * 0.79, y, 1.42), (s * 0.88, y, 1.42), width / 2,
                                       segments=10, rings=finger_rings))
            if s > 0:
                right.append(len(pieces) - 1)
    V, F = concat(*pieces)
    first = np.cumsum([0] + [len(p[0]) for p in pieces])
    fingers = [np.arange(first[i], first[i + 1]) for i in right]
    return V, F, {"fingers": fingers, "hand": np.flatnonzero(V[:, 0] >= 0.70), "root_x": 0.80}
