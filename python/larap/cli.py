"""Command line: python3 -m larap deform IN --handles H.json --out OUT [options]
                 python3 -m larap demo [--out demo.obj]
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import time

import numpy as np

from . import shapes
from .deformer import DEFAULT_GAMMA, DEFAULT_JUNCTION_BRACE, Deformer, available_devices
from .handles import HandleError, flatten, load_handles, parse_handles
from .io import load_mesh, save_mesh

DEMO_HANDLES = {
    "handles": [
        {"name": "base", "box": {"min": [-1, -1, -1], "max": [0.45, 1, 1]}},
        {"name": "tip", "box": {"min": [3.55, -1, -1], "max": [5, 1, 1]},
         "transform": {"rotate": {"axis": [0, 0, 1], "angle": 90}, "pivot": [2.0, 0.424, 0.0]}},
    ]
}


def _add_solver_args(p):
    res = p.add_mutually_exclusive_group()
    res.add_argument("--cells", type=int, help="approximate number of lattice cells (default ~6000)")
    res.add_argument("--cell-size", type=float, help="lattice cell edge length")
    p.add_argument("--weights", choices=["trilinear", "bspline"], default="bspline",
                   help="vertex weights (default bspline: C1, final quality)")
    p.add_argument("--gamma", type=float, default=DEFAULT_GAMMA,
                   help=f"rigidity, scale-free (default {DEFAULT_GAMMA:g})")
    p.add_argument("--iterations", type=int, default=30, help="flip-flop iterations (default 30)")
    p.add_argument("--device", choices=["cpu", "cuda", "auto"], default="auto")
    p.add_argument("--levels", type=int, default=1,
                   help="lattice levels solved coarse to fine (default 1: the fine lattice alone)")
    p.add_argument("--no-split-cells", dest="split_cells", action="store_false",
                   help="keep the plain lattice: do not keep a cell once per connected piece inside it")
    p.add_argument("--split-resolution", type=int, default=24,
                   help="voxels per cell edge that decide the pieces of a cell (default 24)")
    p.add_argument("--junction-brace", type=float, default=DEFAULT_JUNCTION_BRACE,
                   help="weight of the braces where the solid branches inside a cell "
                        f"(default {DEFAULT_JUNCTION_BRACE:g}; 0: none)")


def _deform(V, F, groups, args, out_path, template=None):
    idx, targets = flatten(groups)
    t0 = time.perf_counter()
    d = Deformer(V, F, cells=args.cells, cell_size=args.cell_size, weights=args.weights,
                 gamma=args.gamma, device=args.device, levels=args.levels,
                 split_cells=args.split_cells, split_resolution=args.split_resolution,
                 junction_brace=args.junction_brace)
    # Each group of the file is a handle group; one transform per group when every group has
    # one, else the same targets vertex by vertex.
    d.set_handle_groups([g.vertices for g in groups], weights=[g.weight for g in groups])
    if groups and all(g.transform is not None for g in groups):
        X = d.solve(transforms=np.stack([g.transform for g in groups]), iterations=args.iterations)
    else:
        X = d.solve(targets, iterations=args.iterations)
    wall = (time.perf_counter() - t0) * 1e3
    s = d.stats
    err = np.linalg.norm(X[idx] - targets, axis=1).max() / d.diagonal if len(idx) else 0.0
    save_mesh(out_path, X, F, template=template)
    e = s["energy"]
    print(f"larap: {d.num_vertices} vertices, {d.num_nodes} nodes ({d.num_cells} cells of "
          f"{d.cell_size:.4g}), {len(idx)} handle vertices in {len(groups)} groups, {d.weights} on {d.device} | "
          f"ms: lattice {s['ms_lattice']:.1f}, binding {s['ms_binding']:.1f}, factorize "
          f"{s['ms_factorize']:.1f}, {s['iterations']} iterations: rotations {s['ms_rotations']:.1f} "
          f"rhs {s['ms_rhs']:.1f} solve {s['ms_solve']:.1f}, transfer {s['ms_transfer']:.1f}, "
          f"total {wall:.0f} | energy {e[0] if e else 0:.3g} -> {e[-1] if e else 0:.3g}, "
          f"max handle error {100 * err:.2f}% of diagonal | wrote {out_path}")
    return X, d


def cmd_deform(args):
    if not os.path.exists(args.input):
        raise FileNotFoundError(f"{args.input}: no such file")
    V, F = load_mesh(args.input)
    groups = load_handles(args.handles, V)
    template = args.input if args.input.lower().endswith(".obj") and args.out.lower().endswith(".obj") else None
    _deform(V, F, groups, args, args.out, template)


def cmd_demo(args):
    V, F = shapes.tube(length=4.0, radius=0.5, segments=48, rings=96)
    groups = parse_handles(DEMO_HANDLES, V)
    print(f"larap demo: a tube of {len(V)} vertices, base fixed, tip turned 90 degrees "
          f"(handles: {json.dumps(DEMO_HANDLES)})")
    _deform(V, F, groups, args, args.out)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="python3 -m larap", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = parser.add_subparsers(dest="command", required=True)
    p = sub.add_parser("deform", help="deform a mesh file by a handle file")
    p.add_argument("input", help="mesh: .obj, .ply or .off")
    p.add_argument("--handles", required=True, help="handle groups, JSON (see README)")
    p.add_argument("--out", required=True, help="output mesh (.obj keeps the input OBJ's UVs, normals, groups)")
    _add_solver_args(p)
    p.set_defaults(func=cmd_deform)
    p = sub.add_parser("demo", help="bend a generated tube 90 degrees and write it")
    p.add_argument("--out", default="larap-demo.obj")
    _add_solver_args(p)
    p.set_defaults(func=cmd_demo)
    p = sub.add_parser("devices", help="list the usable devices")
    p.set_defaults(func=lambda a: print(" ".join(available_devices())))
    args = parser.parse_args(argv)
    try:
        args.func(args)
    except (HandleError, ValueError, TypeError, FileNotFoundError, OSError, MemoryError, RuntimeError) as exc:
        print(f"larap: error: {exc}", file=sys.stderr)
        return 2
    return 0
