#!/usr/bin/python3
"""Benchmark: what a pose costs as the handles grow, through the public API, with handles as an
artist makes them (vertex groups, each moved by one transform).

    PYTHONPATH=python /usr/bin/python3 scripts/bench_handles.py [--device cpu|cuda] [--record FILE]

Table 1 (the handle-group issue's check): one mesh and lattice, 4 (or --groups) groups holding
few vertices against the same regions holding many; a pose = 5 flip-flop iterations from a warm
start after a move of every group, plus the transfer into a float32 host array (on CUDA also
the time with the positions left on the device). Medians of --repeat poses, all in one run, so
compare the ratios. --mid N adds a row of N vertices per group (e.g. 10% of the mesh in all).
On CUDA, --copy compares the ways the result reaches the host array (LARAP_CUDA_COPY[:chunk],
docs/cuda.md) on the 'many' row. Table 2 (--quality): time to quality, the milliseconds until
the energy is within 0.1% of the converged energy, at a few lattice sizes; the converged energy
comes from the CPU backend (--reference cpu) or from a long solve on the benchmarked device
(--reference device: 3000 flip-flops, for lattices where the CPU's direct solver is too slow).
Faces: the tube's quads split into triangles unless --quads.
"""
from __future__ import annotations

import argparse
import datetime
import os
import platform
import statistics
import time

import numpy as np

import larap
from larap import shapes


def tube_with_vertices(n_wanted: int, triangles: bool = True):
    """A closed tube (length 8, radius 0.5) of about n_wanted vertices; quads split into two
    triangles each when `triangles`."""
    segments = max(16, int(np.sqrt(n_wanted / 16.0) * 2))
    rings = max(16, n_wanted // segments)
    V, F = shapes.tube(length=8.0, radius=0.5, segments=segments, rings=rings)
    if not triangles:
        return V, F
    quads = np.array([f for f in F if len(f) == 4], np.int64)
    tris = [np.array([f for f in F if len(f) == 3], np.int64), quads[:, [0, 1, 2]], quads[:, [0, 2, 3]]]
    return V, np.concatenate(tris)


def regions(V, groups: int, per_group: int | None):
    """`groups` slabs along the tube; each holds `per_group` vertices (evenly picked) or all of
    the slab's vertices (None)."""
    x = V[:, 0]
    edges = np.linspace(x.min(), x.max(), 2 * groups + 1)
    out = []
    for g in range(groups):
        lo, hi = edges[2 * g], edges[2 * g] + 0.8 * (edges[2 * g + 1] - edges[2 * g])
        ids = np.flatnonzero((x >= lo) & (x <= hi))
        if per_group is not None:
            ids = ids[np.linspace(0, len(ids) - 1, per_group).round().astype(int)]
        out.append(ids)
    return out


def transforms(V, groups, step):
    """Every group turned a little about z around its centre and lifted: a new pose per step."""
    T = np.tile(np.eye(4), (len(groups), 1, 1))
    for g, ids in enumerate(groups):
        c = V[ids].mean(0)
        a = np.radians(2.0 * step * (g - (len(groups) - 1) / 2))
        R = np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]])
        T[g, :3, :3] = R
        T[g, :3, 3] = c - R @ c + [0, 0, 0.01 * step * g]
    return T


def time_poses(d, V, groups, repeat, device):
    out = np.empty((len(V), 3), np.float32)
    host, dev, start = [], [], []
    for r in range(repeat + 2):
        T = transforms(V, groups, r + 1)
        t0 = time.perf_counter()
        d.solve(transforms=T, iterations=5, out=out)
        ms = (time.perf_counter() - t0) * 1e3
        if r >= 2:  # the first poses warm caches up
            host.append(ms)
            start.append(d.stats["ms_start"])
        if device == "cuda":
            T = transforms(V, groups, r + 1.5)
            t0 = time.perf_counter()
            d.solve_on_device(transforms=T, iterations=5)
            ms = (time.perf_counter() - t0) * 1e3
            if r >= 2:
                dev.append(ms)
    med = statistics.median
    return med(host), (med(dev) if dev else float("nan")), med(start)


