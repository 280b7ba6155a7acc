"""Blender command lines of a bake's tasks: the same for the Dask runner, the docs (Deadline,
OpenCue) and the Flamenco job type (flamenco/larap-bake.js builds the same arguments).

Every command carries ``--python-exit-code 1``: without it a script that fails still exits 0 and a
farm marks the task done.
"""
from __future__ import annotations

import os

HERE = os.path.dirname(os.path.abspath(__file__))
CHUNK_SCRIPT = os.path.join(HERE, "blender_chunk.py")
BIND_SCRIPT = os.path.join(HERE, "blender_bind.py")
# With the add-on installed on the farm machine (scripts/install_addon vendors larap into it):
INSTALLED_CHUNK_EXPR = "import larap.farm.blender_chunk as m; m.main()"
INSTALLED_BIND_EXPR = "import larap.farm.blender_bind as m; m.main()"


def chunk_args(job, chunk) -> list:
    """The arguments after ``--`` of blender_chunk.py for one chunk of ``job`` (plan.BakeJob)."""
    args = []
    for name in job.objects:
        args += ["--object", name]
    args += ["--job-frames", f"{job.frame_start}-{job.frame_end}", "--chunk", f"{chunk.start}-{chunk.end}",
             "--mode", job.mode, "--tol", repr(float(job.tol)), "--max-iterations", str(job.max_iterations),
             "--out", job.out_dir]
    if job.mode == "warm":  # 0: the add-on's own final solve
        args += ["--warm-tol", "0" if job.warm_tol is None else repr(float(job.warm_tol))]
    if job.mode == "warm" and job.preroll:
        args += ["--preroll", str(job.preroll)]
    if job.device:
        args += ["--device", job.device]
    return args


def _blender(blender, blend, factory_startup, installed, script, expr, args):
    cmd = [blender, "-b"]
    if factory_startup:
        cmd.append("--factory-startup")
    cmd.append(blend)
    if installed:
        cmd += ["--addons", "larap_blender", "--python-exit-code", "1", "--python-expr", expr]
    else:
        cmd += ["--python-exit-code", "1", "--python", script]
    return cmd + ["--"] + args


def chunk_command(job, chunk, *, blender="blender", addon_path="", installed=False, factory_startup=True) -> list:
    """argv of the Blender process that bakes ``chunk``. ``installed``: use the add-on installed in
    Blender (farm machines) instead of this checkout's scripts (``addon_path``: the folder holding
    larap_blender when it is not installed)."""
    args = chunk_args(job, chunk)
    if addon_path and not installed:
        args += ["--addon-path", addon_path]
    return _blender(blender, job.blend, factory_startup, installed, CHUNK_SCRIPT, INSTALLED_CHUNK_EXPR, args)


def bind_command(blend, objects, frame, save_as, *, blender="blender", addon_path="", installed=False,
                 rebind=False, factory_startup=True) -> list:
    args = []
    for name in objects:
        args += ["--object", name]
    args += ["--frame", str(int(frame)), "--save-as", save_as]
    if rebind:
        args.append("--rebind")
    if addon_path and not installed:
        args += ["--addon-path", addon_path]
    return _blender(blender, blend, factory_startup, installed, BIND_SCRIPT, INSTALLED_BIND_EXPR, args)


def run_process(cmd, timeout=None, env=None, stamp=False, tail_lines=40) -> dict:
    """Run one task's command (on a worker); never raises for the command's own failure.
    Returns {"returncode" (None: timed out), "seconds", "output" (the last lines)}.
    ``stamp``: append ``--launched-at <now>`` (blender_chunk.py reports its start-up time)."""
    import subprocess
    import time
    cmd = list(cmd) + (["--launched-at", repr(time.time())] if stamp else [])
    t0 = time.perf_counter()
    try:
        proc = subprocess.run(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, timeout=timeout,
                              env=None if env is None else {**os.environ, **env})
        rc, out = proc.returncode, proc.stdout
    except subprocess.TimeoutExpired as exc:
        rc, out = None, (exc.output or b"") + f"\n(killed after {timeout} s)".encode()
    except OSError as exc:  # no such executable, permission denied
        rc, out = 127, f"could not start {cmd[0]!r}: {exc}".encode()
    text = out.decode("utf-8", "replace").splitlines()
    return {"returncode": rc, "seconds": time.perf_counter() - t0, "output": "\n".join(text[-tail_lines:])}
