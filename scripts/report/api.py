"""Handle groups through the public API, with a fallback for builds that only have per-vertex
handles: `set_handle_groups` + `solve(transforms=...)` where the engine has them, else
`set_handles(concatenated ids)` + `solve(targets)` with each group's rest positions mapped by its
transform (the same targets; per-vertex handles weigh every vertex alike, groups weigh every
group alike, so the two can differ a little in how hard the handles pull)."""
from __future__ import annotations

import numpy as np


def has_groups(d) -> bool:
    return hasattr(d, "set_handle_groups")


def name(d) -> str:
    return "set_handle_groups + solve(transforms)" if has_groups(d) else "set_handles + solve(targets) (fallback)"


def apply(T, X):
    """Rows of X mapped by the 4x4 affine T."""
    return X @ T[:3, :3].T + T[:3, 3]


def targets(V, groups, transforms):
    """The handle vertices' targets, group by group (the order of the concatenated ids)."""
    return np.concatenate([apply(T, V[g]) for g, T in zip(groups, transforms)])


class Posed:
    """A Deformer with handle groups set, solved by group transforms on either API."""

    def __init__(self, d, V, groups):
        self.d, self.V, self.groups = d, V, [np.asarray(g, np.int64) for g in groups]
        self.ids = np.concatenate(self.groups)
        if has_groups(d):
            d.set_handle_groups(self.groups)
        else:
            d.set_handles(self.ids)

    def solve(self, transforms, iterations=5, out=None, tol=None):
        T = np.asarray(transforms, float)
        if has_groups(self.d):
            return self.d.solve(transforms=T, iterations=iterations, out=out, tol=tol)
        return self.d.solve(targets(self.V, self.groups, T), iterations, out=out, tol=tol)

    def pose_lattice(self, transforms, iterations=5, tol=None):
        T = np.asarray(transforms, float)
        if has_groups(self.d):
            return self.d.pose_lattice(transforms=T, iterations=iterations, tol=tol)
        return self.d.pose_lattice(targets(self.V, self.groups, T), iterations, tol=tol)
