# Run: PYTHONPATH=python /usr/bin/python3 -m pytest -q tests/python/test_farm_dask.py
# Farm bakes of a small generated shot through a Dask LocalCluster on 127.0.0.1 (2 worker
# processes), each chunk in headless Blender: chunked == one process, failures re-run, and the
# --python-exit-code 1 that makes a failing script fail its task.
import os
import shutil
import stat
import subprocess
import sys

import numpy as np
import pytest

from larap.farm import BakeJob, read_pc2
from larap.farm.command import bind_command, chunk_command, run_process
from larap.farm.merge import merged_path
from larap.farm.runner import FarmError

REPO = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
ADDON = os.path.join(REPO, "addon")
SCENE = os.path.join(REPO, "tests", "blender", "farm_scene.py")
FRAMES = (1, 10)
OBJECTS = ["Bar", "Bar.R"]

pytestmark = pytest.mark.skipif(shutil.which("blender") is None, reason="Blender is not installed (scripts/setup)")


@pytest.fixture(scope="module")
def shot(tmp_path_factory):
    """The generated shot, bound by the farm's bind task (blender_bind.py)."""
    d = tmp_path_factory.mktemp("shot")
    raw, bound = str(d / "shot.blend"), str(d / "bound.blend")
    subprocess.run(["blender", "-b", "--factory-startup", "--python-exit-code", "1", "--python", SCENE, "--",
                    raw, "--two", "--rings", "21", "--frames", str(FRAMES[1])], check=True, capture_output=True)
    res = run_process(bind_command(raw, OBJECTS, 1, bound, addon_path=ADDON))
    assert res["returncode"] == 0, res["output"]
    assert "Bar bound at frame 1" in res["output"] and os.path.exists(bound)
    return bound


@pytest.fixture(scope="module")
def client():
    distributed = pytest.importorskip("distributed", reason="python3-distributed is not installed (scripts/setup)")
    from larap.farm.dask_runner import local_cluster
    cluster = local_cluster(2)
    with distributed.Client(cluster) as c:
        assert len(c.scheduler_info()["workers"]) == 2
        assert c.scheduler.address.startswith("tcp://127.0.0.1:")
        yield c
    cluster.close()


def _bake(shot, client, out, log=None, frames=FRAMES, objects=OBJECTS, **kw):
    from larap.farm.dask_runner import run_dask
    job = BakeJob(blend=shot, objects=objects, frame_start=frames[0], frame_end=frames[1], out_dir=str(out), **kw)
    lines = []
    report = run_dask(job, client=client, addon_path=ADDON, log=lines.append, **(log or {}))
    return job, report, lines


def _caches(job):
    return {name: read_pc2(merged_path(job.out_dir, name))[1] for name in job.objects}


def _diag(P):
    return float(np.linalg.norm(P[0].max(axis=0) - P[0].min(axis=0)))


