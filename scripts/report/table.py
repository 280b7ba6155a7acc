"""CSV and Markdown helpers of the report."""
from __future__ import annotations

import csv
import datetime
import os
import platform

import machine_info


def write_csv(path, rows):
    keys = []
    for r in rows:
        keys += [k for k in r if k not in keys]
    with open(path, "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=keys)
        w.writeheader()
        for r in rows:
            w.writerow({k: (f"{v:.6g}" if isinstance(v, float) else v) for k, v in r.items()})


def read_csv(path):
    if not os.path.exists(path):
        return []
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


def num(x, default=float("nan")):
    try:
        return float(x)
    except (TypeError, ValueError):
        return default


def machine() -> dict:
    return dict(cpu=machine_info.cpu_model(), cores=os.cpu_count(), load=round(os.getloadavg()[0], 2),
                date=datetime.datetime.now().strftime("%Y-%m-%d %H:%M"), python=platform.python_version())


def md_table(head, rows):
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    lines += ["| " + " | ".join(str(c) for c in r) + " |" for r in rows]
    return "\n".join(lines)
