#!/usr/bin/env python3
"""Pose quality beside surface ARAP (issue 9): volume change, edge-length distortion (mean and
95th percentile), handle error and the drag of parts that should stay, for a 90° bar bend, a 180°
twist, a finger bend (hand_lowres.obj; palm held up to the fingers as in the issue, and with a
free band of palm) and a limb bend (armadillo.obj's elbow bent 80°), plus two
bars closer than a cell (one bent, the other held).

Same meshes, same handle groups (as an artist makes them), same targets for every method:
  - LARAP with the default lattice (cell splitting on, B-spline transfer), converged;
  - LARAP with split_cells=False (the lattice before issue 9), for comparison;
  - surface ARAP on the full mesh: CGAL's Surface_mesh_deformation (Debian's libcgal-dev),
    compiled by this script into a build folder only (scripts/peers), never linked into LARAP.
The poses ramp in steps as an artist drags (scripts/report/cases.py). Percentages are of the
model's bounding-box diagonal (handle error, drag) or of the rest value (volume, edges).

Run:  /usr/bin/python3 scripts/bench_quality.py [--cases bar_bend90 ...] [--csv FILE] [--record docs/results.md]
The hand and armadillo need ../shared/data/meshes (or LARAP_MESHES); they are skipped, with a
note, when it is absent. Prints a table and the targets, met or missed."""
from __future__ import annotations

import argparse
import os
import sys
import time

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
for p in (HERE, os.path.join(ROOT, "python")):
    if p not in sys.path:
        sys.path.insert(0, p)

import numpy as np  # noqa: E402

import larap  # noqa: E402
from larap import quality  # noqa: E402
from peers import surface_arap  # noqa: E402
from report import api, cases, table  # noqa: E402
from report.quality_runs import CGAL_ITER, CGAL_TOL, FINAL_ITER, FINAL_TOL, LARAP_ITER, measure  # noqa: E402

CASES = {
    "bar_bend90": lambda: cases.bar_case("bend90"),
    "bar_twist180": lambda: cases.bar_case("twist180"),
    "hand_finger": cases.hand_case,
    "hand_finger_free_palm": lambda: cases.hand_case(palm_top=0.40),
    "armadillo_arm": lambda: cases.armadillo_case("arm"),
    "two_bars": cases.two_bars_case,
}
NEEDS = {"hand_finger": "hand_lowres.obj", "hand_finger_free_palm": "hand_lowres.obj", "armadillo_arm": "armadillo.obj"}


def run_larap(case, split_cells):
    kw = {"cells": case.cells} if case.cells else {}
    d = larap.Deformer(case.V, case.F, weights="bspline", split_cells=split_cells, **kw)
    p = api.Posed(d, case.V, case.groups)
    for T in case.steps[:-1]:
        p.solve(T, LARAP_ITER)
    t0 = time.perf_counter()
    X = p.solve(case.final, FINAL_ITER, tol=FINAL_TOL)
    return X, dict(nodes=d.num_nodes, cells=d.num_cells, ms=(time.perf_counter() - t0) * 1e3)


def run_case(case, exe):
    tris, diag = case.tris, quality.diagonal(case.V)
    edge_list = quality.edges(tris)
    base = dict(case=case.name, vertices=len(case.V), handles=case.handle_count,
                handle_share=case.handle_count / len(case.V), groups=len(case.groups))
    rows = []
    for method, split in (("larap", True), ("larap_split_off", False)):
        X, info = run_larap(case, split)
        rows.append(dict(base, method=method, **info, **measure(case, X, diag, tris, edge_list)))
    if exe is None:
        return rows
    poses = [api.targets(case.V, case.groups, T) for T in case.steps]
    res = surface_arap.deform(exe, case.V, tris, np.concatenate(case.groups), poses, CGAL_ITER, CGAL_TOL, timeout=900)
    if res.get("ok"):
        rows.append(dict(base, method="surface_arap", ms=res["pose_ms"][-1],
                         **measure(case, res["X"][-1], diag, tris, edge_list)))
    else:
        rows.append(dict(base, method="surface_arap", error=res.get("error", "failed")))
    return rows


def pct(x, signed=False):
    if x is None or x == "" or np.isnan(table.num(x)):
        return ""
    return f"{100 * table.num(x):+.2f}%" if signed else f"{100 * table.num(x):.2f}%"