def table_handles(args):
    V, F = tube_with_vertices(args.vertices, not args.quads)
    t0 = time.perf_counter()
    d = larap.Deformer(V, F, cells=args.cells, device=args.device)
    t_bind = (time.perf_counter() - t0) * 1e3
    rows = []
    sizes = [("few", args.few)] + ([("mid", args.mid)] if args.mid else []) + [("many", None)]
    for label, per in sizes:
        groups = regions(V, args.groups, per)
        t0 = time.perf_counter()
        d.set_handle_groups(groups)
        t_set = (time.perf_counter() - t0) * 1e3
        host, dev, start = time_poses(d, V, groups, args.repeat, args.device)
        m = sum(len(g) for g in groups)
        rows.append(dict(label=label, handles=m, share=100.0 * m / len(V), set_ms=t_set, host=host, dev=dev, start=start))
    print(f"\n{len(V)} vertices, {len(F)} faces, {d.num_nodes} nodes ({d.num_cells} cells), "
          f"device {d.device}, bind {t_bind:.0f} ms, {args.groups} groups, 5 iterations")
    print(f"{'handles':>22} | {'set_handle_groups ms':>20} | {'pose into host ms':>17} | {'pose on device ms':>17} | {'warm start ms':>13}")
    for r in rows:
        print(f"{r['label']:>5} {r['handles']:>8} ({r['share']:4.1f}%) | {r['set_ms']:20.1f} | {r['host']:17.2f} | "
              f"{r['dev']:17.3f} | {r['start']:13.3f}")
    ratio = rows[-1]["host"] / rows[0]["host"]
    print(f"ratio many/few (into host): {ratio:.3f}")
    copies = []
    if args.device == "cuda" and args.copy:
        groups = regions(V, args.groups, None)
        for spec in args.copy.split(","):
            mode, _, chunk = spec.partition(":")
            os.environ["LARAP_CUDA_COPY"] = mode
            if chunk:
                os.environ["LARAP_CUDA_COPY_CHUNK"] = chunk
            else:
                os.environ.pop("LARAP_CUDA_COPY_CHUNK", None)
            d.set_handle_groups(groups)  # the backend reads its options here
            out = np.empty((len(V), 3), np.float32)
            host, transfer = [], []
            for r in range(args.repeat + 2):
                d.solve(transforms=transforms(V, groups, r + 1), iterations=5, out=out)  # warm
                T = transforms(V, groups, r + 1.5)  # outside the timing (the group means cost ms)
                t0 = time.perf_counter()
                d.solve(transforms=T, iterations=5, out=out)
                ms = (time.perf_counter() - t0) * 1e3
                if r >= 2:
                    host.append(ms)
                    transfer.append(d.stats["ms_transfer"])
            ref = d.solve_on_device(transforms=transforms(V, groups, 9), iterations=0)
            del ref
            X = d.solve(transforms=transforms(V, groups, 9), iterations=0, out=out)
            copies.append(dict(spec=spec, host=statistics.median(host), transfer=statistics.median(transfer),
                               finite=bool(np.isfinite(X).all())))
        os.environ.pop("LARAP_CUDA_COPY", None)
        os.environ.pop("LARAP_CUDA_COPY_CHUNK", None)
        d.set_handle_groups(groups)
        print(f"\ncopy into the host array ('many' row, float32, {len(V)} vertices = {12 * len(V) / 1e6:.1f} MB)")
        print(f"{'LARAP_CUDA_COPY[:chunk]':>24} | {'pose into host ms':>17} | {'ms_transfer':>11}")
        for c in copies:
            print(f"{c['spec']:>24} | {c['host']:17.3f} | {c['transfer']:11.3f}" + ("" if c["finite"] else "  NOT FINITE"))
    return len(V), len(F), d.num_nodes, rows, ratio, copies


