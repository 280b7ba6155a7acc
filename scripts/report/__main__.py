"""Runs the evidence report (issue 13); scripts/evidence is the command that calls it.

    PYTHONPATH=python:scripts /usr/bin/python3 -m report [--quick | --tiny] [--out report/]
        [--skip PART ...] [--keep-meshes]

Parts, in order: table1 (CPU), time_to_quality (CPU), gpu (only where larap.available_devices()
has "cuda"), quality (LARAP beside surface ARAP), dihedral, speed (vs surface ARAP at ~500k
vertices), million (a 1M-vertex pose), blender (Blender's peers and the add-on, one Blender
process each), live_preview (the add-on's live move in a window under Xvfb, preview on and
off), pictures (Workbench renders), then plots and the summary (README.md). A part that
fails or is skipped is recorded with its reason in status.json and in the summary; the others
still run. Sizes: full (< 30 minutes on 2 cores), --quick (a few minutes), --tiny (the smoke
test: seconds, no Blender, no CGAL)."""
from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import time
import traceback

import numpy as np

import larap
from larap import quality

from . import api, cases, convergence, gpu, live_preview, pictures, plots, quality_runs, summary, table, table1

HERE = os.path.dirname(os.path.abspath(__file__))
BLENDER_SIZES = {"full": [20_000, 100_000, 300_000], "quick": [5_000], "tiny": []}
BLENDER_TIMEOUT = {"full": 150, "quick": 120, "tiny": 60}


def blender_cmd(script, *args):
    return ["blender", "-b", "--factory-startup", "--python-exit-code", "1", "--python", script, "--", *args]


def blender_env():
    env = dict(os.environ)
    root = cases.REPO
    env["PYTHONPATH"] = os.pathsep.join([os.path.join(root, "python"), os.path.join(root, "scripts")])
    return env


def run_blender_peers(out, work, size, log):
    if shutil.which("blender") is None:
        raise Skip("no blender on PATH (scripts/setup installs Debian's Blender)")
    result = os.path.join(work, "blender_peers.jsonl")
    if os.path.exists(result):
        os.remove(result)
    for n in BLENDER_SIZES[size]:
        for method in ("larap", "laplacian", "meshdeform"):
            log(f"blender: {method}, {n:,} vertices")
            mesh_out = os.path.join(work, "meshes", f"blender_{method}_{n}.npz")
            t0 = time.time()
            try:
                r = subprocess.run(blender_cmd(os.path.join(HERE, "blender_peers.py"), method, str(n), result, mesh_out),
                                   capture_output=True, text=True, timeout=BLENDER_TIMEOUT[size], env=blender_env())
                if r.returncode:
                    row = dict(method=method, size=n, ok=False, error=f"Blender exited {r.returncode}: "
                               + (r.stderr or r.stdout)[-300:].replace("\n", " "))
                    with open(result, "a") as f:
                        f.write(json.dumps(row) + "\n")
            except subprocess.TimeoutExpired:
                with open(result, "a") as f:
                    f.write(json.dumps(dict(method=method, size=n, ok=False,
                                            error=f"over {BLENDER_TIMEOUT[size]} s (killed)")) + "\n")
            log(f"   {time.time() - t0:.0f} s")
    rows = [json.loads(line) for line in open(result)] if os.path.exists(result) else []
    for row in rows:  # quality of the final pose, with the same measures as every other method
        path = os.path.join(work, "meshes", f"blender_{row['method']}_{row['size']}.npz")
        if not row.get("ok") or not os.path.exists(path):
            continue
        from . import blender_peers_geometry as geo
        V, F, groups, steps = geo.bar(row["size"])
        X = np.load(path)["X"].astype(np.float64)
        tris = quality.triangles(F)
        diag = quality.diagonal(V)
        row["handle_error"] = quality.handle_error(X, np.concatenate(groups), api.targets(V, groups, steps[-1]), diag)
        row["volume_change"] = quality.volume_change(V, X, tris)
        dist = quality.edge_distortion(V, X, quality.edges(tris))
        row["edge_mean"], row["edge_p95"] = dist["mean"], dist["p95"]
    table.write_csv(os.path.join(out, "blender_peers.csv"), rows)
    return rows


class Skip(Exception):
    """A part that cannot run here; the message says why."""


