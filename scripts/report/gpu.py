"""The GPU entry of the report: the same Table 1 and time-to-quality runs on device="cuda",
written as table1_cuda.csv, convergence_cuda.csv and time_to_quality_cuda.csv into the report
folder, which the summary merges beside the CPU's. scripts/evidence runs it when "cuda" is in
larap.available_devices(); on a GPU machine without Blender or CGAL it runs alone:

    PYTHONPATH=python:scripts python3 -m report.gpu --out report/ [--quick]
"""
from __future__ import annotations

import argparse
import os

import larap

from . import convergence, table1


def run(out, size, log=print):
    if "cuda" not in larap.available_devices():
        raise RuntimeError(f"no usable CUDA device (larap.available_devices() == {larap.available_devices()})")
    rows = table1.run(out, size, device="cuda", log=log)
    ttq = convergence.run(out, size, device="cuda", log=log)
    return rows, ttq


def main():
    ap = argparse.ArgumentParser(prog="python3 -m report.gpu")
    ap.add_argument("--out", default="report")
    ap.add_argument("--quick", action="store_true")
    args = ap.parse_args()
    os.makedirs(args.out, exist_ok=True)
    run(args.out, "quick" if args.quick else "full")


if __name__ == "__main__":
    main()
