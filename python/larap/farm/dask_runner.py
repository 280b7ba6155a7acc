"""Run a bake on a Dask cluster (Debian's python3-distributed): each task starts headless Blender
for one chunk on a worker (runner.run_bake does the bookkeeping).

    report = run_dask(job, scheduler="tcp://farm-head:8786")   # an existing cluster
    report = run_dask(job, workers=2)                           # a local cluster on 127.0.0.1

Workers need Blender, the larap package (for larap.farm.command) and access to the .blend and the
bake folder at the same paths; with ``installed=True`` they use the add-on installed in their
Blender, else this checkout's scripts (``addon_path``).
"""
from __future__ import annotations

from .runner import run_bake


def local_cluster(workers=2):
    """A LocalCluster of ``workers`` single-threaded worker processes on 127.0.0.1 (no dashboard)."""
    from distributed import LocalCluster
    return LocalCluster(n_workers=int(workers), threads_per_worker=1, processes=True, host="127.0.0.1",
                        dashboard_address=None)


def run_dask(job, *, client=None, scheduler=None, workers=2, **kwargs):
    """Bake ``job`` through a Dask ``client``, a scheduler address, or a new local cluster of
    ``workers`` processes. Other arguments go to runner.run_bake. Returns runner.BakeReport."""
    try:
        from distributed import Client, wait
    except ImportError:
        raise RuntimeError("the Dask runner needs python3-distributed (apt install python3-distributed)") from None
    if client is not None:
        def submit(fn, *args, name=""):
            # pure=False: a re-run is a new task, never a cached result; no Dask-level retries
            # (run_bake reports and re-runs failures itself).
            return client.submit(fn, *args, key=name or None, pure=False, retries=0)
        return run_bake(job, submit, wait, **kwargs)
    cluster = local_cluster(workers) if scheduler is None else None
    try:
        with Client(scheduler or cluster) as own:
            return run_dask(job, client=own, **kwargs)
    finally:
        if cluster is not None:
            cluster.close()
