#!/usr/bin/python3
"""Draw the farm bake's task graph (docs/farm-task-graph.png) with matplotlib.

    /usr/bin/python3 scripts/farm_task_graph.py [OUT.png]
"""
import os
import sys

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
from matplotlib.patches import FancyArrowPatch, FancyBboxPatch  # noqa: E402

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def box(ax, x, y, w, h, title, lines, color):
    ax.add_patch(FancyBboxPatch((x - w / 2, y - h / 2), w, h, boxstyle="round,pad=0.02,rounding_size=0.08",
                                fc=color, ec="#333333", lw=1.2))
    ax.text(x, y + h / 2 - 0.17, title, ha="center", va="top", fontsize=10.5, weight="bold")
    ax.text(x, y - 0.12, "\n".join(lines), ha="center", va="center", fontsize=8, family="monospace")


def arrow(ax, a, b):
    ax.add_patch(FancyArrowPatch(a, b, arrowstyle="-|>", mutation_scale=14, lw=1.2, color="#333333",
                                 shrinkA=2, shrinkB=2))


def main():
    out = sys.argv[1] if len(sys.argv) > 1 else os.path.join(ROOT, "docs", "farm-task-graph.png")
    fig, ax = plt.subplots(figsize=(11, 5.4), dpi=110)
    ax.set_xlim(0, 11)
    ax.set_ylim(0, 5.4)
    ax.axis("off")
    box(ax, 1.3, 2.7, 2.2, 1.5, "larap-bind", ["optional", "bind at a frame", "save bound.blend"], "#e8e8e8")
    chunks = [("larap-chunk-1-25", "frames 1-25", "from rest at 1"),
              ("larap-chunk-26-50", "frames 26-50", "pre-roll 23-25"),
              ("larap-chunk-76-100", "frames 76-100", "pre-roll 73-75")]
    ys = [4.4, 2.7, 0.75]
    for (name, frames, start), y in zip(chunks, ys):
        box(ax, 5.2, y, 3.1, 1.25, name, [frames + ", " + start, "-> chunks/<obj>.<a>-<b>.pc2", "-> chunk.<a>-<b>.json (last)"],
            "#d7e9f7")
        arrow(ax, (2.4, 2.7), (3.65, y))
        arrow(ax, (6.75, y), (8.2, 2.7))
    ax.text(5.2, 1.68, "...", ha="center", va="center", fontsize=16)
    box(ax, 9.5, 2.7, 2.6, 1.6, "larap-merge", ["verify every chunk", "(size, sha256, settings)", "-> <obj>.pc2, bake.json",
                                                "or name missing frames"], "#dff0d8")
    ax.text(5.5, 5.3, "Each task: blender -b FILE --addons larap_blender --python-exit-code 1 --python-expr ... -- ARGS",
            ha="center", va="top", fontsize=9, style="italic")
    fig.savefig(out, bbox_inches="tight")
    print("wrote", out)


if __name__ == "__main__":
    main()
