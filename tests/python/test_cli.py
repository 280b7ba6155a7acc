# Run: PYTHONPATH=python /usr/bin/python3 -m pytest tests/python/test_cli.py
"""The command line: the demo, deform with a handle file, and clear errors with exit code 2."""
import json
import os
import subprocess
import sys

import numpy as np
import pytest
from conftest import REPO

import larap
from larap import shapes
from larap.cli import main


def run(*args):
    env = dict(os.environ, PYTHONPATH=os.path.join(REPO, "python"))
    return subprocess.run([sys.executable, "-m", "larap", *args], capture_output=True, text=True, env=env, timeout=300)


def test_demo_writes_a_bent_tube(tmp_path):
    out = tmp_path / "demo.obj"
    r = run("demo", "--out", str(out), "--device", "cpu")
    assert r.returncode == 0, r.stderr
    assert "vertices" in r.stdout and "nodes" in r.stdout and "wrote" in r.stdout
    V, F = larap.load_mesh(out)
    V0, _ = shapes.tube(length=4.0, radius=0.5, segments=48, rings=96)
    assert V.shape == V0.shape
    tip = V[V0[:, 0] > 3.9].mean(0)
    assert tip[1] > 1.5  # the tip turned towards +y


@pytest.fixture
def mesh_file(tmp_path):
    V, F = shapes.tube(4, 0.5, 16, 32)
    path = tmp_path / "tube.obj"
    # an OBJ with extra structure the output must keep
    with open(path, "w") as f:
        f.write("# test tube\no tube\n")
        for v in V:
            f.write("v %.17g %.17g %.17g\n" % tuple(v))
        f.write("vt 0 0\nvn 0 0 1\ng side\ns 1\n")
        for face in F:
            f.write("f " + " ".join(f"{i + 1}/1/1" for i in face) + "\n")
    return path, V


def handle_file(tmp_path, data):
    p = tmp_path / "h.json"
    p.write_text(json.dumps(data))
    return p


def test_deform_with_transform_and_targets(tmp_path, mesh_file):
    path, V = mesh_file
    tip = np.flatnonzero(V[:, 0] > 3.6)
    h = handle_file(tmp_path, {"handles": [
        {"name": "base", "box": {"min": [-1, -1, -1], "max": [0.4, 1, 1]}},
        {"name": "tip", "vertices": tip.tolist(), "transform": {"translate": [0, 0, 1.0]}},
        {"name": "mid", "vertices": [int(np.argmin(np.abs(V[:, 0] - 2)))], "targets": [[2, 0, 0.3]]},
    ]})
    out = tmp_path / "out.obj"
    r = run("deform", str(path), "--handles", str(h), "--out", str(out), "--iterations", "20", "--device", "cpu")
    assert r.returncode == 0, r.stderr
    text = out.read_text()
    assert "vt 0 0" in text and "vn 0 0 1" in text and "g side" in text and "/1/1" in text
    X, _ = larap.load_mesh(out)
    assert abs((X[tip] - V[tip])[:, 2].mean() - 1.0) < 0.05


def tip_misses(tmp_path, mesh_file, *gamma_args):
    """Mean miss of a small tip group next to a big base group, pulled with weight 1 and 10."""
    path, V = mesh_file
    tip = np.flatnonzero(V[:, 0] > 3.8)
    miss = []
    for w in (1, 10):
        h = handle_file(tmp_path, {"handles": [
            {"name": "base", "box": {"min": [-1, -1, -1], "max": [1.5, 1, 1]}},
            {"name": "tip", "vertices": tip.tolist(), "weight": w, "transform": {"translate": [0, 1.5, 0]}},
        ]})
        out = tmp_path / f"w{w}.ply"
        assert main(["deform", str(path), "--handles", str(h), "--out", str(out), "--device", "cpu",
                     "--iterations", "40", *gamma_args]) == 0
        X, _ = larap.load_mesh(out)
        miss.append(np.linalg.norm(X[tip] - (V[tip] + [0, 1.5, 0]), axis=1).mean())
    return miss


def test_groups_are_handle_groups_with_their_weight(tmp_path, mesh_file):
    """Each group of the file pulls as one handle group: a small tip group next to a big base
    group reaches its target, and a larger "weight" makes it pull harder (at gamma 0.1, where the
    stiffness rather than the lattice's own reach sets the miss)."""
    miss = tip_misses(tmp_path, mesh_file, "--gamma", "0.1")
    assert miss[0] < 0.1 * 1.5 and miss[1] < 0.5 * miss[0], miss


