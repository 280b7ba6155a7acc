# Run: PYTHONPATH=python /usr/bin/python3 -m pytest -q tests/python/test_farm_merge.py
# The engine-neutral farm pieces without Blender: chunk plans, PC2 files, manifests and the merge's
# refusal of missing, truncated, corrupt or foreign chunks.
import os
import struct

import numpy as np
import pytest

from larap.farm import BakeJob, MergeError, parse_frames, plan_chunks, read_pc2, read_pc2_header, write_pc2
from larap.farm.command import bind_command, chunk_command
from larap.farm.manifest import chunk_dir, chunk_pc2_path, manifest_path, write_manifest
from larap.farm.merge import frame_ranges, merge_bake, merged_path
from larap.farm.pc2 import PC2Error, write_atomic


def test_plan_covers_every_frame_once_with_clamped_preroll():
    for first, last, size, pre in ((1, 100, 25, 3), (-5, 7, 4, 10), (10, 10, 1, 2), (1, 12, 5, 0)):
        chunks = plan_chunks(first, last, size, pre)
        frames = [f for c in chunks for f in range(c.start, c.end + 1)]
        assert frames == list(range(first, last + 1))
        assert all(1 <= c.frames <= size for c in chunks)
        assert chunks[0].solve_start == first  # the first chunk is the one-process start
        assert all(c.solve_start == max(first, c.start - pre) for c in chunks)


def test_plan_and_frames_reject_bad_input():
    with pytest.raises(ValueError, match="empty"):
        plan_chunks(10, 1, 5)
    with pytest.raises(ValueError, match="chunk_size"):
        plan_chunks(1, 10, 0)
    with pytest.raises(TypeError, match="preroll"):
        plan_chunks(1, 10, 5, 1.5)
    assert parse_frames("3-7") == (3, 7) and parse_frames("47") == (47, 47) and parse_frames("1..4") == (1, 4)
    for bad in ("", "a-b", "7-3", "1-2-3"):
        with pytest.raises(ValueError):
            parse_frames(bad)
    with pytest.raises(ValueError, match="beyond Blender's frames"):  # was: a plan of 1e11 chunks
        parse_frames("1-100000000000")
    with pytest.raises(ValueError, match="at most 1048574"):
        plan_chunks(1, 1048575, 1)
    with pytest.raises(ValueError, match="mode"):
        BakeJob("x.blend", ["A"], 1, 10, "out", mode="fast")
    with pytest.raises(ValueError, match="object"):
        BakeJob("x.blend", [], 1, 10, "out")
    with pytest.raises(ValueError, match="warm_tol"):
        BakeJob("x.blend", ["A"], 1, 10, "out", warm_tol=0.0)


def test_pc2_round_trip_and_header_layout(tmp_path):
    P = np.random.default_rng(1).normal(size=(4, 7, 3)).astype(np.float32)
    path = str(tmp_path / "a.pc2")
    write_pc2(path, P, 11)
    raw = open(path, "rb").read()
    assert len(raw) == 32 + 4 * 7 * 12
    assert struct.unpack("<12siiffi", raw[:32]) == (b"POINTCACHE2\0", 1, 7, 11.0, 1.0, 4)
    head, Q = read_pc2(path)
    assert head == {"points": 7, "start": 11.0, "rate": 1.0, "samples": 4}
    assert np.array_equal(P, Q)
    assert os.listdir(tmp_path) == ["a.pc2"]  # no temporary file left
    with pytest.raises(ValueError, match="not finite"):
        write_pc2(str(tmp_path / "nan.pc2"), np.full((1, 2, 3), np.nan), 1)
    with open(path, "r+b") as f:
        f.truncate(100)
    with pytest.raises(PC2Error, match="truncated"):
        read_pc2_header(path)


def test_atomic_write_keeps_the_old_file_when_the_writer_dies(tmp_path):
    path = str(tmp_path / "c.pc2")
    write_pc2(path, np.zeros((1, 2, 3)), 1)
    before = open(path, "rb").read()

    def dies():
        yield b"POINTCACHE2\0 half a file"
        raise KeyboardInterrupt  # the task is killed mid-write

    with pytest.raises(KeyboardInterrupt):
        write_atomic(path, dies())
    assert open(path, "rb").read() == before
    assert os.listdir(tmp_path) == ["c.pc2"]


