#!/usr/bin/env python3
"""GPU benchmark of the CUDA backend against the CPU backend (docs/results-gpu.md).

Run on a machine with a GPU, from the repository root, after building with -DLARAP_CUDA=ON:
    PYTHONPATH=python python3 scripts/bench_gpu.py --out bench.json [--quick]

Handles: two vertex groups holding every vertex of each end (about a third of the vertices),
posed by one transform each (handles_and_targets).

Per configuration (mesh faces, lattice nodes; the paper's Table 1 sizes):
  * milliseconds per stage (rotations, rhs, solve, transfer) per flip-flop on CPU and GPU
    (GPU stages from the profiling mode: plain launches, device events);
  * time to quality: a handle move after a warm pose; the reference is the energy the CPU
    direct solver reaches after 30 flip-flops from that start; the GPU is done when its energy
    is within 0.1 % of it: iterations and milliseconds (graph mode) to get there;
  * the transfer kernel's achieved bandwidth vs a measured device-to-device copy;
  * the whole solve including the copy of the float32 positions to a host numpy array.
Then a solver comparison (mg inner iteration counts, coarse size, levels;
BENCH_SWEEP=solver:inner[:coarse[:levels]],... overrides) on three configs.

Options reach the backend as LARAP_CUDA_* environment variables (native/cuda/cuda_options.h).
The rejected variants (solvers pcg / cheby / jacobi, transfer kernels staged / ilp*) exist only
in a build configured with -DLARAP_CUDA_EXPERIMENTS=ON; a sweep entry that names one in a build
without them is recorded as skipped.
"""
from __future__ import annotations

import argparse
import datetime
import json
import os
import platform
import subprocess
import tempfile
import time

import numpy as np

import larap


def ellipsoid(faces: int):
    """Closed triangulated UV ellipsoid (2 x 0.5 x 0.5) with about `faces` triangles."""
    rings = max(4, int(round(np.sqrt(faces / 4.0))))
    seg = 2 * rings
    th = np.pi * np.arange(1, rings) / rings
    ph = 2 * np.pi * np.arange(seg) / seg
    T, P = np.meshgrid(th, ph, indexing="ij")
    body = np.stack([-np.cos(T), np.sin(T) * np.cos(P), np.sin(T) * np.sin(P)], -1).reshape(-1, 3)
    V = np.concatenate([[[-1, 0, 0], [1, 0, 0]], body]) * [2.0, 0.5, 0.5]
    ring = lambda i, j: 2 + (i - 1) * seg + (j % seg)  # noqa: E731
    j = np.arange(seg)
    F = [np.stack([np.zeros(seg, int), ring(1, j), ring(1, j + 1)], 1)]
    for i in range(1, rings - 1):
        a, b, c, d = ring(i, j), ring(i, j + 1), ring(i + 1, j + 1), ring(i + 1, j)
        F += [np.stack([a, c, b], 1), np.stack([a, d, c], 1)]
    F.append(np.stack([np.ones(seg, int), ring(rings - 1, j + 1), ring(rings - 1, j)], 1))
    return V, np.concatenate(F).astype(np.int64)


def handles_and_targets(V):
    """Realistic handles (vertex groups, docs/results-gpu.md): two groups holding every vertex
    of each end (|x| > 1.7, about a third of the ellipsoid's vertices), the left one held, the
    right one bent about z around (1.7, 0, 0) and lifted: a warm pose, then the handle move."""
    groups = [np.flatnonzero(V[:, 0] < -1.7), np.flatnonzero(V[:, 0] > 1.7)]

    def bend(angle, lift):
        c, s = np.cos(angle), np.sin(angle)
        R = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])
        piv = np.array([1.7, 0, 0])
        T = np.tile(np.eye(4), (2, 1, 1))
        T[1, :3, :3] = R
        T[1, :3, 3] = piv - R @ piv + [0, lift, 0]
        return T

    return groups, bend(0.5, 0.4), bend(0.6, 0.5)  # warm pose, then the handle move


