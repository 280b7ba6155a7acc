"""Why the default stiffness is gamma = 0.03 (docs/method.md, "The default"): per gamma,
  1. pose quality on bench_quality's cases (LARAP only, converged, B-spline): volume change,
     handle error, drag of the parts that should stay, 95th percentile of the edge strain;
  2. the comb scaled to the cell at the tests' 17 sizes (tests/python/test_topology.py,
     comb_sweep): the neighbours' drag, median / worst / sizes within 1 %, and how far the held
     base drifts (the worse weight kind, 30 flip-flops); --comb-gap widens the gap between tines;
  3. a drag as the add-on makes it (5 flip-flops per ramp step) on each device asked for: how far
     the pose is from the converged one (the CPU's, 300 flip-flops to tol 1e-7) and the handle
     error, then after 30 flip-flops more.
Percentages are of the bounding-box diagonal (volume, edges: of the rest value).

Run from the checkout root (meshes from ../shared/data/meshes or LARAP_MESHES; missing ones are
skipped):
    PYTHONPATH=python /usr/bin/python3 scripts/experiments/gamma_default.py [--gammas 0.1 0.03 0.01]
        [--devices cpu cuda] [--skip quality comb drag]"""
import argparse
import os
import sys

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
REPO = os.path.dirname(os.path.dirname(HERE))
sys.path[:0] = [os.path.join(REPO, "scripts"), os.path.join(REPO, "python"), os.path.join(REPO, "tests", "python")]

import larap  # noqa: E402
from larap import quality  # noqa: E402
from report import api, cases  # noqa: E402
from report.quality_runs import FINAL_ITER, FINAL_TOL, LARAP_ITER, measure  # noqa: E402

CASES = {
    "bar_bend90": lambda: cases.bar_case("bend90"),
    "bar_twist180": lambda: cases.bar_case("twist180"),
    "hand_finger": cases.hand_case,
    "armadillo_arm": lambda: cases.armadillo_case("arm"),
}


def handles(V, groups):
    """What the handles are, as artists make them: vertex groups and their share of the mesh."""
    n = sum(len(g) for g in groups)
    return (f"{n:,} of {len(V):,} vertices ({100 * n / len(V):.0f}%) in {len(groups)} vertex groups, "
            f"the smallest {100 * min(len(g) for g in groups) / len(V):.1f}%")


def pct(x):
    return "" if x is None or not np.isfinite(x) else f"{100 * x:.2f}"  # nan: an open mesh's volume


def quality_rows(gammas):
    print("1. pose quality (converged, B-spline): volume % | handle error % | drag % | edge p95 %")
    for name, make in CASES.items():
        case = make()
        if case is None:
            print(f"{name}: skipped (mesh not found)")
            continue
        tris, diag = case.tris, quality.diagonal(case.V)
        edges = quality.edges(tris)
        print(f"{name}: handles {handles(case.V, case.groups)}")
        for g in gammas:
            kw = {"cells": case.cells} if case.cells else {}
            p = api.Posed(larap.Deformer(case.V, case.F, weights="bspline", gamma=g, **kw), case.V, case.groups)
            for T in case.steps[:-1]:
                p.solve(T, LARAP_ITER)
            r = measure(case, p.solve(case.final, FINAL_ITER, tol=FINAL_TOL), diag, tris, edges)
            print(f"{name} gamma={g}: {pct(r.get('volume_change'))} | {pct(r['handle_error'])} | "
                  f"{pct(r.get('drag'))} | {pct(r['edge_p95'])}", flush=True)


def comb_rows(gammas, gap=0.1):
    from larap.quality import diagonal
    from test_topology import SWEEP_SIZES, comb, comb_pose
    print(f"2. comb, 17 cell sizes (gap {gap} cell): drag median / worst / within 1 %, held base's drift (max)")
    for g in gammas:
        drags, drift = [], 0.0
        for h in SWEEP_SIZES:
            V, F, tine_ids, _ = comb(gap=gap * h)
            groups, T = comb_pose(V, tine_ids, moved=1)
            if g == gammas[0] and h == SWEEP_SIZES[0]:
                print(f"handles {handles(V, groups)}")
            drag = 0.0
            for weights in ("trilinear", "bspline"):
                d = larap.Deformer(V, F, cell_size=h, weights=weights, gamma=g)
                d.set_handle_groups(groups)
                X = d.solve(transforms=T, iterations=30)
                size = diagonal(V)
                drag = max([drag] + [np.linalg.norm(X[tine_ids[t]] - V[tine_ids[t]], axis=1).max() / size
                                     for t in (0, 2)])
                drift = max(drift, np.linalg.norm(X[groups[0]] - V[groups[0]], axis=1).max() / size)
            drags.append(drag)
        r = 100 * np.array(drags)
        print(f"gamma={g}: {np.median(r):.2f} / {r.max():.2f} / {(r <= 1.0).sum()} of {len(r)}, "
              f"base drift {100 * drift:.2f}", flush=True)


def drag_rows(gammas, devices):
    print("3. a drag of 5 flip-flops per step: distance to the converged pose % / handle error %, "
          "then after 30 flip-flops more")
    for name in ("bar_bend90", "hand_finger", "armadillo_arm"):
        case = CASES[name]()
        if case is None:
            print(f"{name}: skipped (mesh not found)")
            continue
        diag = quality.diagonal(case.V)
        print(f"{name}: handles {handles(case.V, case.groups)}")
        H = api.targets(case.V, case.groups, case.final)
        for g in gammas:
            kw = {"cells": case.cells} if case.cells else {}
            ref = api.Posed(larap.Deformer(case.V, case.F, gamma=g, **kw), case.V, case.groups)
            for T in case.steps:
                ref.solve(T, 5)
            Xc = ref.solve(case.final, 300, tol=1e-7)
            cols = []
            for dev in devices:
                p = api.Posed(larap.Deformer(case.V, case.F, gamma=g, device=dev, **kw), case.V, case.groups)
                for T in case.steps:
                    X = p.solve(T, 5)
                far = np.linalg.norm(X - Xc, axis=1).max() / diag
                err = np.linalg.norm(X[p.ids] - H, axis=1).max() / diag
                far30 = np.linalg.norm(p.solve(case.final, 30) - Xc, axis=1).max() / diag
                cols.append(f"{dev} {pct(far)} / {pct(err)}, then {pct(far30)}")
            print(f"{name} gamma={g}: " + " | ".join(cols), flush=True)


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--gammas", nargs="+", type=float, default=[0.1, 0.03, 0.01, 0.003])
    ap.add_argument("--devices", nargs="+", default=["cpu"], choices=["cpu", "cuda"])
    ap.add_argument("--skip", nargs="*", default=[], choices=["quality", "comb", "drag"])
    ap.add_argument("--comb-gap", type=float, default=0.1,
                    help="the tines' gap in cells (0.1: the tests'; 1 or more: no cell holds two tines)")
    args = ap.parse_args()
    if "quality" not in args.skip:
        quality_rows(args.gammas)
    if "comb" not in args.skip:
        comb_rows(args.gammas, args.comb_gap)
    if "drag" not in args.skip:
        drag_rows(args.gammas, args.devices)


if __name__ == "__main__":
    main()
