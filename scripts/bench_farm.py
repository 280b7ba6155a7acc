#!/usr/bin/python3
"""Farm bake benchmark: frames/s of one Blender process against the Dask runner with 2 workers,
and the cost per frame split into Blender start-up, bind, solve and write (docs/farm.md).

    PYTHONPATH=python /usr/bin/python3 scripts/bench_farm.py [--frames 48] [--rings 81] [--chunk-size 12]

Builds a generated two-bar shot (tests/blender/farm_scene.py), binds it with the farm's bind task,
bakes it once in one process (one chunk) and once through a local Dask cluster (2 worker processes
on 127.0.0.1, cluster start-up not counted), checks that both caches agree, prints a table and
writes out/bench_farm.json.
"""
import argparse
import datetime
import json
import os
import platform
import subprocess
import sys
import tempfile

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, os.path.join(ROOT, "python"))
from larap.farm import BakeJob, read_pc2  # noqa: E402
from larap.farm.command import bind_command, run_process  # noqa: E402
from larap.farm.merge import merged_path  # noqa: E402
from larap.farm.runner import run_local  # noqa: E402

ADDON = os.path.join(ROOT, "addon")
OBJECTS = ["Bar", "Bar.R"]


def per_frame(report, frames):
    """Seconds per baked frame of each stage, summed over the chunks (CPU-time-like, not wall)."""
    keys = ("startup", "bind", "solve", "write")
    totals = {k: sum(t.get(k, 0.0) for t in report.timing.values()) for k in keys}
    solved = sum(t.get("frames_solved", 0) for t in report.timing.values())
    return {k: v / frames for k, v in totals.items()}, totals, solved


def main():
    p = argparse.ArgumentParser()
    p.add_argument("--frames", type=int, default=48)
    p.add_argument("--rings", type=int, default=81)
    p.add_argument("--chunk-size", type=int, default=12)
    p.add_argument("--preroll", type=int, default=3)
    a = p.parse_args()
    from larap.farm.dask_runner import local_cluster, run_dask
    from distributed import Client
    tmp = tempfile.mkdtemp(prefix="larap-bench-farm-")
    raw, bound = os.path.join(tmp, "shot.blend"), os.path.join(tmp, "bound.blend")
    subprocess.run(["blender", "-b", "--factory-startup", "--python-exit-code", "1", "--python",
                    os.path.join(ROOT, "tests", "blender", "farm_scene.py"), "--", raw, "--two", "--rings",
                    str(a.rings), "--frames", str(a.frames)], check=True, capture_output=True)
    res = run_process(bind_command(raw, OBJECTS, 1, bound, addon_path=ADDON))
    assert res["returncode"] == 0, res["output"]
    kw = dict(blend=bound, objects=OBJECTS, frame_start=1, frame_end=a.frames, preroll=a.preroll, warm_tol=1e-7)
    quiet = dict(addon_path=ADDON, log=lambda line: None)
    one_job = BakeJob(out_dir=os.path.join(tmp, "one"), chunk_size=a.frames, **kw)
    one = run_local(one_job, workers=1, **quiet)
    cluster = local_cluster(2)
    with Client(cluster) as client:
        dask_job = BakeJob(out_dir=os.path.join(tmp, "dask"), chunk_size=a.chunk_size, **kw)
        farm = run_dask(dask_job, client=client, **quiet)
    cluster.close()
    err = 0.0
    for name in OBJECTS:
        A = read_pc2(merged_path(one_job.out_dir, name))[1]
        B = read_pc2(merged_path(dask_job.out_dir, name))[1]
        err = max(err, float(np.abs(A - B).max() / np.linalg.norm(A[0].max(0) - A[0].min(0))))
    points = read_pc2(merged_path(one_job.out_dir, OBJECTS[0]))[0]["points"]
    rows = []
    for label, rep, chunk in (("one process", one, a.frames), ("Dask, 2 workers", farm, a.chunk_size)):
        pf, totals, solved = per_frame(rep, a.frames)
        rows.append({"runner": label, "chunk_size": chunk, "chunks": rep.chunks, "wall_s": rep.seconds,
                     "frames_per_s": rep.frames_per_second, "frames_solved": solved,
                     "per_frame_ms": {k: 1e3 * v for k, v in pf.items()},
                     "per_chunk_s": {k: v / rep.chunks for k, v in totals.items()}})
    ratio = farm.frames_per_second / one.frames_per_second
    info = {"date": datetime.date.today().isoformat(), "machine": f"{platform.node()} ({os.cpu_count()} cores, "
            f"{platform.processor() or platform.machine()})", "device": "cpu",
            "shot": f"{len(OBJECTS)} bars x {points} vertices, {a.frames} frames, 2 handles each, pre-roll {a.preroll}, "
                    f"warm tol 1e-7", "ratio_dask_over_one": ratio, "max_diff_over_diagonal": err, "rows": rows}
    print(f"larap farm bench, {info['date']}, {info['machine']}; {info['shot']}")
    print(f"{'runner':18} {'chunk':>5} {'chunks':>6} {'wall s':>7} {'frames/s':>8} | per frame ms: "
          f"{'startup':>8} {'bind':>6} {'solve':>7} {'write':>6}")
    for r in rows:
        f = r["per_frame_ms"]
        print(f"{r['runner']:18} {r['chunk_size']:5d} {r['chunks']:6d} {r['wall_s']:7.2f} {r['frames_per_s']:8.2f} | "
              f"{'':13} {f['startup']:8.1f} {f['bind']:6.1f} {f['solve']:7.1f} {f['write']:6.2f}")
    for r in rows:
        c = r["per_chunk_s"]
        print(f"  {r['runner']}: per chunk start-up {c['startup']:.2f} s, bind {c['bind']:.3f} s, "
              f"solve {c['solve']:.2f} s ({r['frames_solved']} frames solved for {a.frames} baked)")
    print(f"Dask (2 workers) / one process: {ratio:.2f}x frames/s; caches agree to {err:.1e} of the diagonal")
    os.makedirs(os.path.join(ROOT, "out"), exist_ok=True)
    with open(os.path.join(ROOT, "out", "bench_farm.json"), "w") as fh:
        json.dump(info, fh, indent=1)


if __name__ == "__main__":
    main()
