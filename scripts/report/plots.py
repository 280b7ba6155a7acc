"""The report's plots (matplotlib, Agg), each from the CSV files in the report folder, so a GPU
CSV copied in later is plotted too when the plots are redrawn (python3 -m report.plots DIR)."""
from __future__ import annotations

import os
import sys

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

from .table import num, read_csv  # noqa: E402

STAGES = ("rotations_ms", "rhs_ms", "solve_ms", "coarse_ms", "transfer_ms", "total_ms")


def _save(fig, out, name):
    path = os.path.join(out, "plots", name)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def table1_sweeps(out):
    """Time against mesh size (at the most common lattice size) and against lattice size (on
    the largest mesh), per device and level count."""
    made = []
    for device in ("cpu", "cuda"):
        rows = read_csv(os.path.join(out, f"table1_{device}.csv"))
        if not rows:
            continue
        nodes_t = max({r["nodes_target"] for r in rows}, key=lambda n: sum(r["nodes_target"] == n for r in rows))
        faces_t = max({r["faces_target"] for r in rows}, key=lambda f: (sum(r["faces_target"] == f for r in rows), int(f)))
        for what, key, fixed, label in (("mesh", "faces", ("nodes_target", nodes_t), "mesh faces"),
                                        ("lattice", "nodes", ("faces_target", faces_t), "lattice nodes")):
            sel = [r for r in rows if r[fixed[0]] == fixed[1]]
            if len(sel) < 2:
                continue
            fig, ax = plt.subplots(figsize=(7, 4.2))
            for levels, style in (("1", "-"), ("2", "--")):
                pts = sorted((num(r[key]), r) for r in sel if r["levels"] == levels)
                if not pts:
                    continue
                x = [p[0] for p in pts]
                for stage, color in zip(STAGES, ("C0", "C1", "C2", "C4", "C3", "k")):
                    y = [num(p[1].get(stage)) for p in pts]
                    if max(y) > 0:
                        ax.plot(x, y, style, color=color, marker="o", ms=3,
                                label=f"{stage[:-3]} ({'hierarchy' if levels == '2' else 'single level'})")
            ax.set_xscale("log")
            ax.set_yscale("log")
            ax.set_xlabel(label)
            ax.set_ylabel("ms per pose update (5 flip-flops + transfer)")
            fixed_txt = f"{int(fixed[1]):,} nodes" if what == "mesh" else f"{int(fixed[1]):,} faces"
            ax.set_title(f"{device.upper()}: time against {label} ({fixed_txt})")
            ax.legend(fontsize=6, ncol=2)
            made.append(_save(fig, out, f"table1_{device}_vs_{what}.png"))
    return made


def convergence(out):
    made = []
    for device in ("cpu", "cuda"):
        rows = read_csv(os.path.join(out, f"convergence_{device}.csv"))
        if not rows:
            continue
        for faces in sorted({r["faces"] for r in rows}, key=int):
            sel = [r for r in rows if r["faces"] == faces]
            fig, ax = plt.subplots(figsize=(7, 4.2))
            for levels in sorted({r["levels"] for r in sel}):
                pts = sorted((num(r["ms"]), max(num(r["relative"]), 1e-7), int(r["iteration"]))
                             for r in sel if r["levels"] == levels)
                ax.plot([p[0] for p in pts], [p[1] for p in pts], marker="o", ms=3,
                        label=f"{'single level' if levels == '1' else levels + ' levels'}")
            ax.axhline(1e-3, color="k", lw=0.8, ls=":", label="0.1% of the converged energy")
            ax.set_xscale("log")
            ax.set_yscale("log")
            ax.set_xlabel("ms (one solve from the warm pose, coarse levels included)")
            ax.set_ylabel("E / E* - 1")
            ax.set_title(f"{device.upper()}: time to quality, {int(faces):,} faces, {sel[0]['nodes']} nodes, "
                         f"{sel[0]['handles']} handle vertices")
            ax.legend(fontsize=8)
            made.append(_save(fig, out, f"time_to_quality_{device}_{faces}.png"))
    return made


def quality_bars(out):
    rows = read_csv(os.path.join(out, "quality.csv"))
    if not rows:
        return []
    made = []
    cases_ = list(dict.fromkeys(r["case"] for r in rows))
    methods = ["larap_bspline", "larap_trilinear", "surface_arap"]
    for metric, label in (("volume_change", "|volume change| (%)"), ("edge_p95", "edge-length distortion, 95th pct (%)"),
                          ("edge_mean", "edge-length distortion, mean (%)"), ("handle_error", "handle error (% of diagonal)")):
        fig, ax = plt.subplots(figsize=(9, 4))
        w = 0.27
        for k, m in enumerate(methods):
            ys = []
            for c in cases_:
                r = next((r for r in rows if r["case"] == c and r["method"] == m), None)
                ys.append(abs(num(r.get(metric))) * 100 if r else float("nan"))
            ax.bar([i + (k - 1) * w for i in range(len(cases_))], ys, w, label=m)
        ax.set_xticks(range(len(cases_)))
        ax.set_xticklabels(cases_, rotation=30, ha="right", fontsize=8)
        ax.set_ylabel(label)
        ax.legend(fontsize=8)
        made.append(_save(fig, out, f"quality_{metric}.png"))
    return made


def blender(out):
    rows = [r for r in read_csv(os.path.join(out, "blender_peers.csv")) if r.get("ok") == "True"]
    if not rows:
        return []
    fig, axes = plt.subplots(1, 2, figsize=(10, 4))
    for ax, key, label in ((axes[0], "bind_ms", "bind ms"), (axes[1], "move_ms", "ms per handle move")):
        for m in sorted({r["method"] for r in rows}):
            pts = sorted((num(r["vertices"]), num(r[key])) for r in rows if r["method"] == m)
            ax.plot([p[0] for p in pts], [p[1] for p in pts], marker="o", label=m)
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_xlabel("vertices")
        ax.set_ylabel(label)
        ax.legend(fontsize=8)
    fig.suptitle("Inside Blender 3.4 (headless): bind and handle move")
    return [_save(fig, out, "blender_peers.png")]


def run(out):
    os.makedirs(os.path.join(out, "plots"), exist_ok=True)
    return table1_sweeps(out) + convergence(out) + quality_bars(out) + blender(out)


if __name__ == "__main__":
    print("\n".join(run(sys.argv[1] if len(sys.argv) > 1 else "report")))
