"""Bake one chunk of frames for one or more bound objects, inside headless Blender.

    blender -b --factory-startup SHOT.blend --python-exit-code 1 --python .../larap/farm/blender_chunk.py -- \\
        --object Body --job-frames 1-100 --chunk 26-50 [--preroll 3] [--mode warm|rest] [--tol 1e-10] \\
        [--max-iterations 1000] [--warm-tol 1e-7] --out BAKE_DIR [--device cpu] [--addon-path DIR]
or, with the add-on installed on the farm machine:
    blender -b SHOT.blend --addons larap_blender --python-exit-code 1 \\
        --python-expr "import larap.farm.blender_chunk as c; c.main()" -- ARGS

The first solved frame (the chunk's start, or the start of its pre-roll) is solved from rest to
``--tol``; later frames warm-start from the previous one (mode "warm": to ``--warm-tol``, default
1e-7; 0: the add-on's own final solve) or
are solved from rest too (mode "rest": independent of the chunking, bit for bit). Writes one PC2
per object and then the chunk's manifest (manifest.py), each atomically. Without
``--python-exit-code 1`` a failure here would still exit 0: every command line in larap.farm has it.
"""
from __future__ import annotations

import argparse
import os
import sys
import time

if __name__ == "__main__" and __package__ in (None, ""):
    # Run as a file (--python): import the package this file belongs to.
    sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__)))))

from larap.farm._blender import bind_state, enable_addon, final_solve, find_objects, script_argv  # noqa: E402
from larap.farm.manifest import chunk_dir, chunk_pc2_path, write_manifest  # noqa: E402
from larap.farm.pc2 import write_pc2  # noqa: E402
from larap.farm.plan import MODES, BakeJob, Chunk, parse_frames  # noqa: E402


def parse_args(argv):
    p = argparse.ArgumentParser(prog="blender_chunk.py", description="Bake one chunk (inside Blender)")
    p.add_argument("--object", action="append", required=True, help="bound mesh object (repeat for several)")
    p.add_argument("--job-frames", required=True, help="the whole bake's frames, e.g. 1-100")
    p.add_argument("--chunk", required=True, help="this chunk's frames, e.g. 26-50")
    p.add_argument("--preroll", type=int, default=0, help="frames solved before the chunk and discarded")
    p.add_argument("--mode", choices=MODES, default="warm")
    p.add_argument("--tol", type=float, default=1e-10, help="tolerance of from-rest solves")
    p.add_argument("--max-iterations", type=int, default=1000, help="iteration cap of from-rest solves")
    p.add_argument("--warm-tol", type=float, default=1e-7,
                   help="tolerance of warm-started solves (default 1e-7; 0: the add-on's final solve)")
    p.add_argument("--out", required=True, help="bake folder (chunks go to OUT/chunks)")
    p.add_argument("--device", default="", choices=["", "cpu", "cuda", "auto"])
    p.add_argument("--addon-path", default="", help="folder holding larap_blender when it is not installed")
    p.add_argument("--launched-at", type=float, default=0.0, help="time.time() when Blender was started")
    return p.parse_args(argv)


def bake_chunk(core, scene, objs, job, chunk):
    """Solve frames chunk.solve_start..chunk.end; returns ({name: (frames, n, 3) float32}, timing)."""
    import numpy as np
    timing = {"bind": 0.0, "solve": 0.0, "frames_solved": chunk.end - chunk.solve_start + 1,
              "max_iterations": 0,
              "rest_solves": 0, "rest_iterations": 0, "warm_solves": 0, "warm_iterations": 0}
    out = {}
    with core.suspend_live():
        t0 = time.perf_counter()
        scene.frame_set(chunk.solve_start)
        for obj in objs:
            core.check_object(obj, need_bound=True)
            if job.device:
                obj.larap.device = job.device
            core.ensure_runtime(obj, "full")
            out[obj.name] = np.empty((chunk.frames, len(obj.data.vertices), 3), dtype=np.float32)
        timing["bind"] = time.perf_counter() - t0
        t0 = time.perf_counter()
        warned = set()
        for f in range(chunk.solve_start, chunk.end + 1):
            if f != chunk.solve_start:
                scene.frame_set(f)
            for obj in objs:
                rt = core.runtime(obj)
                if job.mode == "rest" or f == chunk.solve_start:
                    result = final_solve(core, obj, job.tol, job.max_iterations)
                elif job.warm_tol is not None:
                    result = final_solve(core, obj, job.warm_tol, job.max_iterations, from_rest=False)
                else:
                    result = final_solve(core, obj, from_rest=False)
                for w in result.warnings:
                    if w not in warned:
                        warned.add(w)
                        print(f"larap-farm chunk {chunk}: {obj.name}: {w}", flush=True)
                rt = core.runtime(obj)
                its = int(rt.stats.get("iterations", 0))
                timing["max_iterations"] = max(timing["max_iterations"], its)
                kind = "rest" if job.mode == "rest" or f == chunk.solve_start else "warm"
                timing[kind + "_solves"] += 1  # and their iterations, summed: warm frames need fewer
                timing[kind + "_iterations"] += its
                if f >= chunk.start:
                    out[obj.name][f - chunk.start] = rt.out
        timing["solve"] = time.perf_counter() - t0
    return out, timing


def main(argv=None):
    started = time.time()
    args = parse_args(script_argv(argv))
    import bpy
    core = enable_addon(args.addon_path)
    first, last = parse_frames(args.job_frames)
    c0, c1 = parse_frames(args.chunk)
    job = BakeJob(blend=bpy.data.filepath, objects=list(args.object), frame_start=first, frame_end=last,
                  out_dir=os.path.abspath(args.out), chunk_size=c1 - c0 + 1, preroll=args.preroll,
                  mode=args.mode, tol=args.tol, warm_tol=args.warm_tol or None, max_iterations=args.max_iterations,
                  device=args.device)
    if c0 < first or c1 > last:
        raise ValueError(f"chunk {args.chunk} lies outside the bake's frames {args.job_frames}")
    chunk = Chunk(c0, c1, max(first, c0 - args.preroll) if args.mode == "warm" else c0)
    signature = job.signature()  # hashes the .blend now, as close as possible to when Blender read it
    objs = find_objects(job.objects)
    positions, timing = bake_chunk(core, bpy.context.scene, objs, job, chunk)
    binds = {obj.name: bind_state(core, obj) for obj in objs}
    t0 = time.perf_counter()
    os.makedirs(chunk_dir(job.out_dir), exist_ok=True)
    for name, P in positions.items():
        write_pc2(chunk_pc2_path(job.out_dir, name, chunk), P, chunk.start)
    timing["startup"] = started - args.launched_at if args.launched_at else 0.0
    timing["write"] = time.perf_counter() - t0
    write_manifest(job.out_dir, chunk, signature, {n: P.shape[1] for n, P in positions.items()}, timing, binds)
    timing["write"] = time.perf_counter() - t0
    pre = chunk.start - chunk.solve_start
    print(f"larap-farm chunk {chunk}: {len(objs)} object(s) x {chunk.frames} frames"
          f"{f' (+{pre} pre-roll)' if pre else ''}, {job.mode}; startup {timing['startup']:.2f} s, "
          f"bind {timing['bind']:.2f} s, solve {timing['solve']:.2f} s, write {timing['write']:.3f} s", flush=True)


if __name__ == "__main__":
    main()
