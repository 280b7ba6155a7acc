"""The Blender peers' bar, outside Blender: the same mesh, groups and steps that
blender_peers.py builds for a vertex count, for measuring its poses."""
from __future__ import annotations

import numpy as np

from . import cases


def bar(vertices):
    rings = max(16, int(round(np.sqrt(2 * vertices))))
    segments = max(16, int(round(vertices / rings)))
    V, F = cases.shapes.tube(length=4.0, radius=0.5, segments=segments, rings=rings)
    groups = [np.flatnonzero(V[:, 0] <= 0.4 + 1e-9), np.flatnonzero(V[:, 0] >= 3.6 - 1e-9)]
    return V, F, groups, cases.bar_case("bend90").steps
