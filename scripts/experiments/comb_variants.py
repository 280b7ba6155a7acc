"""Drives arap_variants.py on the tests' scenes (tests/python/test_topology.py, test_deformer.py):
per energy variant, the comb's drag and tip miss (trilinear and B-spline transfer of the same
lattice pose), a rigid motion of every handle, the two-bars test, the volume of a 90 degree bend
of the tube and the hand test (energy variants without material weights: no inside test there).
Run: PYTHONPATH=python /usr/bin/python3 scripts/experiments/comb_variants.py"""
import os
import sys
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
REPO = os.path.dirname(os.path.dirname(HERE))
sys.path[:0] = [HERE, os.path.join(REPO, "python"), os.path.join(REPO, "tests", "python")]

import larap  # noqa: E402
from arap_variants import (Lat, Solver, group_alpha, group_targets, transfer, material_masks,  # noqa: E402
                           cell_weights, boxes_inside, split_copy_weights, mean_over_copies)
from conftest import affine, apply, rotation  # noqa: E402
from larap.quality import diagonal, triangles, volume  # noqa: E402
from test_topology import comb, comb_pose, bars, bend_first_pin_second  # noqa: E402
from test_deformer import bend_setup  # noqa: E402
from larap import shapes  # noqa: E402

ITER = 200


def comb_boxes(tines=3, gap=0.1, width=1.0, height=1.0, length=6.0):
    pitch = width + gap
    b = [((-3.0, 0.0, 0.0), (-0.1, tines * pitch - gap, height))]
    for t in range(tines):
        b.append(((-0.5, t * pitch, 0.0), (length, t * pitch + width, height)))
    return b


# variant name -> (rotations, weight mode or None, floor)
VARIANTS = {
    "node (engine)": ("node", None, 0.0),
    "cell": ("cell", None, 0.0),
    "nodecell": ("nodecell", None, 0.0),
    "node+frac floor.05": ("node", "fraction", 0.05),
    "cell+frac floor.05": ("cell", "fraction", 0.05),
    "node+frac floor.001": ("node", "fraction", 1e-3),
    "cell+frac floor.001": ("cell", "fraction", 1e-3),
    "cell+quadrant floor.001": ("cell", "quadrant", 1e-3),
    # material on the copies of split cells only (1 elsewhere): the rule the engine adopted
    "node+split material": ("node", "split", 0.05),
    "cell+split material": ("cell", "split", 0.05),
}


def make(lat, rows, alpha, variant, masks):
    rot, mode, floor = VARIANTS[variant]
    if mode == "split":
        wc = split_copy_weights(lat, masks, floor)
        if rot == "node":
            return Solver(lat, rows, alpha, edge_w=mean_over_copies(lat, wc))
        return Solver(lat, rows, alpha, rotations="cell", cw=np.repeat(wc[:, None], 12, 1), floor=0.0)
    cw = None if mode is None else cell_weights(masks, mode)
    return Solver(lat, rows, alpha, rotations=rot, cw=cw, floor=floor)


def run_comb(variant, h=1.0, caches={}, scaled=False):
    """scaled: the comb's gap is 0.1 h (the tests' comb_sweep: tines 1/h cells thick, always 0.1
    cell apart) instead of 0.1."""
    cache = caches.setdefault((h, scaled), {})
    if "lat" not in cache:
        gap = 0.1 * h if scaled else 0.1
        V, F, tine_ids, _ = comb(gap=gap)
        d = larap.Deformer(V, F, cell_size=h, weights="bspline")
        groups, T = comb_pose(V, tine_ids, moved=1)
        lat = Lat(d, V)
        cache.update(V=V, tine_ids=tine_ids, groups=groups, T=T, lat=lat,
                     masks=material_masks(lat, boxes_inside(comb_boxes(gap=gap))))
    c = cache
    V, groups, T, lat = c["V"], c["groups"], c["T"], c["lat"]
    rows, alpha = group_alpha(groups)
    s = make(lat, rows, alpha, variant, c["masks"])
    X = s.solve(group_targets(V, groups, T), ITER)
    out = []
    for kind in ("trilinear", "bspline"):
        Y = transfer(lat, X, kind)
        drag = max(np.linalg.norm(Y[c["tine_ids"][t]] - V[c["tine_ids"][t]], axis=1).max() for t in (0, 2)) / diagonal(V)
        miss = np.linalg.norm(Y[groups[2]] - apply(T[2], V[groups[2]]), axis=1).max() / 6.0
        out += [100 * drag, 100 * miss]
    # every handle group moved by one rigid motion: that motion of the lattice is a fixed point
    # (the engine reaches it by its rigid warm start; from rest flip-flop needs many iterations)
    M = affine(rotation([1, 2, 3], 50), pivot=(1.0, 1.0, 0.5))
    Xr = s.solve(group_targets(V, groups, np.stack([M] * len(groups))), 5, X0=apply(M, lat.rest))
    out.append(np.abs(Xr - apply(M, lat.rest)).max() / diagonal(V))
    Xz = s.solve(group_targets(V, groups, np.stack([np.eye(4)] * len(groups))), 5)
    out.append(np.abs(Xz - lat.rest).max())
    return out