def test_group_weight_pulls_harder_at_the_default_stiffness(tmp_path, mesh_file):
    """At the default stiffness the tip is already close (the lattice's reach, not the stiffness,
    sets most of its miss); a weight of 10 still brings it closer (measured: 0.64 x)."""
    miss = tip_misses(tmp_path, mesh_file)
    assert miss[0] < 0.01 * 1.5 and miss[1] < 0.8 * miss[0], miss


def test_rotation_forms(tmp_path, mesh_file):
    path, V = mesh_file
    outs = []
    for rot in ({"axis": [0, 0, 1], "angle": 30}, {"quaternion": [np.cos(np.pi / 12), 0, 0, np.sin(np.pi / 12)]}):
        h = handle_file(tmp_path, {"handles": [{"box": {"min": [-1, -1, -1], "max": [0.4, 1, 1]}},
                                               {"box": {"min": [3.6, -1, -1], "max": [5, 1, 1]}, "transform": {"rotate": rot}}]})
        out = tmp_path / "rot.ply"
        assert main(["deform", str(path), "--handles", str(h), "--out", str(out), "--device", "cpu"]) == 0
        outs.append(larap.load_mesh(out)[0])
    assert np.abs(outs[0] - outs[1]).max() < 1e-6


@pytest.mark.parametrize("data,words", [
    ({"handles": [{"vertices": [0, 10**9]}]}, "out of range"),
    ({"handles": [{"box": {"min": [9, 9, 9], "max": [10, 10, 10]}}]}, "selects no vertex"),
    ({"handles": [{"vertices": [0, 1]}, {"vertices": [1, 2]}]}, "in both"),
    ({"handles": [{"vertices": [0], "targets": [[0, 0]]}]}, "targets"),
    ({"handles": [{"vertices": [0], "weight": -1}]}, "weight"),
    ({"handles": [{"vertices": [0], "weight": "heavy"}]}, "weight"),
    ({"handles": [{"vertices": [0], "transform": {"rotate": {"axis": [0, 0, 0], "angle": 3}}}]}, "axis"),
    ({"handles": [{"vertices": [0], "transform": {"shear": 1}}]}, "unknown"),
    ({"nothing": []}, "list 'handles'"),
    ({"handles": [{"vertices": [0], "weight": 10**400}]}, "too large"),
    ({"handles": [{"vertices": [10**30]}]}, "too large"),
])
def test_bad_handle_files(tmp_path, mesh_file, data, words, capsys):
    path, _ = mesh_file
    h = handle_file(tmp_path, data)
    assert main(["deform", str(path), "--handles", str(h), "--out", str(tmp_path / "o.obj")]) == 2
    err = capsys.readouterr().err
    assert err.startswith("larap: error:") and words in err


def test_bad_files_exit_2(tmp_path, mesh_file, capsys):
    path, _ = mesh_file
    h = handle_file(tmp_path, {"handles": []})
    assert main(["deform", str(tmp_path / "missing.obj"), "--handles", str(h), "--out", "x.obj"]) == 2
    assert "missing.obj" in capsys.readouterr().err
    bad = tmp_path / "bad.json"
    bad.write_text("{not json")
    assert main(["deform", str(path), "--handles", str(bad), "--out", "x.obj"]) == 2
    assert "JSON" in capsys.readouterr().err
    latin = tmp_path / "latin.json"
    latin.write_bytes('{"handles": [{"name": "Ärm", "vertices": [0]}]}'.encode("latin-1"))
    assert main(["deform", str(path), "--handles", str(latin), "--out", "x.obj"]) == 2
    assert "latin.json: not UTF-8" in capsys.readouterr().err
    assert main(["deform", str(path), "--handles", str(h), "--out", "x.obj", "--iterations", str(2**31)]) == 2
    assert "iterations is out of range" in capsys.readouterr().err
    trunc = tmp_path / "trunc.off"
    trunc.write_text("OFF\n100 50 0\n0 0 0\n")
    assert main(["deform", str(trunc), "--handles", str(h), "--out", "x.obj"]) == 2
    assert main(["deform", str(path), "--handles", str(h), "--out", str(tmp_path / "o.obj"), "--cells", "-3"]) == 2
    assert "cells" in capsys.readouterr().err


def test_demo_with_a_hierarchy(tmp_path):
    out = tmp_path / "demo3.obj"
    assert main(["demo", "--out", str(out), "--device", "cpu", "--levels", "3", "--iterations", "10"]) == 0
    V, _ = larap.load_mesh(out)
    V0, _ = shapes.tube(length=4.0, radius=0.5, segments=48, rings=96)
    assert V[V0[:, 0] > 3.9].mean(0)[1] > 1.5
    assert main(["demo", "--out", str(out), "--levels", "0"]) == 2