def time_to_quality(args, cells):
    V, F = tube_with_vertices(args.vertices, not args.quads)
    groups = regions(V, args.groups, None)
    d = larap.Deformer(V, F, cells=cells, device=args.device)
    d.set_handle_groups(groups)
    T0, T1 = transforms(V, groups, 1), transforms(V, groups, 4)
    if args.reference == "cpu":
        ref = larap.Deformer(V, F, cells=cells, device="cpu")
        ref.set_handle_groups(groups)
        ref.solve(transforms=T0, iterations=200, tol=1e-10)
        ref.solve(transforms=T1, iterations=500, tol=1e-12)
        converged = ref.stats["energy"][-1]
    else:  # a long solve on the device itself
        d.solve(transforms=T0, iterations=200)
        d.solve(transforms=T1, iterations=3000)
        converged = min(d.stats["energy"])
    target = converged * 1.001
    for its in (1, 2, 3, 5, 8, 12, 20, 30, 50, 80, 120, 200):
        d.reset()
        d.solve(transforms=T0, iterations=60)
        out = np.empty((len(V), 3), np.float32)
        t0 = time.perf_counter()
        d.solve(transforms=T1, iterations=its, out=out)
        ms = (time.perf_counter() - t0) * 1e3
        if d.stats["energy"][-1] <= target:
            return d.num_nodes, its, ms, len(d.handles)
    return d.num_nodes, None, float("nan"), len(d.handles)


def main():
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--device", default="cpu", choices=["cpu", "cuda"])
    p.add_argument("--vertices", type=int, default=1_000_000)
    p.add_argument("--cells", type=int, default=7700, help="about 10k nodes on the default tube")
    p.add_argument("--groups", type=int, default=4)
    p.add_argument("--few", type=int, default=100, help="vertices per group in the 'few' row")
    p.add_argument("--mid", type=int, default=0, help="vertices per group in a middle row (0: none)")
    p.add_argument("--quads", action="store_true", help="keep the tube's quads (default: triangles)")
    p.add_argument("--copy", default="overlap:65536,overlap:262144,staged:262144,direct",
                   help="CUDA: LARAP_CUDA_COPY[:chunk] variants to compare ('' = none)")
    p.add_argument("--reference", default="cpu", choices=["cpu", "device"],
                   help="where the converged energy of the time-to-quality table comes from")
    p.add_argument("--repeat", type=int, default=7)
    p.add_argument("--quality", default="", help="comma-separated cell counts for the time-to-quality table")
    p.add_argument("--record", default="", help="append the tables (Markdown) to this file")
    args = p.parse_args()
    n, f, nodes, rows, ratio, copies = table_handles(args)
    quality = []
    for cells in [int(c) for c in args.quality.split(",") if c]:
        quality.append(time_to_quality(args, cells))
        nn, its, ms, m = quality[-1]
        print(f"time to quality (0.1% of converged energy, reference {args.reference}), {nn} nodes, "
              f"{m} handle vertices in {args.groups} groups: {its} iterations, {ms:.2f} ms into a host array", flush=True)
    if args.record:
        when = datetime.date.today().isoformat()
        with open(args.record, "a") as fh:
            fh.write(f"\n### Pose cost against handle count ({when}, {platform.node() or 'host'}, {args.device}, "
                     f"{os.cpu_count()} cores)\n\n")
            fh.write(f"{n} vertices, {f} faces, {nodes} nodes, {args.groups} groups, 5 iterations, medians of {args.repeat}.\n\n")
            fh.write("| handle vertices | share | set_handle_groups (ms) | pose into host (ms) | pose on device (ms) |\n|---|---|---|---|---|\n")
            for r in rows:
                fh.write(f"| {r['handles']} | {r['share']:.1f}% | {r['set_ms']:.1f} | {r['host']:.2f} | {r['dev']:.3f} |\n")
            fh.write(f"\nRatio many/few: **{ratio:.3f}**.\n")
            if copies:
                fh.write("\n| LARAP_CUDA_COPY[:chunk] | pose into host (ms) | ms_transfer |\n|---|---|---|\n")
                for c in copies:
                    fh.write(f"| {c['spec']} | {c['host']:.3f} | {c['transfer']:.3f} |\n")
            for nn, its, ms, m in quality:
                fh.write(f"\nTime to quality at {nn} nodes: {its} iterations, {ms:.2f} ms.\n")


if __name__ == "__main__":
    main()