def test_every_command_line_exits_nonzero_on_failure():
    job = BakeJob("/s/shot.blend", ["Body", "Prop A"], 1, 10, "/s/out", chunk_size=4, preroll=2, warm_tol=1e-7)
    cmds = [chunk_command(job, c, installed=i) for c in job.chunks() for i in (False, True)]
    cmds += [bind_command("/s/shot.blend", ["Body"], 1, "/s/out/bound.blend", installed=i) for i in (False, True)]
    for cmd in cmds:
        k = cmd.index("--python-exit-code")
        assert cmd[k + 1] == "1" and cmd[:2] == ["blender", "-b"]
        assert cmd.index("--python-exit-code") < cmd.index("--")
    c = chunk_command(job, job.chunks()[1])
    tail = c[c.index("--") + 1:]
    assert tail[:4] == ["--object", "Body", "--object", "Prop A"]
    assert tail[tail.index("--chunk") + 1] == "5-8" and tail[tail.index("--preroll") + 1] == "2"


# ------------------------------------------------------------------------------------------------
# The merge

def _shot(tmp_path, content=b"BLENDER-v304 the artist's shot, version 1"):
    """A stand-in for the .blend (the merge only hashes it)."""
    path = tmp_path / "shot.blend"
    path.write_bytes(content)
    return str(path)


def _write_chunk(job, c, shift=0.0, binds=None, points=None):
    """Chunk ``c`` of ``job`` as blender_chunk.py writes it: frame f of object k is filled with
    f + 100k + shift, 5 + k points (``points``: name -> another count)."""
    counts = {}
    for k, name in enumerate(job.objects):
        P = np.empty((c.frames, (points or {}).get(name, 5 + k), 3), np.float32)
        for i, f in enumerate(range(c.start, c.end + 1)):
            P[i] = f + 100 * k + shift
        write_pc2(chunk_pc2_path(job.out_dir, name, c), P, c.start)
        counts[name] = P.shape[1]
    write_manifest(job.out_dir, c, job.signature(), counts, {"bind": 0.0, "solve": 0.0, "write": 0.0},
                   binds or {n: "bound-once" for n in job.objects})


def _fake_bake(tmp_path, chunk_size=4, objects=("Bar", "Odd name/1")):
    """A finished bake of frames 1-10 written without Blender: frame f of object k is filled with f + 100k."""
    job = BakeJob(blend=_shot(tmp_path), objects=list(objects), frame_start=1, frame_end=10,
                  out_dir=str(tmp_path), chunk_size=chunk_size)
    os.makedirs(chunk_dir(job.out_dir), exist_ok=True)
    for c in job.chunks():
        _write_chunk(job, c)
    return job


def test_merge_joins_chunks_in_frame_order(tmp_path):
    job = _fake_bake(tmp_path)
    summary = merge_bake(job)
    for k, name in enumerate(job.objects):
        head, P = read_pc2(merged_path(job.out_dir, name))
        assert head["start"] == 1.0 and head["samples"] == 10 and head["points"] == 5 + k
        assert np.array_equal(P[:, 0, 0], np.arange(1, 11) + 100 * k)
        assert summary["objects"][name]["file"] == os.path.basename(merged_path(job.out_dir, name))
    assert "/" not in os.path.basename(merged_path(job.out_dir, "Odd name/1"))


def _refused(job, *match):
    merged = merged_path(job.out_dir, job.objects[0])
    before = open(merged, "rb").read() if os.path.exists(merged) else None
    with pytest.raises(MergeError) as info:
        merge_bake(job)
    for m in match:
        assert m in str(info.value), str(info.value)
    after = open(merged, "rb").read() if os.path.exists(merged) else None
    assert after == before  # an earlier merged cache is never touched
    return info.value


def test_merge_names_missing_frames(tmp_path):
    job = _fake_bake(tmp_path)
    merge_bake(job)
    os.remove(manifest_path(job.out_dir, job.chunks()[1]))  # chunk 5-8 never finished
    err = _refused(job, "frames 5-8 of 1-10", "chunk 5-8: not finished")
    assert err.missing_frames == [5, 6, 7, 8]


