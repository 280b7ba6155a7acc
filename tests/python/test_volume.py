# Run: PYTHONPATH=python /usr/bin/python3 -m pytest tests/python/test_volume.py
"""Volume in a limb bend (issue 9's target: no larger a change than surface ARAP's, on a
character's limb). A thin-limbed figure at the default lattice: its arm, a closed tube 9 cm thick
(2.4 cells), bent 80 degrees at the elbow with the body held to the shoulder and the forearm's end
and hand moved, as an artist pins it (vertex groups, 83% of the vertices)."""
import numpy as np
import pytest
from conftest import affine, rotation

import larap
from larap import quality
from larap.shapes import box, concat, sphere, tube_between

# Surface ARAP (CGAL's Surface_mesh_deformation, scripts/peers, 100 iterations per step, the pose
# ramped in 4 steps) on the arm tube with the same handles: -7.18% (2026-11-24). With one rotation
# per node the lattice lost -8.07% (-8.2 to -9.9% at other orientations of the model).
SURFACE_ARAP = -0.0718


def figure():
    """Torso, head, legs, two arms (tubes of 40 rings) and palms; returns V, F and the right arm's
    vertex ids and triangles (ids into V)."""
    pieces = [box((-0.18, -0.1, 0.9), (0.18, 0.1, 1.5), 6), sphere((0.0, 0.0, 1.65), 0.12, 10, 16),
              box((-0.17, -0.08, 0.0), (-0.03, 0.08, 0.92), 6), box((0.03, -0.08, 0.0), (0.17, 0.08, 0.92), 6)]
    arm = None
    for s in (-1.0, 1.0):
        pieces.append(tube_between((s * 0.15, 0, 1.42), (s * 0.72, 0, 1.42), 0.045, segments=16, rings=40))
        if s > 0:
            arm = len(pieces) - 1
        lo, hi = sorted((s * 0.70, s * 0.80))
        pieces.append(box((lo, -0.05, 1.405), (hi, 0.05, 1.435), 4))
    V, F = concat(*pieces)
    first = np.cumsum([0] + [len(p[0]) for p in pieces])
    ids = np.arange(first[arm], first[arm + 1])
    return V, F, ids, quality.triangles(pieces[arm][1]) + first[arm]


@pytest.mark.parametrize("weights", ["trilinear", "bspline"])
def test_thin_elbow_keeps_more_volume_than_surface_arap(weights):
    V, F, arm, arm_tris = figure()
    groups = [np.flatnonzero(V[:, 0] < 0.25), np.flatnonzero(V[:, 0] > 0.62)]
    d = larap.Deformer(V, F, weights=weights)
    assert 2.0 < 0.09 / d.cell_size < 3.0  # the arm is two to three cells thick
    d.set_handle_groups(groups)
    for t in (0.25, 0.5, 0.75):  # dragged there, as the quality benchmark ramps it
        d.solve(transforms=[np.eye(4), affine(rotation([0, 0, 1], 80 * t), pivot=(0.45, 0, 1.42))], iterations=30)
    T = [np.eye(4), affine(rotation([0, 0, 1], 80), pivot=(0.45, 0, 1.42))]
    X = d.solve(transforms=T, iterations=300, tol=1e-7)
    change = quality.volume_change(V, X, arm_tris)
    assert change < 0.0  # an elbow's inside is pressed: the test measures a real bend
    assert change >= SURFACE_ARAP, change
    hand = groups[1]
    miss = np.linalg.norm(X[hand] - (V[hand] @ T[1][:3, :3].T + T[1][:3, 3]), axis=1).max()
    assert miss <= 0.03 * 0.27, miss  # the hand reaches its target within 3% of the forearm
