#!/usr/bin/env python3
"""Where a fused flip-flop's time goes on the GPU: the device time of each grid-wide phase of the
fused cooperative kernel (the product's path), beside the flip-flops and milliseconds to quality,
for variants of the CUDA options measured side by side in one run (docs/results-gpu.md).

Run on a machine with a GPU, from the repository root, after building with -DLARAP_CUDA=ON:
    PYTHONPATH=python python3 scripts/bench_fused_phases.py --out phases.json \\
        --configs 1700000:10000 --variant mg1:LARAP_CUDA_INNER=1 --variant mg2:LARAP_CUDA_INNER=2

The meshes, handles and moves are bench_gpu.py's: ellipsoids, two vertex groups holding every
vertex of each end (about a third of the vertices), a warm pose and then the handle move; quality
is the energy within 0.1% of the CPU direct solve's after 30 flip-flops. The phase times come
from LARAP_CUDA_PHASES (native/cuda/cuda_options.h): one thread's clock64() after each grid-wide
barrier, so a phase's time is its slowest block's plus the barrier. The milliseconds to quality
come from separate solves without the stamps (flip-flops to quality x the device time per
flip-flop of a 60-flip-flop solve). Variants are interleaved, rounds times.
"""
from __future__ import annotations

import argparse
import datetime
import json
import os
import subprocess
import sys
import tempfile

import numpy as np

import larap

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import machine_info  # noqa: E402
from bench_gpu import aim_cells, ellipsoid, first_within, gpu_warmup, handles_and_targets, make, pose, set_env  # noqa: E402

OPTION_VARS = ("LARAP_CUDA_SOLVER", "LARAP_CUDA_INNER", "LARAP_CUDA_MG_LEVELS", "LARAP_CUDA_MG_COARSE",
               "LARAP_CUDA_COOP_BLOCKS", "LARAP_CUDA_EXACT_RESIDUAL")


def phase_names(levels, inner):
    """In kernel order; "final" is the final update's phase: where the update is left to the next
    flip-flop (all but a launch's last) it only reads alpha, with no update and no barrier."""
    per = ["a", "a1", "coarse", "b1", "c", "d"] if levels == 3 else ["a", "coarse", "c", "d"]
    return ["rotations", "rhs"] + [f"{p}{k}" for k in range(inner) for p in per] + ["final"]


def parse_variant(spec):
    name, _, rest = spec.partition(":")
    env = {}
    for kv in filter(None, rest.split(",")):
        k, _, v = kv.partition("=")
        if k not in OPTION_VARS:
            raise SystemExit(f"--variant {spec}: {k} is not one of {', '.join(OPTION_VARS)}")
        env[k] = v
    return name, env


def measure(dg, h, T1, T2, env, E_ref, out32, path):
    set_env(**{k: env.get(k) for k in OPTION_VARS})
    dg.set_handle_groups(h)  # the backend reads its options again here
    gpu_warmup(dg, T1, out32, seconds=0.3)
    dg.reset()
    pose(dg, T1, 30, out32)
    pose(dg, T2, 60, out32)
    ms_per_ff = dg.stats["ms_solve"] / 60
    n_star = first_within(dg.stats["energy"], E_ref)
    dg.reset()
    pose(dg, T1, 30, out32)
    set_env(LARAP_CUDA_PHASES=path)
    dg.set_handle_groups(h)
    gpu_warmup(dg, T1, out32, seconds=0.3)  # stamped too; the record read is the last solve's
    dg.reset()
    pose(dg, T1, 30, out32)
    pose(dg, T2, 60, out32)
    set_env(LARAP_CUDA_PHASES=None)
    res = {"ff_to_quality": n_star, "us_per_ff": 1e3 * ms_per_ff,
           "ms_to_quality": None if n_star is None else n_star * ms_per_ff}
    if not os.path.exists(path):  # a build without LARAP_CUDA_PHASES (an older tree, to compare)
        return res
    with open(path) as f:
        rec = [json.loads(line) for line in f if line.strip()][-1]
    os.remove(path)
    us = [c / rec["clock_khz"] * 1e3 for c in rec["cycles"]]
    res.update(levels=rec["levels"], inner=rec["inner"], blocks=rec["blocks"], phase_us=us,
               stamped_us_per_ff=sum(us))
    return res