def test_merge_refuses_a_truncated_chunk(tmp_path):
    job = _fake_bake(tmp_path)
    path = chunk_pc2_path(job.out_dir, "Bar", job.chunks()[2])
    with open(path, "r+b") as f:
        f.truncate(os.path.getsize(path) - 7)
    _refused(job, "frames 9-10", "chunk 9-10", "truncated")


def test_merge_refuses_a_corrupt_chunk_of_the_right_size(tmp_path):
    job = _fake_bake(tmp_path)
    merge_bake(job)
    path = chunk_pc2_path(job.out_dir, "Odd name/1", job.chunks()[0])
    raw = bytearray(open(path, "rb").read())
    raw[40] ^= 0x01
    open(path, "wb").write(bytes(raw))
    _refused(job, "frames 1-4", "corrupt")


def test_merge_refuses_chunks_of_another_bake(tmp_path):
    job = _fake_bake(tmp_path)
    other = BakeJob(blend=job.blend, objects=["Bar", "Odd name/1"], frame_start=1, frame_end=10,
                    out_dir=str(tmp_path), chunk_size=4, preroll=5)
    _refused(other, "another bake", "preroll")
    other = BakeJob(blend=job.blend, objects=["Bar", "Odd name/1"], frame_start=1, frame_end=10,
                    out_dir=str(tmp_path), chunk_size=5)
    _refused(other, "frames 1-10", "not finished")


def test_merge_refuses_chunks_of_an_earlier_version_of_the_shot(tmp_path):
    """The artist edits the animation and saves: chunks baked from the old file are refused, even
    with the same path, size and settings."""
    job = _fake_bake(tmp_path)
    merge_bake(job)
    before = open(job.blend, "rb").read()
    _shot(tmp_path, before.replace(b"version 1", b"version 2"))  # same size, other content
    again = BakeJob(blend=job.blend, objects=job.objects, frame_start=1, frame_end=10, out_dir=job.out_dir,
                    chunk_size=4)
    assert again.signature()["blend_sha256"] != job.signature()["blend_sha256"]
    err = _refused(again, "frames 1-10", "another version", "blend_sha256")
    assert len(err.problems) == 3
    # The same file under another path is another shot too.
    os.makedirs(tmp_path / "copy")
    other = _shot(tmp_path / "copy", before)
    _refused(BakeJob(blend=other, objects=job.objects, frame_start=1, frame_end=10, out_dir=job.out_dir,
                     chunk_size=4), "another version", "blend")
    # A missing .blend: a clear error before anything is compared or written.
    with pytest.raises(OSError, match="cannot read the bake's .blend"):
        merge_bake(BakeJob(blend=str(tmp_path / "gone.blend"), objects=job.objects, frame_start=1, frame_end=10,
                           out_dir=job.out_dir, chunk_size=4))


def test_merge_refuses_chunks_bound_differently(tmp_path):
    job = _fake_bake(tmp_path)
    _write_chunk(job, job.chunks()[1], binds={"Bar": "bound-once", "Odd name/1": "another lattice"})
    err = _refused(job, "'Odd name/1' was bound differently", "chunks 1-4, 9-10; chunks 5-8")
    assert not os.path.exists(os.path.join(job.out_dir, "bake.json"))


def _files(tmp_path):
    return {p: open(os.path.join(tmp_path, p), "rb").read() for p in os.listdir(tmp_path)
            if os.path.isfile(os.path.join(tmp_path, p))}


def test_merge_refused_for_the_second_object_writes_nothing(tmp_path):
    """The second object has another vertex count in one chunk: no object's cache and no bake.json
    is written, nor any temporary file left, whether or not an earlier merge is there."""
    job = _fake_bake(tmp_path)
    _write_chunk(job, job.chunks()[1], points={"Odd name/1": 7})
    before = _files(tmp_path)
    assert before == {"shot.blend": before["shot.blend"]}
    _refused(job, "'Odd name/1' has different vertex counts", "chunks 1-4, 9-10: 6; chunks 5-8: 7")
    assert _files(tmp_path) == before
    # With an earlier merged cache: it stays as it was, every file of it.
    _write_chunk(job, job.chunks()[1], shift=0.0)
    merge_bake(job)
    before = _files(tmp_path)
    _write_chunk(job, job.chunks()[1], shift=0.25, points={"Odd name/1": 7})
    _refused(job, "different vertex counts")
    assert _files(tmp_path) == before