def test_chunked_bake_equals_one_process(shot, client, tmp_path):
    """The bake as shipped (BakeJob's defaults: warm mode, pre-roll 3, warm tolerance 1e-7):
    several chunk sizes within 1e-4 of the bounding-box diagonal of the one-process bake (and
    within 1e-6: docs/farm.md measured 4.4e-8 on the 12-frame shot), and the
    warm frames really warm-start (fewer iterations than solves from rest to the same tolerance)."""
    assert BakeJob("x.blend", ["A"], 1, 2, "out").warm_tol == 1e-7 and BakeJob("x.blend", ["A"], 1, 2, "out").preroll == 3
    kw = dict(frames=(1, 8))
    job, report, lines = _bake(shot, client, tmp_path / "one", chunk_size=8, **kw)
    ref = _caches(job)
    assert report.chunks == 1 and not report.failures
    assert any("chunk 1-8 done" in l for l in lines) and "0 failure(s)" in lines[-1]
    _, rest, _ = _bake(shot, client, tmp_path / "rest", chunk_size=8, mode="rest", tol=1e-7, **kw)
    warm, cold = report.timing[job.chunks()[0]], rest.timing[job.chunks()[0]]
    assert warm["warm_solves"] == 2 * 7 and cold["rest_solves"] == 2 * 8
    # Frames 2-8 warm-started against frames 1-8 from rest (frame 1, the rest pose, is cheap): a
    # reset would make the warm average the larger (measured 74 against 80 per solve).
    assert warm["warm_iterations"] / warm["warm_solves"] < cold["rest_iterations"] / cold["rest_solves"], (warm, cold)
    for P in ref.values():
        assert P.shape[0] == 8
        assert np.abs(P[-1] - P[0]).max() > 0.2 * _diag(P)  # the shot really moves
    for size in (4, 3):
        job, report, lines = _bake(shot, client, tmp_path / f"c{size}", chunk_size=size, **kw)
        assert report.chunks == -(-8 // size) and not report.failures
        assert sum("done" in l for l in lines) == report.chunks
        for name, P in _caches(job).items():
            err = np.abs(P - ref[name]).max() / _diag(ref[name])
            assert err < 1e-4, (name, size, err)
            assert err < 1e-6, (name, size, err)


def test_rest_mode_is_bit_for_bit(shot, client, tmp_path):
    kw = dict(mode="rest", frames=(3, 8), objects=["Bar.R"])
    job, _, _ = _bake(shot, client, tmp_path / "one", chunk_size=6, **kw)
    ref = _caches(job)
    job, report, _ = _bake(shot, client, tmp_path / "c4", chunk_size=4, **kw)
    assert report.chunks == 2
    for name, P in _caches(job).items():
        assert np.array_equal(P, ref[name]), name


FAKE_BLENDER = """#!/usr/bin/python3
# Stands in for blender: the first run (or every run, FAKE_ALWAYS=1) of chunk FAKE_CHUNK leaves a
# half-written chunk behind and is killed; everything else runs the real Blender.
import os, signal, sys
args = sys.argv[1:]
chunk = args[args.index("--chunk") + 1] if "--chunk" in args else ""
out = args[args.index("--out") + 1] if "--out" in args else ""
if chunk == os.environ["FAKE_CHUNK"]:
    mark = os.path.join(out, "killed-" + chunk)
    if os.environ.get("FAKE_ALWAYS") == "1" or not os.path.exists(mark):
        open(mark, "w").close()
        a, b = (int(x) for x in chunk.split("-"))
        stem = os.path.join(out, "chunks", "Bar.%06d-%06d.pc2" % (a, b))
        os.makedirs(os.path.dirname(stem), exist_ok=True)
        for name in (stem, stem + ".tmp-1-dead"):
            with open(name, "wb") as f:
                f.write(b"POINTCACHE2\\0" + b"\\1" * 50)
        os.kill(os.getpid(), signal.SIGKILL)
os.execvp("blender", ["blender"] + args)
"""


def test_killed_chunk_is_reported_and_rerun(shot, client, tmp_path):
    fake = tmp_path / "fake-blender"
    fake.write_text(FAKE_BLENDER)
    fake.chmod(fake.stat().st_mode | stat.S_IXUSR)
    kw = dict(frames=(1, 6), objects=["Bar"], chunk_size=3)
    job, _, _ = _bake(shot, client, tmp_path / "ref", **kw)
    ref = _caches(job)
    out = tmp_path / "farm"
    run = dict(blender=str(fake), env={"FAKE_CHUNK": "4-6"}, retries=2)
    job, report, lines = _bake(shot, client, out, log=run, **kw)
    (chunk, attempt, reason), = report.failures
    assert str(chunk) == "4-6" and attempt == 1 and "exit code -9" in reason
    assert report.attempts[chunk] == 2
    assert any("chunk 4-6 FAILED (attempt 1 of 3, running it again)" in l for l in lines)
    assert "1 failure(s) re-run" in lines[-1]
    merged = _caches(job)
    assert np.array_equal(merged["Bar"], ref["Bar"])  # the re-run replaced the half-written chunk
    # A chunk that keeps failing: reported, nothing merged, the earlier merged cache untouched.
    before = open(merged_path(str(out), "Bar"), "rb").read()
    run = dict(blender=str(fake), env={"FAKE_CHUNK": "1-3", "FAKE_ALWAYS": "1"}, retries=0)
    with pytest.raises(FarmError, match=r"1 of 2 chunks failed after 1 attempts \(1-3\); nothing merged"):
        _bake(shot, client, out, log=run, **kw)
    assert open(merged_path(str(out), "Bar"), "rb").read() == before


def test_resume_rebakes_chunks_of_an_edited_shot(shot, client, tmp_path):
    """The artist edits the animation, saves over the same file and re-runs with --resume into the
    same folder: the old chunks are refused and baked again, never merged with the new ones."""
    blend = str(tmp_path / "shot.blend")
    shutil.copyfile(shot, blend)
    kw = dict(frames=(1, 6), objects=["Bar"], chunk_size=3)
    job, _, _ = _bake(blend, client, tmp_path / "bake", **kw)
    old = _caches(job)["Bar"]
    _, report, _ = _bake(blend, client, tmp_path / "bake", log={"resume": True}, **kw)
    assert len(report.skipped) == 2 and not report.attempts  # unchanged file: both chunks kept
    # The edit: the same shot keyed over 5 frames instead of 10 (the handle moves twice as fast).
    raw = str(tmp_path / "edited-raw.blend")
    subprocess.run(["blender", "-b", "--factory-startup", "--python-exit-code", "1", "--python", SCENE, "--",
                    raw, "--two", "--rings", "21", "--frames", "5"], check=True, capture_output=True)
    res = run_process(bind_command(raw, OBJECTS, 1, blend, addon_path=ADDON))
    assert res["returncode"] == 0, res["output"]
    job, report, _ = _bake(blend, client, tmp_path / "bake", log={"resume": True}, **kw)
    assert report.skipped == [] and sorted(str(c) for c in report.attempts) == ["1-3", "4-6"]
    new = _caches(job)["Bar"]
    assert np.abs(new[1:] - old[1:]).max() > 0.05 * _diag(old)  # the edited animation, in every chunk


def test_failing_chunk_script_fails_its_task(shot, tmp_path):
    job = BakeJob(blend=shot, objects=["Nope"], frame_start=1, frame_end=2, out_dir=str(tmp_path), chunk_size=2)
    res = run_process(chunk_command(job, job.chunks()[0], addon_path=ADDON), stamp=True)
    assert res["returncode"] == 1, res["output"]
    assert "has no object named 'Nope'" in res["output"]
    assert not os.path.exists(os.path.join(str(tmp_path), "chunks", "chunk.000001-000002.json"))


def test_cli_plan_and_command():
    env = {**os.environ, "PYTHONPATH": os.path.join(REPO, "python")}
    out = subprocess.run([sys.executable, "-m", "larap.farm", "plan", "--frames", "1-10", "--chunk-size", "4",
                          "--preroll", "2"], capture_output=True, text=True, env=env, check=True).stdout
    assert out.split("\n")[:3] == ["1-4", "5-8  (solved from 3)", "9-10  (solved from 7)"]
    bad = subprocess.run([sys.executable, "-m", "larap.farm", "plan", "--frames", "9-1"], capture_output=True,
                         text=True, env=env)
    assert bad.returncode == 1 and "empty" in bad.stderr
