# Run: PYTHONPATH=python /usr/bin/python3 -m pytest tests/python/test_wires.py
"""Wire meshes (loose edges only: a Skin modifier's skeleton, guide curves): the lattice keeps the
cells every edge passes through, so the wire bends as one piece instead of tearing into its
vertices (native/src/voxel_grid.cpp, mark_segments). Properties on larap.shapes.stick_figure,
bound at the default lattice as a user would."""
import numpy as np
import pytest
from conftest import rotation, tol

import larap
from larap import shapes
from larap.quality import diagonal, triangles

WEIGHTS = ["trilinear", "bspline"]


@pytest.fixture(scope="module")
def figure():
    return shapes.stick_figure()


def edge_lengths(X, F):
    F = np.asarray(F)
    return np.linalg.norm(X[F[:, 0]] - X[F[:, 1]], axis=1)


def raise_arm(V, limbs, angle=80.0):
    """Held as an artist pins a figure: the spine, the right hand and both feet (each limb's last
    two vertices) kept where they are, the left hand turned `angle` degrees up about the shoulder:
    (groups, transforms, the left hand's ids, shoulder). (A limb that nothing holds is a free branch
    of the junction it leaves: ARAP turns it with the junction, so a free right arm rises with the
    left, 10% of the figure's height once converged; hold it, as here.)"""
    spine = V[limbs["spine"]]
    shoulder = spine[np.argmin(np.linalg.norm(spine - V[limbs["left_arm"][0]], axis=1))]
    hand = limbs["left_arm"][-2:]
    R = rotation([1, 0, 0], angle)
    turn = np.eye(4)
    turn[:3, :3] = R
    turn[:3, 3] = shoulder - R @ shoulder
    held = [limbs[k][-2:] for k in ("right_arm", "left_leg", "right_leg")]
    groups = [limbs["spine"], hand] + held
    T = np.stack([np.eye(4), turn] + [np.eye(4)] * len(held))
    return groups, T, hand, shoulder


def test_a_wire_is_one_lattice_component(figure):
    V, F, _ = figure
    assert larap.Deformer(V, F).num_components == 1
    # Without its edges every chain of far-apart vertices falls apart (the old behaviour).
    assert larap.Deformer(V, [], cell_size=0.05).num_components > 40


@pytest.mark.parametrize("weights", WEIGHTS)
def test_rest_targets_give_rest_pose(figure, weights, device):
    V, F, limbs = figure
    d = larap.Deformer(V, F, weights=weights, device=device)
    groups, T, _, _ = raise_arm(V, limbs)
    d.set_handle_groups(groups)
    X = d.solve(transforms=np.tile(np.eye(4), (len(groups), 1, 1)), iterations=5)
    assert np.abs(X - V).max() <= 1e-6 * diagonal(V)


@pytest.mark.parametrize("weights", WEIGHTS)
def test_rigid_motion_gives_rigid_pose(figure, weights, device):
    V, F, limbs = figure
    R, t = rotation([1, 2, 3], 60), np.array([1.0, -2.0, 0.5])
    d = larap.Deformer(V, F, weights=weights, device=device)
    groups, _, _, _ = raise_arm(V, limbs)
    d.set_handle_groups(groups)
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R, t
    X = d.solve(transforms=np.stack([T] * len(groups)), iterations=60)
    assert np.abs(X - (V @ R.T + t)).max() <= 1e-3 * diagonal(V)


@pytest.mark.parametrize("weights", WEIGHTS)
def test_raised_arm_bends_without_tearing(figure, weights, device):
    """The hand reaches its target, every edge keeps its length within 10% (the wire is one piece:
    without the edges' cells the arm's middle stayed at rest and its edges stretched up to 9.7
    times), the held limbs stay within 1% of the figure's size, and the energy never rises."""
    V, F, limbs = figure
    groups, T, hand, shoulder = raise_arm(V, limbs)
    d = larap.Deformer(V, F, weights=weights, device=device)
    d.set_handle_groups(groups)
    X = d.solve(transforms=T, iterations=60)
    size = diagonal(V)
    target = V[hand] @ T[1, :3, :3].T + T[1, :3, 3]
    arm = np.linalg.norm(V[limbs["left_arm"][-1]] - shoulder)
    assert np.linalg.norm(X[hand] - target, axis=1).max() <= 0.03 * arm
    stretch = edge_lengths(X, F) / edge_lengths(V, F)
    assert np.abs(stretch - 1).max() <= 0.10, (stretch.min(), stretch.max())
    others = np.concatenate([limbs[k] for k in ("right_arm", "left_leg", "right_leg")])
    assert np.linalg.norm(X[others] - V[others], axis=1).max() <= 0.01 * size
    # The arm's middle followed the hand up (the torn wire left it at rest).
    middle = limbs["left_arm"][len(limbs["left_arm"]) // 2]
    assert X[middle, 2] - V[middle, 2] >= 0.25 * arm
    e = np.array(d.stats["energy"])
    assert np.all(np.diff(e) <= tol(device, 1e-9, 1e-5) * e[0]), e


def test_obj_lines_load_as_a_wire(tmp_path, figure):
    """An OBJ whose polylines (`l`) hold the figure binds as the same one-piece wire."""
    V, F, limbs = figure
    path = tmp_path / "figure.obj"
    path.write_text("".join(f"v {x:.17g} {y:.17g} {z:.17g}\n" for x, y, z in V) +
                    "".join(f"l {a + 1} {b + 1}\n" for a, b in F))
    W, G = larap.load_mesh(str(path))
    assert np.array_equal(W, V)
    assert G.shape == (len(F), 2) and triangles(G).shape == (0, 3)  # lines give no triangle
    assert larap.Deformer(W, G).num_components == 1
    # and saved back as lines
    out = tmp_path / "back.obj"
    larap.save_mesh(str(out), W, G)
    assert sum(line.startswith("l ") for line in out.read_text().splitlines()) == len(F)


@pytest.mark.parametrize("weights,levels", [("trilinear", 1), ("bspline", 1), ("trilinear", 3)])
def test_cpu_and_cuda_agree_on_a_wire(figure, weights, levels):
    """The raised arm on both devices, converged (3,000 flip-flops: a chain one cell thick converges
    slowly, and after 200 the figure is still 0.25% of its size from its pose, more than the
    devices' paths may differ): the poses within 1e-4 of the diagonal, the energies within 1e-3,
    neither rising (test_cuda.poses_agree); skipped where no GPU is usable."""
    from test_cuda import poses_agree
    if "cuda" not in larap.available_devices():
        pytest.skip("no usable CUDA device here")
    V, F, limbs = figure
    groups, T, _, _ = raise_arm(V, limbs)
    poses_agree(lambda dev: larap.Deformer(V, F, weights=weights, levels=levels, device=dev), groups, T,
                iterations=3000)