def targets(rows):
    """The issue's targets, from the rows: (target, measured, verdict)."""
    by = {(r["case"], r["method"]): r for r in rows}
    out = []

    def vol(case, method):
        r = by.get((case, method))
        return None if r is None or "volume_change" not in r else abs(r["volume_change"])

    a, s = vol("bar_bend90", "larap"), vol("bar_bend90", "surface_arap")
    if a is not None and s is not None:
        out.append(("90° bar bend: volume change (absolute) at most a third of surface ARAP's",
                    f"{100 * a:.2f}% vs {100 * s:.2f}%", "met" if a <= s / 3 else "missed"))
    a, s = vol("armadillo_arm", "larap"), vol("armadillo_arm", "surface_arap")
    if a is not None and s is not None:
        out.append(("limb bend: volume change (absolute) no larger than surface ARAP's",
                    f"{100 * a:.2f}% vs {100 * s:.2f}%", "met" if a <= s else "missed"))
    r, q = by.get(("hand_finger", "larap")), by.get(("hand_finger", "surface_arap"))
    if r is not None and "drag" in r:
        peer = f"; surface ARAP {100 * q['drag']:.2f}%" if q is not None and "drag" in q else ""
        out.append(("neighbouring fingers dragged at most 1% of the hand",
                    f"LARAP {100 * r['drag']:.2f}%{peer}", "met" if r["drag"] <= 0.01 else "missed"))
    return out


def markdown(rows, skipped, header):
    cols = ("case", "method", "vertices", "handles", "nodes", "volume_change", "edge_mean", "edge_p95",
            "handle_error", "drag")
    lines = [header, "", "| " + " | ".join(cols) + " |", "|" + "---|" * len(cols)]
    for r in rows:
        cells = []
        for c in cols:
            v = r.get(c, "")
            if c in ("volume_change", "edge_mean", "edge_p95", "handle_error", "drag"):
                cells.append(pct(v, signed=(c == "volume_change")))
            elif c == "handles" and v != "":
                cells.append(f"{v:,} ({100 * r['handle_share']:.0f}%)")
            elif c == "method" and "error" in r:
                cells.append(f"{v} (failed: {r['error']})")
            else:
                cells.append(f"{v:,}" if isinstance(v, int) else str(v))
        lines.append("| " + " | ".join(cells) + " |")
    lines += ["", "| target | measured | verdict |", "|---|---|---|"]
    lines += [f"| {t} | {m} | **{v}** |" for t, m, v in targets(rows)]
    if skipped:
        lines += ["", "Skipped: " + "; ".join(skipped)]
    return "\n".join(lines) + "\n"


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cases", nargs="+", choices=sorted(CASES), default=list(CASES))
    ap.add_argument("--csv", default="", help="write the rows to this CSV file")
    ap.add_argument("--record", default="", help="append the table to this Markdown file (e.g. docs/results.md)")
    ap.add_argument("--build", default=os.path.join(ROOT, "build-evidence"), help="where the CGAL peer is compiled")
    args = ap.parse_args()

    try:
        exe = surface_arap.build(args.build)
    except RuntimeError as e:
        exe = None
        print(f"surface ARAP skipped: {e}", file=sys.stderr)
    rows, skipped = [], [] if exe is not None else ["surface ARAP (CGAL could not be built)"]
    for name in args.cases:
        case = CASES[name]()
        if case is None:
            skipped.append(f"{name}: {NEEDS.get(name, 'its mesh')} not found (../shared/data/meshes or LARAP_MESHES)")
            continue
        print(f"{name}: {len(case.V):,} vertices, {case.handle_count:,} handle vertices in {len(case.groups)} groups",
              file=sys.stderr, flush=True)
        rows += run_case(case, exe)
    m = table.machine()
    header = (f"## {m['date']}: pose quality beside surface ARAP (scripts/bench_quality.py)\n\n"
              f"{m['cpu']}, {m['cores']} cores, load {m['load']}, device cpu; LARAP converged "
              f"({FINAL_ITER} flip-flops at most, tol {FINAL_TOL:g}), surface ARAP {CGAL_ITER} iterations "
              f"(tol {CGAL_TOL:g}) per step; poses ramped in steps. Volume and edges: % of the rest value; "
              f"handle error and drag: % of the bounding-box diagonal.")
    text = markdown(rows, skipped, header)
    print(text)
    if args.csv:
        table.write_csv(args.csv, rows)
    if args.record:
        with open(args.record, "a") as f:
            f.write("\n" + text)


if __name__ == "__main__":
    main()
