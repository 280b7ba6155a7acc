"""Run a bake's chunks on any executor, re-run the ones that fail, then merge.

The executor is two functions: ``submit(fn, *args, name=...) -> future`` and
``wait(futures, return_when="FIRST_COMPLETED") -> (done, not_done)`` (concurrent.futures and
Dask's distributed both fit; dask_runner.py and :func:`run_local` wire them). A chunk counts as
done only when its Blender exited 0 *and* its files verify against its manifest; anything else is
reported (exit code and the log's last lines) and submitted again, up to ``retries`` times. The
merge runs only when every chunk is done, so a failed chunk never reaches the merged cache.
"""
from __future__ import annotations

import concurrent.futures
import dataclasses
import os
import time
import uuid

from .command import chunk_command, run_process
from .manifest import ChunkError, chunk_dir, manifest_path, verify_chunk
from .merge import merge_bake


class FarmError(RuntimeError):
    """Chunks that still failed after their retries (``.report`` says which and why)."""

    def __init__(self, message, report):
        super().__init__(message)
        self.report = report


@dataclasses.dataclass
class BakeReport:
    seconds: float = 0.0
    frames: int = 0
    chunks: int = 0
    attempts: dict = dataclasses.field(default_factory=dict)   # chunk -> attempts made
    failures: list = dataclasses.field(default_factory=list)   # (chunk, attempt, reason)
    timing: dict = dataclasses.field(default_factory=dict)     # chunk -> its manifest's timing
    skipped: list = dataclasses.field(default_factory=list)    # chunks kept from an earlier run (resume)
    merged: dict = dataclasses.field(default_factory=dict)     # merge_bake's summary

    @property
    def frames_per_second(self) -> float:
        return self.frames / self.seconds if self.seconds > 0 else 0.0


def _outcome(future, job, chunk, signature):
    """(ok, reason, manifest)."""
    try:
        res = future.result()
    except Exception as exc:  # the worker died, the task was cancelled, ...
        return False, f"{type(exc).__name__}: {exc}", None
    if res["returncode"] != 0:
        what = "timed out" if res["returncode"] is None else f"exit code {res['returncode']}"
        tail = "\n".join("      " + line for line in res["output"].splitlines()[-8:])
        return False, f"{what} after {res['seconds']:.1f} s; log ends:\n{tail}", None
    try:
        return True, "", verify_chunk(job.out_dir, chunk, signature)
    except (ChunkError, OSError) as exc:
        return False, f"Blender exited 0 but the chunk is not intact: {exc}", None


def run_bake(job, submit, wait, *, blender="blender", addon_path="", installed=False, retries=2,
             timeout=None, env=None, resume=False, merge=True, log=print) -> BakeReport:
    """Bake every chunk of ``job`` (plan.BakeJob), re-running failures, then merge (see module doc).
    ``resume``: keep chunks an earlier run of the same bake finished (verified), else start clean."""
    chunks = job.chunks()
    # The shot (the .blend's path and content hash) and the settings: a chunk of another version of
    # the file is never kept by --resume nor merged. OSError here when the .blend cannot be read.
    signature = job.signature()
    os.makedirs(chunk_dir(job.out_dir), exist_ok=True)
    report = BakeReport(frames=job.frame_end - job.frame_start + 1, chunks=len(chunks))
    todo = []
    for chunk in chunks:
        if resume:
            try:
                report.timing[chunk] = verify_chunk(job.out_dir, chunk, signature)["timing"]
                report.skipped.append(chunk)
                continue
            except (ChunkError, OSError):
                pass
        try:
            os.remove(manifest_path(job.out_dir, chunk))  # a stale manifest must not pass for this run's
        except FileNotFoundError:
            pass
        todo.append(chunk)
    t0 = time.perf_counter()

    def launch(chunk):
        report.attempts[chunk] = report.attempts.get(chunk, 0) + 1
        cmd = chunk_command(job, chunk, blender=blender, addon_path=addon_path, installed=installed)
        return submit(run_process, cmd, timeout, env, True, name=f"larap-chunk-{chunk}-{report.attempts[chunk]}-{uuid.uuid4().hex[:8]}")

    running = {launch(c): c for c in todo}
    lost, finished = [], len(report.skipped)
    while running:
        done, _ = wait(list(running), return_when="FIRST_COMPLETED")
        for fut in done:
            chunk = running.pop(fut)
            ok, reason, doc = _outcome(fut, job, chunk, signature)
            n = report.attempts[chunk]
            if ok:
                finished += 1
                t = doc["timing"]
                report.timing[chunk] = t
                log(f"larap-farm [{finished}/{len(chunks)}] chunk {chunk} done ({chunk.frames} frames; "
                    f"startup {t.get('startup', 0):.2f} s, bind {t['bind']:.2f} s, solve {t['solve']:.2f} s, "
                    f"write {t['write']:.3f} s){' on attempt %d' % n if n > 1 else ''}")
                continue
            report.failures.append((chunk, n, reason))
            again = n <= retries
            log(f"larap-farm chunk {chunk} FAILED (attempt {n} of {retries + 1}"
                f"{', running it again' if again else ', giving up'}): {reason}")
            if again:
                running[launch(chunk)] = chunk
            else:
                lost.append(chunk)
    report.seconds = time.perf_counter() - t0
    if lost:
        msg = (f"larap-farm: {len(lost)} of {len(chunks)} chunks failed after {retries + 1} attempts "
               f"({', '.join(str(c) for c in lost)}); nothing merged")
        raise FarmError(msg, report)
    if merge:
        report.merged = merge_bake(job)
    log(f"larap-farm: {len(job.objects)} object(s), {report.frames} frames in {len(chunks)} chunks "
        f"({len(report.skipped)} kept from an earlier run): {report.seconds:.1f} s, "
        f"{report.frames_per_second:.2f} frames/s, {len(report.failures)} failure(s) re-run"
        + (f"; merged into {job.out_dir}" if merge else ""))
    return report


def run_local(job, *, workers=1, **kwargs) -> BakeReport:
    """The same bake on this machine: ``workers`` Blender processes at a time (1: one after another)."""
    with concurrent.futures.ThreadPoolExecutor(max_workers=workers) as pool:
        def submit(fn, *args, name=""):
            return pool.submit(fn, *args)
        return run_bake(job, submit, concurrent.futures.wait, **kwargs)
