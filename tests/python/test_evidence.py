# Run: PYTHONPATH=python /usr/bin/python3 -m pytest tests/python/test_evidence.py
"""Smoke test of the evidence report (scripts/evidence): at its tiny size (seconds, no Blender,
no CGAL) the report folder has its summary, its CSV files with a handle count on every row, its
plots, and a status that names every part and why one was skipped. The full report's figures
are not checked here (speed is shown by the report itself, never by a test)."""
import csv
import json
import os
import subprocess
import sys

import pytest
from conftest import REPO

sys.path.insert(0, os.path.join(REPO, "scripts"))


def rows(path):
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


@pytest.fixture(scope="module")
def report(tmp_path_factory):
    out = tmp_path_factory.mktemp("evidence")
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([os.path.join(REPO, "python"), os.path.join(REPO, "scripts")]),
               MPLBACKEND="Agg")
    r = subprocess.run([sys.executable, "-m", "report", "--tiny", "--out", str(out)], env=env, cwd=REPO,
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stdout[-2000:] + r.stderr[-2000:]
    return out


def test_folder_structure(report):
    for name in ("README.md", "status.json", "table1_cpu.csv", "convergence_cpu.csv", "time_to_quality_cpu.csv",
                 "quality.csv"):
        assert (report / name).is_file(), name
    plots = os.listdir(report / "plots")
    assert "table1_cpu_vs_mesh.png" in plots and any(p.startswith("time_to_quality_cpu") for p in plots)
    assert not (report / "work" / "meshes").exists()  # intermediate meshes are removed unless kept


def test_every_table1_row_states_its_handles(report):
    table = rows(report / "table1_cpu.csv")
    assert {r["levels"] for r in table} == {"1", "2"}
    for r in table:
        assert int(r["handles"]) > 0 and int(r["handle_groups"]) >= 2
        assert float(r["handle_percent"]) >= 5.0  # handles as an artist makes them
        assert float(r["total_ms"]) > 0


def test_time_to_quality_reaches_the_threshold(report):
    ttq = rows(report / "time_to_quality_cpu.csv")
    assert {r["levels"] for r in ttq} == {"1", "2", "3"}
    assert any(r["iterations_to_quality"] for r in ttq)
    curve = rows(report / "convergence_cpu.csv")
    assert min(float(r["relative"]) for r in curve) <= 1e-3


def test_status_names_skips_and_summary_says_them(report):
    status = json.load(open(report / "status.json"))
    for part in ("table1", "time_to_quality", "gpu", "quality", "plots"):
        assert part in status["parts"], part
    assert all(p["state"] != "failed" for p in status["parts"].values()), status["parts"]
    import larap
    if "cuda" not in larap.available_devices():
        assert status["parts"]["gpu"]["state"] == "skipped" and "CUDA" in status["parts"]["gpu"]["reason"]
    text = (report / "README.md").read_text()
    assert "## Against the targets" in text and "## Parts run, skipped and failed" in text
    assert "gpu | skipped" in text or "cuda" in larap.available_devices()


def test_quality_of_the_bend_is_measured(report):
    (row,) = rows(report / "quality.csv")
    assert row["case"] == "bar_bend90"
    assert abs(float(row["volume_change"])) < 0.05  # the lattice keeps the bar's volume
    assert float(row["handle_error"]) < 0.02