def main():
    ap = argparse.ArgumentParser(prog="scripts/evidence")
    g = ap.add_mutually_exclusive_group()
    g.add_argument("--quick", action="store_true", help="a small version (a few minutes)")
    g.add_argument("--tiny", action="store_true", help="seconds: the smoke test's size (no Blender, no CGAL)")
    ap.add_argument("--out", default=os.path.join(cases.REPO, "report"))
    ap.add_argument("--skip", nargs="*", default=[], help="parts to leave out")
    ap.add_argument("--keep-meshes", action="store_true", help="keep the posed meshes (work/meshes/*.npz)")
    args = ap.parse_args()
    size = "tiny" if args.tiny else "quick" if args.quick else "full"
    out = os.path.abspath(args.out)
    work = os.path.join(out, "work")
    for d in (out, work, os.path.join(out, "plots"), os.path.join(out, "pictures")):
        os.makedirs(d, exist_ok=True)
    start = time.time()
    status = dict(size=size, machine=table.machine(), api=None, parts={}, devices=larap.available_devices(),
                  engine=os.path.dirname(larap.__file__), meshes=cases.meshes_dir())

    def log(msg):
        print(f"[{time.time() - start:6.0f} s] {msg}", flush=True)

    def part(name, fn, *a):
        if name in args.skip:
            status["parts"][name] = dict(state="skipped", reason="--skip")
            return None
        t0, load0 = time.time(), os.getloadavg()[0]
        try:
            res = fn(*a)
            status["parts"][name] = dict(state="ok", seconds=round(time.time() - t0, 1),
                                         load=[round(load0, 2), round(os.getloadavg()[0], 2)])
            return res
        except Skip as exc:
            status["parts"][name] = dict(state="skipped", reason=str(exc))
        except Exception as exc:
            traceback.print_exc()
            status["parts"][name] = dict(state="failed", reason=f"{type(exc).__name__}: {exc}")
        log(f"{name}: {status['parts'][name]['state']}: {status['parts'][name]['reason']}")
        return None

    probe = larap.Deformer(*cases.bar())
    status["api"] = api.name(probe)
    del probe

    exe = None
    if size != "tiny":
        from peers import surface_arap

        def build():
            return surface_arap.build(os.path.join(cases.REPO, "build-evidence"))
        exe = part("surface_arap_build", build)

    part("table1", table1.run, out, size, "cpu", log)
    part("time_to_quality", convergence.run, out, size, "cpu", log)

    def gpu_part():
        if "cuda" not in larap.available_devices():
            raise Skip("no usable CUDA device here (larap.available_devices() == "
                       f"{larap.available_devices()}); run `python3 -m report.gpu --out DIR` where one is")
        return gpu.run(out, size, log)
    part("gpu", gpu_part)

    def quality_part():
        rows, skipped = quality_runs.run(work, size == "quick", exe, log)
        for s in skipped:
            status.setdefault("notes", []).append(s)
        if exe is None:
            status.setdefault("notes", []).append("surface ARAP not run (its peer was not built)")
        shutil.move(os.path.join(work, "quality.csv"), os.path.join(out, "quality.csv"))
        return rows
    if size != "tiny":
        part("quality", quality_part)
    else:
        def tiny_quality():
            case = cases.bar_case("bend90")
            X, Xt, info, d = quality_runs.run_larap(case)
            tris = case.tris
            row = dict(case=case.name, method="larap_bspline", vertices=len(case.V), handles=case.handle_count,
                       **quality_runs.measure(case, X, quality.diagonal(case.V), tris, quality.edges(tris)))
            table.write_csv(os.path.join(out, "quality.csv"), [row])
        part("quality", tiny_quality)

    def dihedral_part():
        rows = quality_runs.dihedral(work, size != "full", log)
        shutil.move(os.path.join(work, "dihedral.csv"), os.path.join(out, "dihedral.csv"))
        return rows
    if size != "tiny":
        part("dihedral", dihedral_part)

        def speed_part():
            row = quality_runs.speed(work, size == "quick", exe, log)
            shutil.move(os.path.join(work, "speed_vs_surface_arap.csv"), os.path.join(out, "speed_vs_surface_arap.csv"))
            return row
        part("speed", speed_part)

        def million():
            row, why = pictures.big_pose(work, size == "quick", log)
            if row is None:
                raise Skip(why)
            pictures.big_csv(out, row)
        part("million", million)
        part("blender", run_blender_peers, out, work, size, log)

        def preview_part():
            try:
                return live_preview.run(out, work, size, log)
            except live_preview.Unavailable as exc:
                raise Skip(str(exc)) from None
        part("live_preview", preview_part)

        def render():
            if shutil.which("blender") is None:
                raise Skip("no blender on PATH")
            spec_path = os.path.join(work, "pictures.json")
            pictures.write_specs(spec_path, pictures.specs(work, os.path.join(out, "pictures")))
            r = subprocess.run(blender_cmd(os.path.join(HERE, "render_scenes.py"), spec_path), capture_output=True,
                               text=True, timeout=900)
            failed = [l for l in r.stdout.splitlines() if l.startswith("FAILED")]
            if r.returncode or failed:
                raise RuntimeError((failed or [r.stderr[-300:]])[0])
        part("pictures", render)

    part("plots", plots.run, out)
    status["seconds"] = round(time.time() - start, 1)
    status["machine_end"] = table.machine()
    with open(os.path.join(out, "status.json"), "w") as f:
        json.dump(status, f, indent=1)
    summary.write(out, status)
    if not args.keep_meshes:
        shutil.rmtree(os.path.join(work, "meshes"), ignore_errors=True)
    log(f"report written to {out}/README.md")
    return 0 if all(p["state"] != "failed" for p in status["parts"].values()) else 1


if __name__ == "__main__":
    sys.exit(main())
