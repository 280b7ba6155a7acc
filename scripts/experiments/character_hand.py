"""Issue 9's character measurement on a character of our own (larap.shapes.character: a T-pose
figure of separate parts, four fingers pushed into each palm, half a cell thick and a tenth of a
cell apart on the default lattice): one finger turned 60 degrees about its root, the body, the
palm and the other fingertips held (or the body and palm as one group). Prints, per lattice size
and weight kind, how far the other fingers move (% of the hand's diagonal), how far the held
groups drift, and the turned tip's miss (% of the finger's length); with --transfer also the
B-spline output of the trilinear lattice pose (what the stencils alone add).

    PYTHONPATH=python /usr/bin/python3 scripts/experiments/character_hand.py [--cells 6000 20000]"""
import argparse
import os
import sys

import numpy as np

REPO = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
sys.path[:0] = [os.path.join(REPO, "python"), os.path.join(REPO, "tests", "python")]

import larap  # noqa: E402
from larap import shapes  # noqa: E402
from test_junctions import finger_pose, hand_size  # noqa: E402


def main():
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--cells", type=int, nargs="+", default=[6000, 20000])
    p.add_argument("--transfer", action="store_true")
    a = p.parse_args()
    V, F, parts = shapes.character()
    groups, T = finger_pose(V, parts)
    size, fingers = hand_size(V, parts), parts["fingers"]
    n = sum(len(g) for g in groups)
    print(f"character: {len(V):,} vertices; handles {n:,} ({100 * n / len(V):.0f}%) in {len(groups)} groups "
          f"(body, palm {len(groups[1])}, fingertips {len(groups[2])} each)")
    print("cells | pins | weights | h (finger thickness in cells) | other fingers % | held drift % | tip miss %")
    for cells in a.cells:
        for pins, gs, tt in (("body+palm", groups, T),
                             ("one group", [np.concatenate(groups[:2])] + groups[2:], np.concatenate([T[:1], T[2:]]))):
            for w in ("trilinear", "bspline"):
                d = larap.Deformer(V, F, weights=w, cells=cells)
                d.set_handle_groups(gs)
                X = d.solve(transforms=tt, iterations=60)
                drag = max(np.linalg.norm(X[fingers[k]] - V[fingers[k]], axis=1).max() for k in (0, 2, 3))
                held = np.concatenate(gs[:len(gs) - 4])
                drift = np.linalg.norm(X[held] - V[held], axis=1).max()
                tip, M = gs[-3], tt[-3]
                miss = np.linalg.norm(X[tip] - (V[tip] @ M[:3, :3].T + M[:3, 3]), axis=1).max()
                print(f"{cells} | {pins} | {w} | {d.cell_size:.4f} ({0.018 / d.cell_size:.2f}) | "
                      f"{100 * drag / size:.2f} | {100 * drift / size:.2f} | {100 * miss / 0.09:.1f}", flush=True)
                if a.transfer and w == "trilinear":
                    d.weights = "bspline"
                    X = d.solve(transforms=tt, iterations=0)
                    drag = max(np.linalg.norm(X[fingers[k]] - V[fingers[k]], axis=1).max() for k in (0, 2, 3))
                    print(f"{cells} | {pins} | B-spline of that pose | | {100 * drag / size:.2f} | |")


if __name__ == "__main__":
    main()