def test_merge_that_fails_while_streaming_renames_nothing(tmp_path):
    """A chunk of the second object whose positions turn out not finite (checksum and header
    valid): the first object's finished temporary file is never renamed into place."""
    job = _fake_bake(tmp_path)
    merge_bake(job)
    before = _files(tmp_path)
    c = job.chunks()[2]
    path = chunk_pc2_path(job.out_dir, "Odd name/1", c)
    raw = bytearray(open(path, "rb").read())
    raw[32:36] = np.float32(np.nan).tobytes()
    open(path, "wb").write(bytes(raw))
    write_manifest(job.out_dir, c, job.signature(), {"Bar": 5, "Odd name/1": 6}, {},
                   {n: "bound-once" for n in job.objects})
    err = _refused(job, "chunk 9-10", "non-finite")
    assert err.missing_frames == [9, 10]
    assert _files(tmp_path) == before


def test_merge_holds_one_chunk_at_a_time(tmp_path, monkeypatch):
    """Memory: the merge never loads the chunks up front nor builds an object's whole cache; at
    most one chunk's positions are alive at any time."""
    import gc
    import tracemalloc
    import weakref
    from larap.farm import manifest, merge, pc2
    frames, points, size = 60, 20000, 4
    job = BakeJob(blend=_shot(tmp_path), objects=["A", "B"], frame_start=1, frame_end=frames,
                  out_dir=str(tmp_path), chunk_size=size)
    os.makedirs(chunk_dir(job.out_dir))
    rng = np.random.default_rng(3)
    ref = {n: rng.normal(size=(frames, points, 3)).astype(np.float32) for n in job.objects}
    for c in job.chunks():
        for n in job.objects:
            write_pc2(chunk_pc2_path(job.out_dir, n, c), ref[n][c.start - 1:c.end], c.start)
        write_manifest(job.out_dir, c, job.signature(), {n: points for n in job.objects}, {},
                       {n: "bound-once" for n in job.objects})
    live, peak = [0], [0]

    def counted(loader):
        def load(*args, **kw):
            out = loader(*args, **kw)
            arrays = [a for a in (out if isinstance(out, tuple) else (out,)) if isinstance(a, np.ndarray)]
            for a in arrays:
                live[0] += 1
                weakref.finalize(a, lambda: live.__setitem__(0, live[0] - 1))
            peak[0] = max(peak[0], live[0])
            return out
        return load

    monkeypatch.setattr(manifest, "read_pc2", counted(pc2.read_pc2))  # the loader the merge used to call
    monkeypatch.setattr(merge, "_read_chunk", counted(getattr(merge, "_read_chunk", None)), raising=False)
    gc.collect()
    tracemalloc.start()
    try:
        merge_bake(job)
        _, most = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert peak[0] == 1, peak[0]
    one_object = frames * points * 12
    assert most < one_object / 4, (most, one_object)  # a chunk: 1/15 of an object, plus 1 MiB read blocks
    for n in job.objects:
        _, P = read_pc2(merged_path(job.out_dir, n))
        assert np.array_equal(P, ref[n])


def test_resume_rebakes_the_chunks_of_an_earlier_version_of_the_shot(tmp_path):
    """--resume after the artist changed the .blend: no old chunk is kept, every one is baked
    again, and the merged cache is the new version's."""
    import concurrent.futures
    from larap.farm.runner import run_bake
    job = _fake_bake(tmp_path)
    launched = []

    def submit(fn, cmd, *args, name=""):
        chunk = next(c for c in job.chunks() if str(c) == cmd[cmd.index("--chunk") + 1])
        launched.append(str(chunk))
        _write_chunk(current, chunk, shift=0.5)  # what Blender would bake from the new file
        fut = concurrent.futures.Future()
        fut.set_result({"returncode": 0, "seconds": 0.0, "output": ""})
        return fut

    current = BakeJob(blend=job.blend, objects=job.objects, frame_start=1, frame_end=10, out_dir=job.out_dir,
                      chunk_size=4)
    report = run_bake(current, submit, concurrent.futures.wait, resume=True, log=lambda *_: None)
    assert launched == [] and len(report.skipped) == 3  # same file: every chunk kept
    _shot(tmp_path, b"BLENDER-v304 the artist's shot, version 2")
    current = BakeJob(blend=job.blend, objects=job.objects, frame_start=1, frame_end=10, out_dir=job.out_dir,
                      chunk_size=4)
    report = run_bake(current, submit, concurrent.futures.wait, resume=True, log=lambda *_: None)
    assert sorted(launched) == ["1-4", "5-8", "9-10"] and report.skipped == []
    _, P = read_pc2(merged_path(job.out_dir, "Bar"))
    assert np.array_equal(P[:, 0, 0], np.arange(1, 11) + 0.5)