def pose(d, T, iterations, out):
    return d.solve(transforms=T, iterations=iterations, out=out)


def gpu_warmup(d, T, out, seconds=0.5):
    """Keep the GPU busy for a while so that it runs at its working clocks while we time (an idle
    GPU drops its SM clock; the bursts of a small solve alone do not bring it back up)."""
    t = time.time()
    while time.time() - t < seconds:
        pose(d, T, 200, out)


def first_within(E, ref, tol=1e-3):
    for k, e in enumerate(E):
        if e <= ref * (1 + tol):
            return k + 1
    return None


def d2d_bandwidth():
    try:
        import torch
    except ImportError:
        return None
    n = 1 << 28  # 256 MiB
    x = torch.empty(n, dtype=torch.uint8, device="cuda")
    y = torch.empty_like(x)
    for _ in range(3):
        y.copy_(x)
    torch.cuda.synchronize()
    ts = []
    for _ in range(20):
        a, b = torch.cuda.Event(enable_timing=True), torch.cuda.Event(enable_timing=True)
        a.record()
        y.copy_(x)
        b.record()
        b.synchronize()
        ts.append(a.elapsed_time(b))
    ms = float(np.median(ts))
    return 2 * n / (ms * 1e-3) / 1e9


def read_profile(path):
    recs = []
    if os.path.exists(path):
        with open(path) as f:
            recs = [json.loads(line) for line in f if line.strip()]
        os.remove(path)
    return recs


# The stiffness of every figure this script recorded (docs/results-gpu.md, the README): the
# default until 2026-11-22 (now 0.03, docs/method.md). Kept so that new runs compare with them.
GAMMA = 0.1


def make(V, F, cells, device, weights="trilinear"):
    return larap.Deformer(V, F, cells=cells, weights=weights, device=device, gamma=GAMMA)


def aim_cells(V, F, nodes):
    """cells= that gives about `nodes` lattice nodes (one correction step)."""
    cells = int(nodes * 0.8)
    d = make(V, F, cells, "cpu")
    ratio = d.num_nodes / max(d.num_cells, 1)
    if abs(d.num_nodes - nodes) > 0.1 * nodes:
        cells = int(nodes / ratio)
        d = make(V, F, cells, "cpu")
    return cells, d


def set_env(**kv):
    for k, v in kv.items():
        if v is None:
            os.environ.pop(k, None)
        else:
            os.environ[k] = str(v)


