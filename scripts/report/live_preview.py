"""The add-on's live move inside a Blender window (issue 13, "inside Blender, the live-move cost with
the preview and with mesh write-back"; issue 11's benchmark): runs scripts/bench_preview.py under
Xvfb (software OpenGL is enough) and keeps its rows as live_preview.csv, with the 3D View showing
the 1M-vertex mesh posed by the preview as pictures/preview-1m.png."""
from __future__ import annotations

import json
import os
import shutil
import subprocess

from . import cases, table

SIZES = {"full": [100_000, 1_000_000], "quick": [100_000]}
PAIRS = {"full": 12, "quick": 6}    # (idle, move) redraw pairs per size and mode, at most
BUDGET_S = {"full": 60, "quick": 30}  # seconds of pairs per size and mode
TIMEOUT_S = {"full": 1200, "quick": 400}


class Unavailable(Exception):
    """No window can be opened here; the message says why."""


def rows_from(markdown_path):
    """The JSON rows bench_preview.py appended (its last run) to its results file."""
    info = None
    for line in open(markdown_path):
        if line.startswith("<!-- json: "):
            info = json.loads(line[len("<!-- json: "):].rsplit("-->", 1)[0])
    if info is None:
        raise RuntimeError("bench_preview.py wrote no result")
    return info


def run(out, work, size, log):
    for tool in ("blender", "xvfb-run"):
        if shutil.which(tool) is None:
            raise Unavailable(f"no {tool} on PATH (scripts/setup installs Debian's blender and xvfb)")
    md = os.path.join(work, "live_preview.md")
    if os.path.exists(md):
        os.remove(md)
    picture = os.path.join(out, "pictures", "preview-1m.png") if size == "full" else ""
    cmd = ["xvfb-run", "-a", "-s", "-screen 0 1280x800x24", "blender", "--factory-startup", "--python",
           os.path.join(cases.REPO, "scripts", "bench_preview.py"), "--",
           "--sizes", *map(str, SIZES[size]), "--pairs", str(PAIRS[size]), "--budget", str(BUDGET_S[size]),
           "--out", md]
    if picture:
        cmd += ["--picture", picture]
    log(f"live preview in a window: {', '.join(f'{n:,}' for n in SIZES[size])} vertices")
    env = dict(os.environ, LARAP_ENGINE_PATH=os.path.join(cases.REPO, "python"))
    r = subprocess.run(cmd, capture_output=True, text=True, timeout=TIMEOUT_S[size], env=env)
    if r.returncode or not os.path.exists(md):
        raise RuntimeError(f"bench_preview.py exited {r.returncode}: " + (r.stderr or r.stdout)[-400:].replace("\n", " "))
    info = rows_from(md)
    rows = [dict(row, blender=info.get("blender"), gl=info.get("gl"), date=info.get("date")) for row in info["rows"]]
    table.write_csv(os.path.join(out, "live_preview.csv"), rows)
    return rows