def run_bars(variant):
    V, F, first, second = bars(2.5)
    d = larap.Deformer(V, F, cell_size=1.0, weights="bspline")
    groups, T = bend_first_pin_second(V, first, second)
    lat = Lat(d, V)
    masks = None
    if VARIANTS[variant][1]:
        side, sp = 0.8, 2.5
        masks = material_masks(lat, boxes_inside([((0, 0, 0), (8, side, side)), ((0, side + sp, 0), (8, 2 * side + sp, side))]))
    rows, alpha = group_alpha(groups)
    s = make(lat, rows, alpha, variant, masks)
    X = transfer(lat, s.solve(group_targets(V, groups, T), 5), "bspline")
    return 100 * np.linalg.norm(X[second] - V[second], axis=1).max() / 8.0


def run_tube(variant):
    V, F = shapes.tube(length=4.0, radius=0.5, segments=32, rings=64)
    d = larap.Deformer(V, F, weights="bspline")
    idx, T = bend_setup(V)
    lat = Lat(d, V)
    masks = None
    if VARIANTS[variant][1]:
        def inside(P):
            return (P[:, 0] >= 0) & (P[:, 0] <= 4) & (P[:, 1] ** 2 + P[:, 2] ** 2 <= 0.25)
        masks = material_masks(lat, inside, k=8)
    s = make(lat, idx, np.full(len(idx), 1.0 / len(idx)), variant, masks)
    X = transfer(lat, s.solve(T, ITER), "bspline")
    tris = triangles(F)
    return volume(X, tris) / volume(V, tris), np.linalg.norm(X[idx] - T, axis=1).max() / diagonal(V)


def hand_setup():
    path = os.path.join(REPO, "..", "shared", "data", "meshes", "hand_lowres.obj")
    if not os.path.exists(path):
        return None
    import test_topology as tt
    V, F = larap.load_mesh(path)
    groups, T, fingers, moved, length = tt.hand_finger_pose(V, F)
    d = larap.Deformer(V, F, weights="bspline")
    return V, d, groups, T, fingers, moved, length


def run_hand(variant, cache={}):
    if VARIANTS[variant][1]:
        return None
    if "h" not in cache:
        cache["h"] = hand_setup()
        if cache["h"] is not None:
            cache["lat"] = Lat(cache["h"][1], cache["h"][0])
    if cache["h"] is None:
        return None
    V, d, groups, T, fingers, moved, length = cache["h"]
    lat = cache["lat"]
    rows, alpha = group_alpha(groups)
    s = make(lat, rows, alpha, variant, None)
    Xl = s.solve(group_targets(V, groups, T), ITER)
    out = []
    for kind in ("trilinear", "bspline"):
        X = transfer(lat, Xl, kind)
        drag = max(np.linalg.norm(X[f] - V[f], axis=1).max() for k, f in enumerate(fingers) if k != moved) / diagonal(V)
        miss = np.linalg.norm(X[groups[1 + moved]] - apply(T[1 + moved], V[groups[1 + moved]]), axis=1).max() / length
        out += [100 * drag, 100 * miss]
    return out


def sweep(names, sizes=(0.9, 0.95, 1.05, 1.1), scaled=False):
    """The comb at other cell sizes (the tests' h = 1 is a favourable alignment)."""
    print("comb drag % (trilinear / bspline) and tip miss % (bspline) by cell size"
          + (", gap 0.1 h" if scaled else ""))
    print("variant | " + " | ".join(f"h={h}" for h in sizes) + (" | median, worst, within 1 %" if scaled else ""))
    for v in names:
        cols, worst = [], []
        for h in sizes:
            c = run_comb(v, h, scaled=scaled)
            worst.append(max(c[0], c[2]))
            cols.append(f"{c[0]:.2f} / {c[2]:.2f}, miss {c[3]:.2f}")
        if scaled:
            cols.append(f"{np.median(worst):.2f}, {max(worst):.2f}, {sum(w <= 1.0 for w in worst)}/{len(worst)}")
        print(f"{v} | " + " | ".join(cols), flush=True)


if __name__ == "__main__":
    if sys.argv[1:2] == ["--sweep"]:
        sweep(sys.argv[2:] or list(VARIANTS))
        sys.exit(0)
    if sys.argv[1:2] == ["--scaled"]:  # the comb scaled to the cell at the tests' 17 sizes
        ITER = 100
        sweep(sys.argv[2:] or list(VARIANTS), tuple(np.round(np.linspace(0.25, 1.05, 17), 3)), scaled=True)
        sys.exit(0)
    names = sys.argv[1:] or list(VARIANTS)
    print(f"{ITER} flip-flop iterations from rest (bars: 5); % of the comb's diagonal / tine length")
    print("variant | comb tri drag / miss | comb bspl drag / miss | rigid err/diag | rest err | "
          "bars pinned % | tube vol ratio, handle miss/diag | hand tri drag/miss | hand bspl drag/miss")
    for v in names:
        t = time.time()
        c = run_comb(v)
        b = run_bars(v)
        vol, hm = run_tube(v)
        h = run_hand(v)
        hs = "skipped" if h is None else "%.2f / %.2f | %.2f / %.2f" % tuple(h)
        print(f"{v} | {c[0]:.2f} / {c[1]:.2f} | {c[2]:.2f} / {c[3]:.2f} | {c[4]:.1e} | {c[5]:.1e} | {b:.3f} | "
              f"{vol:.4f}, {hm:.4f} | {hs}   ({time.time() - t:.0f} s)", flush=True)
