"""Command line of the farm bake (system Python; Blender runs only inside the chunk tasks).

    python3 -m larap.farm plan --frames 1-100 --chunk-size 25 [--preroll 3]
    python3 -m larap.farm command SHOT.blend --object Body --frames 1-100 --chunk-size 25 --out DIR [--installed]
    python3 -m larap.farm bake  SHOT.blend --object Body --frames 1-100 --chunk-size 25 --out DIR [--workers 2]
    python3 -m larap.farm dask  SHOT.blend --object Body --frames 1-100 --chunk-size 25 --out DIR
                                [--scheduler tcp://HOST:8786 | --workers 2]
    python3 -m larap.farm merge SHOT.blend --object Body --frames 1-100 --chunk-size 25 --out DIR

``command`` prints one Blender command line per chunk, for farms that run arbitrary commands
(Deadline, OpenCue); ``merge`` then joins the chunks. Exit status 0 only when all went well.
Inside Blender (the Flamenco merge task): ``--python-expr "import larap.farm.cli as c; c.blender_main()" -- merge ...``.
"""
from __future__ import annotations

import argparse
import os
import shlex
import sys

from .command import chunk_command
from .merge import MergeError, merge_bake
from .plan import MODES, BakeJob, parse_frames, plan_chunks
from .runner import FarmError, run_local

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__)))))
REPO_ADDON = os.path.join(ROOT, "addon")


def _job_args(p, runs=False):
    p.add_argument("blend", help="the .blend file (the bound copy, when a bind task ran)")
    p.add_argument("--object", action="append", required=True, help="bound mesh object (repeat for several)")
    p.add_argument("--frames", required=True, help="frame range, e.g. 1-100")
    p.add_argument("--chunk-size", type=int, default=25)
    p.add_argument("--preroll", type=int, default=3, help="frames solved before each chunk and discarded (default 3)")
    p.add_argument("--mode", choices=MODES, default="warm",
                   help="warm: frames warm-start within a chunk; rest: every frame from rest (chunking-independent)")
    p.add_argument("--tol", type=float, default=1e-10, help="tolerance of from-rest solves (default 1e-10)")
    p.add_argument("--max-iterations", type=int, default=1000, help="iteration cap of from-rest solves")
    p.add_argument("--warm-tol", type=float, default=1e-7,
                   help="tolerance of warm-started solves (default 1e-7; 0: the add-on's final solve, 1e-5)")
    p.add_argument("--device", default="", choices=["", "cpu", "cuda", "auto"])
    p.add_argument("--out", required=True, help="bake folder")
    p.add_argument("--blender", default=os.environ.get("BLENDER", "blender"))
    p.add_argument("--installed", action="store_true",
                   help="use the add-on installed in Blender (farm machines) instead of this checkout's")
    if runs:
        p.add_argument("--retries", type=int, default=2, help="re-runs of a failed chunk (default 2)")
        p.add_argument("--timeout", type=float, default=None, help="seconds before a chunk is killed")
        p.add_argument("--resume", action="store_true", help="keep chunks an earlier run of this bake finished")


def _job(a) -> BakeJob:
    first, last = parse_frames(a.frames)
    return BakeJob(blend=os.path.abspath(a.blend), objects=a.object, frame_start=first, frame_end=last,
                   out_dir=os.path.abspath(a.out), chunk_size=a.chunk_size, preroll=a.preroll, mode=a.mode,
                   tol=a.tol, warm_tol=a.warm_tol or None, max_iterations=a.max_iterations, device=a.device)


def _run_kwargs(a):
    return dict(blender=a.blender, addon_path="" if a.installed else REPO_ADDON, installed=a.installed,
                retries=a.retries, timeout=a.timeout, resume=a.resume)


def cmd_plan(a):
    first, last = parse_frames(a.frames)
    for c in plan_chunks(first, last, a.chunk_size, a.preroll):
        print(f"{c.start}-{c.end}" + (f"  (solved from {c.solve_start})" if c.solve_start != c.start else ""))


def cmd_command(a):
    job = _job(a)
    for c in job.chunks():
        print(shlex.join(chunk_command(job, c, blender=a.blender, addon_path="" if a.installed else REPO_ADDON,
                                       installed=a.installed)))


def cmd_bake(a):
    run_local(_job(a), workers=a.workers, **_run_kwargs(a))


def cmd_dask(a):
    from .dask_runner import run_dask
    run_dask(_job(a), scheduler=a.scheduler, workers=a.workers, **_run_kwargs(a))


def cmd_merge(a):
    summary = merge_bake(_job(a))
    for name, entry in summary["objects"].items():
        print(f"larap-farm merge: {name}: {entry['samples']} frames of {entry['points']} points -> "
              f"{os.path.join(os.path.abspath(a.out), entry['file'])}")


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="python3 -m larap.farm", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = parser.add_subparsers(dest="command", required=True)
    p = sub.add_parser("plan", help="print the chunks of a frame range")
    p.add_argument("--frames", required=True)
    p.add_argument("--chunk-size", type=int, default=25)
    p.add_argument("--preroll", type=int, default=0)
    p.set_defaults(func=cmd_plan)
    p = sub.add_parser("command", help="print each chunk's Blender command line (Deadline, OpenCue, ...)")
    _job_args(p)
    p.set_defaults(func=cmd_command)
    p = sub.add_parser("bake", help="bake here, WORKERS Blender processes at a time, then merge")
    _job_args(p, runs=True)
    p.add_argument("--workers", type=int, default=1)
    p.set_defaults(func=cmd_bake)
    p = sub.add_parser("dask", help="bake on a Dask cluster, then merge")
    _job_args(p, runs=True)
    p.add_argument("--scheduler", default=None, help="address of a running scheduler (default: a local cluster)")
    p.add_argument("--workers", type=int, default=2, help="workers of the local cluster (default 2)")
    p.set_defaults(func=cmd_dask)
    p = sub.add_parser("merge", help="merge the chunks of a finished bake")
    _job_args(p)
    p.set_defaults(func=cmd_merge)
    a = parser.parse_args(argv)
    try:
        a.func(a)
    except (FarmError, MergeError, ValueError, TypeError, OSError, RuntimeError) as exc:
        print(f"larap-farm: error: {exc}", file=sys.stderr)
        return 1
    return 0


def blender_main():
    """The same commands inside Blender (arguments after ``--``); raises on failure, so that
    ``--python-exit-code 1`` fails the task."""
    from ._blender import script_argv
    argv = script_argv()
    code = main(argv)
    if code:
        raise RuntimeError(f"larap-farm {argv[0] if argv else ''} failed (exit status {code}; the reason is above)")
