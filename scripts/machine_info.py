# SPDX-License-Identifier: GPL-3.0-or-later
"""What a benchmark records about the machine it ran on: the CPU's model name and a one-line
description (CPU, cores, OS, load now). Plain Python, so the benchmarks that run inside Blender
(bench_blender.py, bench_preview.py), the ones that do not (bench.py) and the evidence report
(report/table.py) all say it the same way."""
from __future__ import annotations

import os
import platform


def cpu_model() -> str:
    """The CPU's model name from /proc/cpuinfo; what ``platform`` knows where that is missing."""
    cpu = platform.processor() or platform.machine()
    try:
        with open("/proc/cpuinfo") as f:
            return next((ln.split(":", 1)[1].strip() for ln in f if ln.startswith("model name")), cpu)
    except OSError:
        return cpu


def describe() -> str:
    """``<cpu>, <n> cores, <platform>, load <1-minute load average>`` (the load only where the OS has one)."""
    load = ", load %.1f" % os.getloadavg()[0] if hasattr(os, "getloadavg") else ""
    return "%s, %d cores, %s%s" % (cpu_model(), os.cpu_count() or 0, platform.platform(), load)