def test_merge_ignores_temporary_files_of_killed_writers(tmp_path):
    job = _fake_bake(tmp_path)
    junk = chunk_pc2_path(job.out_dir, "Bar", job.chunks()[0]) + ".tmp-999-dead"
    open(junk, "wb").write(b"POINTCACHE2\0garbage")
    merge_bake(job)
    _, P = read_pc2(merged_path(job.out_dir, "Bar"))
    assert np.array_equal(P[:, 0, 0], np.arange(1, 11))


def test_frame_ranges():
    assert frame_ranges([9, 1, 2, 3, 7, 10]) == "1-3, 7, 9-10"


NODE_COMPILE = r"""
const vm = require("vm"), fs = require("fs"), path = require("path");
const author = {
  Task: (name, type) => ({ name, cmds: [], addCommand(c) { this.cmds.push(c); }, addDependency() {} }),
  Command: (name, parameters) => parameters,
};
const ctx = vm.createContext({ author, path: path.posix, print: () => {} });
vm.runInContext(fs.readFileSync(process.argv[1], "utf8"), ctx);
const tasks = [];
ctx.compileJob({ settings: JSON.parse(process.argv[2]), addTask: (t) => tasks.push(t) });
console.log(JSON.stringify(tasks.map((t) => ({ name: t.name, args: t.cmds[0].args }))));
"""


def test_flamenco_job_type_matches_the_python_commands():
    """The Flamenco job type builds the same chunk arguments as larap.farm.command, and its merge
    task's arguments describe the same bake (same signature) as its chunks."""
    import json
    import shutil
    import subprocess
    from larap.farm.command import chunk_args
    if shutil.which("node") is None:
        pytest.skip("node is not installed (scripts/setup installs nodejs)")
    script = os.path.join(os.path.dirname(__file__), "..", "..", "flamenco", "larap-bake.js")
    settings = {"frames": "2-11", "chunk_size": 4, "preroll": 2, "objects": '["Body", "Prop, A"]',
                "bake_output": "/farm/bake", "device": "cpu", "mode": "warm", "warm_tol": 1e-7, "tol": 1e-10,
                "max_iterations": 500, "bind": False, "blendfile": "/farm/shot.blend"}
    out = subprocess.run(["node", "-e", NODE_COMPILE, script, json.dumps(settings)], capture_output=True,
                         text=True, check=True).stdout
    tasks = json.loads(out)
    job = BakeJob("/farm/shot.blend", ["Body", "Prop, A"], 2, 11, "/farm/bake", chunk_size=4, preroll=2,
                  warm_tol=1e-7, tol=1e-10, max_iterations=500, device="cpu")

    def after_dashes(args):
        tail = args[args.index("--") + 1:]
        return [str(float(v)) if i > 0 and tail[i - 1] in ("--tol", "--warm-tol") else v for i, v in enumerate(tail)]

    chunks = [t for t in tasks if t["name"].startswith("larap-chunk-")]
    assert [t["name"] for t in chunks] == [f"larap-chunk-{c}" for c in job.chunks()]
    for t, c in zip(chunks, job.chunks()):
        assert sorted(after_dashes(t["args"])) == sorted(after_dashes(["--"] + chunk_args(job, c)))
    import argparse
    from larap.farm import cli
    merge = after_dashes(tasks[-1]["args"])
    parser = argparse.ArgumentParser()
    sub = parser.add_subparsers()
    cli._job_args(sub.add_parser("merge"))
    merged = cli._job(parser.parse_args(merge))
    assert merged.settings() == job.settings() and merged.blend == job.blend  # the .blend is hashed on the farm
