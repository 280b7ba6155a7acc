#!/usr/bin/env python3
"""Bind cost where cells split: `Deformer(V, F)` (lattice, cell splitting, binding; no handles, so
nothing else) on models whose cells are analysed, this tree against another checkout, each bind
in its own process, the two trees alternating, best of 3 binds per process. The models: a long
thin box of large triangles, rows of loose boxes 0.05 apart, the character of larap.shapes, a
1M-vertex torus, and the public meshes of ../shared when present. Prints a table (seconds, and this tree's over the
other's) and writes it as JSON with the machine.

Run: /usr/bin/python3 scripts/bench_bind.py --other CHECKOUT [--rounds 2] [--all-meshes] [--out FILE]"""
import argparse
import json
import os

import machine_info
from tree_child import run_child

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
SHARED = os.path.join(ROOT, "..", "shared", "data", "meshes")

CHILD = r'''
import json, sys, time
import larap
from larap import shapes
name = sys.argv[1]
kw = {}
if name == "thin box":
    V, F = shapes.box((0, 0, 0), (237.0, 0.9, 0.9), 8)
    kw = {"cell_size": 0.5}
elif name.startswith("boxes "):
    parts = []
    for k in range(int(name.split()[1])):
        x = 0.95 * k
        parts.append(shapes.box((x, 0.0, 0.0), (x + 0.9, 0.9, 0.9), 2))
    V, F = shapes.concat(*parts)
    kw = {"cell_size": 0.5}
elif name == "character":
    if not hasattr(shapes, "character"):  # a checkout older than it (bf2125a, before issue 9)
        print(json.dumps({"missing": "larap.shapes.character"}))
        sys.exit(0)
    V, F, _ = shapes.character()
elif name == "torus":
    V, F = shapes.torus(1.0, 0.35, 1414, 707)
else:
    V, F = larap.load_mesh(name)
binds = []
for _ in range(3):
    t0 = time.perf_counter(); d = larap.Deformer(V, F, **kw); binds.append(time.perf_counter() - t0)
print(json.dumps({"vertices": len(V), "cells": d.num_cells, "nodes": d.num_nodes, "bind_s": min(binds)}))
'''

MODELS = [("thin box", "a 237 x 0.9 x 0.9 box, 386 vertices, cell 0.5"),
          ("boxes 250", "250 boxes 0.9 wide, 0.05 apart, cell 0.5"),
          ("boxes 2000", "2,000 boxes 0.9 wide, 0.05 apart, cell 0.5"),
          ("character", "larap.shapes.character(), default lattice"),
          ("torus", "torus of 1M vertices, default lattice")]


def main():
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--other", required=True, help="the checkout to compare with, built (its python/ is used)")
    p.add_argument("--rounds", type=int, default=2, help="alternations of the two trees per model")
    p.add_argument("--out", default=os.path.join(ROOT, "build", "bench_bind.json"))
    p.add_argument("--all-meshes", action="store_true",
                   help="every public mesh of ../shared (default: suzanne, truck and woody)")
    a = p.parse_args()
    models = list(MODELS)
    if os.path.isdir(SHARED):
        names = ("suzanne.obj", "truck.obj", "woody.obj")
        if a.all_meshes:
            names = sorted(n for n in os.listdir(SHARED) if n.endswith((".obj", ".off", ".ply", ".stl")))
        for name in names:
            path = os.path.join(SHARED, name)
            if os.path.exists(path):
                models.append((path, name + ", default lattice"))
    rows = []
    print("| model | vertices | cells | nodes | other: bind s | this tree: bind s | ratio |")
    print("|---|---|---|---|---|---|---|")
    for model, label in models:
        mine, other = [], []
        for _ in range(a.rounds):
            other.append(run_child(a.other, CHILD, model))
            mine.append(run_child(ROOT, CHILD, model))
        m = min(r["bind_s"] for r in mine)
        o = None if "missing" in other[0] else min(r["bind_s"] for r in other)
        rows.append({"model": label, **mine[0], "bind_s": m, "other_bind_s": o})
        other_s, ratio = ("(no " + other[0]["missing"] + ")", "") if o is None else (f"{o:.3f}", f"{m / o:.2f}")
        print(f"| {label} | {mine[0]['vertices']:,} | {mine[0]['cells']:,} | {mine[0]['nodes']:,} | "
              f"{other_s} | {m:.3f} | {ratio} |", flush=True)
    os.makedirs(os.path.dirname(a.out), exist_ok=True)
    with open(a.out, "w") as f:
        json.dump({"machine": machine_info.describe(), "other": os.path.abspath(a.other), "rows": rows}, f, indent=1)
    print("written", a.out)


if __name__ == "__main__":
    main()