def run_config(faces, nodes, variants, rounds):
    V, F = ellipsoid(faces)
    cells, dc = aim_cells(V, F, nodes)
    h, T1, T2 = handles_and_targets(V)
    out32 = np.empty(V.shape, np.float32)
    dc.set_handle_groups(h)
    pose(dc, T1, 30, out32)
    pose(dc, T2, 30, out32)
    E_ref = dc.stats["energy"][-1]
    res = {"faces": int(len(F)), "vertices": int(len(V)), "nodes": dc.num_nodes, "cells": dc.num_cells,
           "handle_vertices": int(sum(len(g) for g in h)), "handle_groups": len(h), "runs": {}}
    del dc
    dg = make(V, F, cells, "cuda")
    path = os.path.join(tempfile.mkdtemp(), "phases.jsonl")
    for r in range(rounds):
        for name, env in variants:
            res["runs"].setdefault(name, []).append(measure(dg, h, T1, T2, env, E_ref, out32, path))
    set_env(**{k: None for k in OPTION_VARS})
    return res


def table(res):
    names = list(res["runs"])
    print(f"\n{res['faces']:,} faces, {res['vertices']:,} vertices, {res['nodes']:,} nodes, "
          f"{res['handle_vertices']:,} handle vertices in {res['handle_groups']} groups")
    first = {n: res["runs"][n][0] for n in names}
    print("| | " + " | ".join(names) + " |")
    print("|---|" + "---|" * len(names))

    def row(label, f):
        print(f"| {label} | " + " | ".join(" / ".join(f(r) for r in res["runs"][n]) for n in names) + " |")

    row("flip-flops to quality", lambda r: str(r["ff_to_quality"]))
    row("us per flip-flop (60, unstamped)", lambda r: f"{r['us_per_ff']:.1f}")
    row("ms to quality", lambda r: "-" if r["ms_to_quality"] is None else f"{r['ms_to_quality']:.3f}")
    stamped = [n for n in names if "phase_us" in first[n]]
    if not stamped:
        return
    row("stamped phases, us per flip-flop", lambda r: f"{r['stamped_us_per_ff']:.1f}" if "phase_us" in r else "-")
    labels = []  # every variant's phases, in kernel order (two and three levels interleave)
    for n in stamped:
        at = -1
        for label in phase_names(first[n]["levels"], first[n]["inner"]):
            if label in labels:
                at = labels.index(label)
            else:
                at += 1
                labels.insert(at, label)
    for k, label in enumerate(labels):
        def cell(r, k=k, label=label):
            if "phase_us" not in r:
                return "-"
            own = phase_names(r["levels"], r["inner"])
            return f"{r['phase_us'][own.index(label)]:.2f}" if label in own else "-"
        row(f"phase {label}, us", cell)


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--configs", default="1700000:10000,2000000:40000", help="faces:nodes,...")
    ap.add_argument("--variant", action="append", default=[],
                    help="NAME:VAR=VALUE,... (LARAP_CUDA_* options); default: mg1 and mg2")
    ap.add_argument("--rounds", type=int, default=2)
    ap.add_argument("--out", default="phases.json")
    a = ap.parse_args()
    for k in [k for k in os.environ if k.startswith("LARAP_CUDA_")]:  # only the variants' options
        del os.environ[k]
    variants = [parse_variant(v) for v in a.variant] or [("mg1", {"LARAP_CUDA_INNER": "1"}),
                                                          ("mg2", {"LARAP_CUDA_INNER": "2"})]
    try:
        gpu = subprocess.run(["nvidia-smi", "--query-gpu=name,driver_version", "--format=csv,noheader"],
                             capture_output=True, text=True, check=False).stdout.strip()
    except OSError:
        gpu = "?"
    meta = {"date": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"), "gpu": gpu,
            "machine": machine_info.describe(), "larap": os.path.dirname(larap.__file__),
            "variants": {n: e for n, e in variants}}
    print(json.dumps(meta))
    results = []
    for spec in a.configs.split(","):
        faces, nodes = (int(x) for x in spec.split(":")[:2])
        res = run_config(faces, nodes, variants, a.rounds)
        table(res)
        results.append(res)
    with open(a.out, "w") as f:
        json.dump({"meta": meta, "results": results}, f, indent=1)


if __name__ == "__main__":
    main()