def run_config(faces, nodes, reps=5, solver_sweep=False, cpu_iters=30):
    res = {"faces_target": faces, "nodes_target": nodes}
    V, F = ellipsoid(faces)
    res["vertices"], res["faces"] = int(len(V)), int(len(F))
    cells, dc = aim_cells(V, F, nodes)
    res["nodes"], res["cells"] = dc.num_nodes, dc.num_cells
    h, T1, T2 = handles_and_targets(V)
    res["handles"] = int(sum(len(g) for g in h))
    res["handle_groups"] = len(h)
    out32 = np.empty(V.shape, np.float32)

    # ---- CPU: reference energy and stage times
    dc.set_handle_groups(h)
    res["cpu_ms_factorize"] = dc.stats["ms_factorize"]
    pose(dc, T1, 30, out32)
    pose(dc, T2, cpu_iters, out32)
    s = dc.stats
    E_ref = s["energy"][-1]
    res["E_ref"] = E_ref
    res["cpu_ms_per_iter"] = {k: s["ms_" + k] / cpu_iters for k in ("rotations", "rhs", "solve")}
    res["cpu_ms_transfer"] = s["ms_transfer"]
    res["cpu_ms_total_30"] = s["ms_total"]
    X_cpu = out32.copy()
    del dc

    # ---- GPU (default: PCG, graph mode)
    set_env(LARAP_CUDA_SOLVER=None, LARAP_CUDA_INNER=None, LARAP_CUDA_PROFILE=None)
    dg = make(V, F, cells, "cuda")
    assert dg.device == "cuda" and dg.num_nodes == res["nodes"]
    t_sh = time.time()
    dg.set_handle_groups(h)
    res["gpu_set_handles_s"] = time.time() - t_sh
    gpu_warmup(dg, T1, out32)
    dg.reset()
    pose(dg, T1, 30, out32)
    pose(dg, T2, 60, out32)
    E = dg.stats["energy"]
    n_star = first_within(E, E_ref)
    res["gpu_energy_curve"] = E
    res["gpu_iters_to_quality"] = n_star
    res["gpu_E60_over_Eref"] = E[-1] / E_ref
    res["gpu_ms_per_iter_graph"] = dg.stats["ms_solve"] / 60
    # converged agreement (positions after 60 vs CPU after 30 flip-flops)
    diag = float(np.linalg.norm(V.max(0) - V.min(0)))
    res["gpu_vs_cpu_max_dist_over_diag"] = float(np.linalg.norm(out32 - X_cpu, axis=1).max() / diag)

    n_run = n_star or 30
    tot, sol, tra = [], [], []
    gpu_warmup(dg, T1, out32, 0.3)
    for _ in range(reps):
        dg.reset()
        pose(dg, T1, 30, out32)
        pose(dg, T2, n_run, out32)
        st = dg.stats
        tot.append(st["ms_total"])
        sol.append(st["ms_solve"])
        tra.append(st["ms_transfer"])
    res["gpu_warm_solve"] = {"iterations": n_run, "ms_total_incl_host_copy": float(np.median(tot)),
                             "ms_solve_device": float(np.median(sol)),
                             "ms_transfer_incl_host_copy": float(np.median(tra))}

    # ---- GPU profile mode: stages (plain launches) and the transfer kernel alone
    prof = os.path.join(tempfile.gettempdir(), "larap_prof.jsonl")
    read_profile(prof)
    for w in ("trilinear", "bspline"):
        set_env(LARAP_CUDA_PROFILE=prof)
        dg.weights = w
        dg.set_handle_groups(h)       # re-prepares the handles and reads the environment
        gpu_warmup(dg, T1, out32, 0.3)
        dg.reset()
        pose(dg, T1, 30, out32)
        read_profile(prof)
        for _ in range(3):
            pose(dg, T2, 10, out32)
            pose(dg, T2, 10, np.empty(V.shape, np.float64))
        recs = read_profile(prof)
        it = [r for r in recs if r["what"] == "iterate"]
        tr32 = [r for r in recs if r["what"] == "transfer" and r["elem_size"] == 4]
        tr64 = [r for r in recs if r["what"] == "transfer" and r["elem_size"] == 8]
        res[f"gpu_profile_{w}"] = {
            "ms_rotations_per_iter": float(np.median([r["ms_rotations"] / r["iterations"] for r in it])),
            "ms_rhs_per_iter": float(np.median([r["ms_rhs"] / r["iterations"] for r in it])),
            "ms_solve_per_iter_plain_launches": float(np.median([r["ms_solve"] / r["iterations"] for r in it])),
            "transfer_kernel_ms_f32": float(np.median([r["kernel_ms"] for r in tr32])),
            "transfer_kernel_ms_f64": float(np.median([r["kernel_ms"] for r in tr64])),
            "transfer_pipeline_ms_f32": float(np.median([r["pipeline_ms"] for r in tr32])),
            "transfer_pipeline_ms_f64": float(np.median([r["pipeline_ms"] for r in tr64])),
        }
    set_env(LARAP_CUDA_PROFILE=None, LARAP_CUDA_TRANSFER=None)
    dg.weights = "trilinear"
    dg.set_handle_groups(h)

    if solver_sweep:
        sweep = []
        # solver:inner[:max coarse nodes]
        spec = os.environ.get("BENCH_SWEEP", "mg:1,mg:2,mg:3,mg:4,mg:2:512,mg:2:4096")
        # solver:inner[:coarse[:levels]] (coarse may be empty: the default)
        combos = []
        for a in spec.split(","):
            f = a.split(":") + [None, None]
            combos.append((f[0], int(f[1]), f[2] or None, f[3] or None))
        for solver, inner, coarse, levels in combos:
            set_env(LARAP_CUDA_SOLVER=solver, LARAP_CUDA_INNER=inner, LARAP_CUDA_MG_COARSE=coarse,
                    LARAP_CUDA_MG_LEVELS=levels)
            t_sh = time.time()
            try:
                dg.set_handle_groups(h)
            except ValueError as exc:  # an experiment in a build without them
                sweep.append({"solver": solver, "inner": inner, "mg_coarse": coarse, "mg_levels": levels,
                              "skipped": str(exc)})
                continue
            t_sh = time.time() - t_sh
            gpu_warmup(dg, T1, out32, 0.2)
            dg.reset()
            pose(dg, T1, 30, out32)
            pose(dg, T2, 100, out32)
            E = dg.stats["energy"]
            k = first_within(E, E_ref)
            per = dg.stats["ms_solve"] / 100
            sweep.append({"solver": solver, "inner": inner, "mg_coarse": coarse, "mg_levels": levels,
                          "iters_to_quality": k,
                          "set_handles_s": t_sh,
                          "ms_per_flipflop": per, "ms_to_quality": None if k is None else k * per,
                          "E100_over_Eref": E[-1] / E_ref})
        set_env(LARAP_CUDA_SOLVER=None, LARAP_CUDA_INNER=None, LARAP_CUDA_MG_COARSE=None,
                LARAP_CUDA_MG_LEVELS=None)
        # default solver: fused cooperative kernel (default) vs one graph per flip-flop vs plain
        for key, env in (("gpu_ms_per_iter_unfused_graph", dict(LARAP_CUDA_FUSED=0)),
                         ("gpu_ms_per_iter_plain_launches", dict(LARAP_CUDA_FUSED=0, LARAP_CUDA_GRAPH=0))):
            set_env(**env)
            dg.set_handle_groups(h)
            gpu_warmup(dg, T1, out32, 0.2)
            dg.reset()
            pose(dg, T1, 30, out32)
            pose(dg, T2, 100, out32)
            res[key] = dg.stats["ms_solve"] / 100
        set_env(LARAP_CUDA_GRAPH=None, LARAP_CUDA_FUSED=None)
        coop = {}
        for b in os.environ.get("BENCH_COOP", "").split(","):
            if not b:
                continue
            set_env(LARAP_CUDA_COOP_BLOCKS=b)
            dg.set_handle_groups(h)
            dg.reset()
            pose(dg, T1, 30, out32)
            pose(dg, T2, 100, out32)
            coop[b] = dg.stats["ms_solve"] / 100
        set_env(LARAP_CUDA_COOP_BLOCKS=None)
        dg.set_handle_groups(h)
        res["gpu_ms_per_iter_by_coop_blocks"] = coop
        res["solver_sweep"] = sweep
    return res


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--out", default="bench_gpu.json")
    ap.add_argument("--quick", action="store_true", help="small configurations only")
    ap.add_argument("--configs", help="faces:nodes[:sweep],... instead of the default set "
                    "(sweep=1 also compares the solvers), e.g. 1700000:20000")
    args = ap.parse_args()
    if "cuda" not in larap.available_devices():
        raise SystemExit("no usable CUDA device: larap.available_devices() == %r" % larap.available_devices())
    info = {"date": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
            "host": platform.node(), "cpu_threads": os.cpu_count()}
    try:
        info["nvidia_smi"] = subprocess.run(
            ["nvidia-smi", "--query-gpu=name,driver_version,memory.total,clocks.max.sm",
             "--format=csv,noheader"], capture_output=True, text=True, timeout=20).stdout.strip()
    except Exception as exc:  # noqa: BLE001
        info["nvidia_smi"] = f"n/a ({exc})"
    info["d2d_copy_GBps"] = d2d_bandwidth()
    configs = [(17_000, 5_000, True), (170_000, 10_000, False), (1_700_000, 10_000, True),
               (1_700_000, 20_000, False), (2_000_000, 40_000, True)]
    if args.configs:
        configs = []
        for item in args.configs.split(","):
            parts = [int(x) for x in item.split(":")]
            configs.append((parts[0], parts[1], bool(parts[2]) if len(parts) > 2 else False))
    elif args.quick:
        configs = [(17_000, 5_000, True), (170_000, 10_000, False)]
    results = {"info": info, "configs": []}
    for faces, nodes, sweep in configs:
        t0 = time.time()
        r = run_config(faces, nodes, solver_sweep=sweep)
        r["wall_s"] = time.time() - t0
        results["configs"].append(r)
        with open(args.out, "w") as f:
            json.dump(results, f, indent=1)
        bw = info["d2d_copy_GBps"]
        p = r["gpu_profile_trilinear"]
        ach = 40 * r["vertices"] / (p["transfer_kernel_ms_f32"] * 1e-3) / 1e9
        print(f"{r['faces']:>9} faces {r['vertices']:>8} verts {r['nodes']:>6} nodes "
              f"{r['handles']} handle verts in {r['handle_groups']} groups | "
              f"q-iters {r['gpu_iters_to_quality']} | set_handles {r['gpu_set_handles_s']:.3f}s | warm solve+transfer "
              f"{r['gpu_warm_solve']['ms_solve_device'] + p['transfer_kernel_ms_f32']:.3f} ms (device), "
              f"{r['gpu_warm_solve']['ms_total_incl_host_copy']:.3f} ms (incl. host copy) | "
              f"transfer {p['transfer_kernel_ms_f32'] * 1e3:.1f} us = {ach:.0f} GB/s"
              + (f" ({100 * ach / bw:.0f}% of copy)" if bw else "")
              + f" | cpu/gpu dist {r['gpu_vs_cpu_max_dist_over_diag']:.2e} | {r['wall_s']:.0f}s", flush=True)
        for sw in r.get("solver_sweep", []):
            if "skipped" in sw:
                print(f"    {sw['solver']:>6} inner {sw['inner']:>2}: skipped ({sw['skipped']})", flush=True)
                continue
            print(f"    {sw['solver']:>6} inner {sw['inner']:>2} coarse {sw['mg_coarse']} levels {sw['mg_levels']}: {sw['iters_to_quality']} flip-flops, "
                  f"{sw['ms_per_flipflop'] * 1e3:.1f} us each, to quality "
                  f"{'-' if sw['ms_to_quality'] is None else '%.3f ms' % sw['ms_to_quality']}, "
                  f"E100/Eref {sw['E100_over_Eref']:.5f}, set_handles {sw['set_handles_s']:.3f}s", flush=True)
        print(f"    transfer kernel: f32 {p['transfer_kernel_ms_f32'] * 1e3:.1f} us, "
              f"f64 {p['transfer_kernel_ms_f64'] * 1e3:.1f} us", flush=True)
        if r.get("gpu_ms_per_iter_by_coop_blocks"):
            print("    fused per flip-flop by blocks: " + ", ".join(
                f"{b}: {v * 1e3:.1f} us" for b, v in r["gpu_ms_per_iter_by_coop_blocks"].items()), flush=True)
        if "gpu_ms_per_iter_unfused_graph" in r:
            print(f"    default per flip-flop: fused {r['gpu_ms_per_iter_graph'] * 1e3:.1f} us, unfused graph "
                  f"{r['gpu_ms_per_iter_unfused_graph'] * 1e3:.1f} us, plain launches "
                  f"{r['gpu_ms_per_iter_plain_launches'] * 1e3:.1f} us", flush=True)
    print(json.dumps(info))


if __name__ == "__main__":
    main()
