# SPDX-License-Identifier: GPL-3.0-or-later
"""Bind as a user triggers it, through the add-on's operators, on a 1M-vertex tube: this tree's
add-on against another checkout's, each tree in a Blender process of its own.

Run (headless):
  blender -b --factory-startup --python-exit-code 1 --python scripts/bench_addon_bind.py -- \
      [--other CHECKOUT [--engine PATH]] [--rounds 3] [--vertices 1000000] [--out FILE | --no-write]

The mesh: a closed quad tube (scripts/blender_mesh.py, 256 vertices a ring, 4 x 0.5 units) of about
--vertices vertices, with vertex groups as an artist makes them: Left and Right (its end rings,
x < -1.6 and x > 1.6: 10% of the vertices each) and Mid (|x| < 0.1: 5%). Timed, as bpy.ops calls:
  * two handles: larap.handle_add of Left and of Right, on the unbound mesh;
  * Bind: larap.bind (lattice, binding, shape keys, first pose);
  * first solve: Right's target moved 0.05 up, then larap.solve (final weights, full validation);
  * third handle: larap.handle_add of Mid, on the bound mesh;
  * rebind: larap.bind again, keeping the pose.
For each step also the add-on's reads of Blender data: the foreach_get calls made through
larap_blender.mesh_data._get (every read of positions, topology, groups and keys in these steps;
the GPU preview's own reads, which need a window, do not go through it; checkouts without _get
report no reads) and their total time.

Each round runs one Blender process per tree (Blender keeps the add-on's modules once imported),
launched by this script with the same Blender and this tree's copy of this script; the trees
alternate, the one that goes first swapping every round. This tree loads its addon/ and python/
(which must be built); --other CHECKOUT loads that checkout's addon/ and the engine --engine names
(a folder holding larap/; default: CHECKOUT/python when it has a _core built for Blender's
Python, else this tree's python/, the comparison then being of the add-on alone). Each child says
which add-on and engine it loaded, and fails unless they are the ones asked for.
Prints a table (median and range over --rounds of each step, this tree over the other) and appends
it (markdown + a JSON line) to docs/results-blender.md unless --no-write.
"""
import argparse
import datetime
import glob
import importlib.machinery
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time

import bpy

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
sys.path.insert(0, HERE)
import machine_info  # noqa: E402

CHILD_TIMEOUT_S = 600
SEGMENTS = 256
# (key, label) of the steps, in the order a child runs them.
STEPS = [("handles", "two handles (handle_add x 2)"),
         ("bind", "Bind"),
         ("solve", "first solve, full validation"),
         ("handle_bound", "third handle, bound mesh"),
         ("rebind", "rebind, keeping the pose")]
# Vertex groups: name, and which vertices (by their rest x) it holds.
GROUPS = [("Left", lambda x: x < -1.6), ("Right", lambda x: x > 1.6), ("Mid", lambda x: abs(x) < 0.1)]


def parse_args():
    argv = sys.argv[sys.argv.index("--") + 1:] if "--" in sys.argv else []
    p = argparse.ArgumentParser(prog="bench_addon_bind.py")
    p.add_argument("--other", default="", help="checkout to compare with (its addon/; see --engine)")
    p.add_argument("--engine", default="",
                   help="folder holding the larap/ engine for --other's children (default: OTHER/python when "
                        "built for Blender's Python, else this tree's python/)")
    p.add_argument("--rounds", type=int, default=3, help="Blender processes per tree")
    p.add_argument("--vertices", type=int, default=1000000)
    p.add_argument("--iterations", type=int, default=5)
    p.add_argument("--device", default="cpu")
    p.add_argument("--verbose", action="store_true", help="print each child's output (every read with its caller)")
    p.add_argument("--out", default=os.path.join(ROOT, "docs", "results-blender.md"))
    p.add_argument("--no-write", action="store_true")
    # A child (launched by the run above): the checkout whose addon/ it loads, and where it writes.
    p.add_argument("--child", default="", help=argparse.SUPPRESS)
    p.add_argument("--json", default="", help=argparse.SUPPRESS)
    return p.parse_args(argv)


# ----------------------------------------------------------------------------------------------
# The child: one tree, one Blender process

def child(args):
    import numpy as np
    import blender_mesh

    root, engine_path = os.path.abspath(args.child), os.path.abspath(args.engine)
    for path in (engine_path, os.path.join(root, "addon")):
        sys.path.insert(0, path)
    import larap  # before the add-on, which then takes this one (engine.py: an imported larap first)
    if not os.path.realpath(larap.__file__).startswith(os.path.realpath(engine_path) + os.sep):
        raise SystemExit("the engine came from %s, not %s" % (larap.__file__, engine_path))
    import addon_utils
    bpy.ops.wm.read_factory_settings(use_empty=True)
    mod = addon_utils.enable("larap_blender", default_set=True)
    if mod is None or not hasattr(bpy.types.Object, "larap"):
        raise SystemExit("could not enable the larap_blender add-on from %s" % root)
    if not os.path.realpath(mod.__file__).startswith(os.path.realpath(root) + os.sep):
        raise SystemExit("the add-on came from %s, not %s" % (mod.__file__, root))
    from larap_blender import engine, mesh_data
    if engine.get() is None:
        raise SystemExit(engine.error())
    if os.path.realpath(engine.location()) != os.path.realpath(os.path.dirname(larap.__file__)):
        raise SystemExit("the add-on took the engine in %s, not %s" % (engine.location(), larap.__file__))
    print("add-on from %s, engine from %s" % (os.path.dirname(mod.__file__), engine.location()), flush=True)

    reads = []  # (attribute, items, seconds, caller) of each foreach_get made through mesh_data._get
    counted = hasattr(mesh_data, "_get")
    if counted:
        original = mesh_data._get

        def counting_get(collection, attr, count, dtype, width=1):
            t0 = time.perf_counter()
            out = original(collection, attr, count, dtype, width)
            dt = time.perf_counter() - t0
            f, chain = sys._getframe(1), []
            while f is not None and len(chain) < 3:
                chain.append("%s:%s" % (os.path.basename(f.f_code.co_filename), f.f_code.co_name))
                f = f.f_back
            reads.append((attr, int(count), dt, " < ".join(chain)))
            return out

        mesh_data._get = counting_get  # the module's functions look _get up at each call

    obj, rest = blender_mesh.quad_tube("Tube", args.vertices, SEGMENTS)
    for o in bpy.context.selected_objects:
        o.select_set(False)
    bpy.context.view_layer.objects.active = obj
    obj.select_set(True)
    n = len(obj.data.vertices)
    sizes = {}
    for name, test in GROUPS:
        idx = np.flatnonzero(test(rest[:, 0]))
        obj.vertex_groups.new(name=name).add(idx.tolist(), 1.0, "REPLACE")
        sizes[name] = int(len(idx))
    s = obj.larap
    s.iterations = args.iterations
    s.device = args.device
    me = obj.data
    out = dict(root=root, addon=os.path.dirname(mod.__file__), engine=engine.location(), reads_counted=counted,
               vertices=n, loops=len(me.loops), polygons=len(me.polygons), edges=len(me.edges), groups=sizes,
               steps={})

    def step(key, fn):
        del reads[:]
        t0 = time.perf_counter()
        res = fn()
        wall = time.perf_counter() - t0
        if res != {"FINISHED"}:
            raise SystemExit("%s: the operator returned %s" % (key, res))
        out["steps"][key] = dict(s=wall, reads=len(reads) if counted else None,
                                 reads_s=sum(r[2] for r in reads) if counted else None,
                                 detail=[list(r) for r in reads])
        print("%-13s %.3f s; reads through mesh_data._get: %s" % (
            key, wall, "%d, %.3f s" % (len(reads), out["steps"][key]["reads_s"]) if counted else "not counted"))
        for attr, count, dt, chain in reads:
            print("   %-13s %8d  %6.1f ms  %s" % (attr, count, dt * 1e3, chain))

    def two_handles():
        first = bpy.ops.larap.handle_add(vertex_group="Left")
        return first if first != {"FINISHED"} else bpy.ops.larap.handle_add(vertex_group="Right")

    step("handles", two_handles)
    step("bind", lambda: bpy.ops.larap.bind())
    s.handles[1].target.location.z += 0.05
    bpy.context.view_layer.update()
    step("solve", lambda: bpy.ops.larap.solve())
    step("handle_bound", lambda: bpy.ops.larap.handle_add(vertex_group="Mid"))
    step("rebind", lambda: bpy.ops.larap.bind())

    import hashlib
    from larap_blender import runtime
    d = runtime.runtime(obj).deformer
    co = np.empty(n * 3, np.float32)
    obj.data.shape_keys.key_blocks[s.shape_key].data.foreach_get("co", co)
    out.update(cells=int(d.num_cells), nodes=int(d.num_nodes),
               pose_hash=hashlib.blake2b(co.tobytes(), digest_size=8).hexdigest(), topology=str(s.bind_topology))
    with open(args.json, "w") as f:
        json.dump(out, f)


# ----------------------------------------------------------------------------------------------
# The run: children, table, results file

def built(python_dir):
    """Whether ``python_dir``/larap has a _core this Blender's Python can import."""
    return any(glob.glob(os.path.join(python_dir, "larap", "_core" + suffix))
               for suffix in importlib.machinery.EXTENSION_SUFFIXES)


def revision(checkout):
    """The checkout's commit, and whether its addon/ or python/ has uncommitted changes."""
    try:
        head = subprocess.run(["git", "-C", checkout, "rev-parse", "--short", "HEAD"], capture_output=True,
                              text=True, check=True).stdout.strip()
        dirty = subprocess.run(["git", "-C", checkout, "status", "--porcelain", "--", "addon", "python"],
                               capture_output=True, text=True, check=True).stdout.strip()
        return head + (" + uncommitted changes in addon/ or python/" if dirty else "")
    except (OSError, subprocess.CalledProcessError):
        return "not a git checkout"


def run_child(tree, args, work, k):
    path = os.path.join(work, "%s_%d.json" % (tree["name"], k))
    cmd = [bpy.app.binary_path, "-b", "--factory-startup", "--python-exit-code", "1",
           "--python", os.path.abspath(__file__), "--",
           "--child", tree["root"], "--engine", tree["engine"], "--json", path,
           "--vertices", str(args.vertices), "--iterations", str(args.iterations), "--device", args.device]
    t0 = time.perf_counter()
    try:
        r = subprocess.run(cmd, capture_output=True, text=True, timeout=CHILD_TIMEOUT_S)
    except subprocess.TimeoutExpired:
        raise SystemExit("%s: over %d s (killed)" % (tree["name"], CHILD_TIMEOUT_S))
    if args.verbose:
        print(r.stdout, flush=True)
    if r.returncode or not os.path.exists(path):
        raise SystemExit("%s (%s): Blender exited %d:\n%s" % (tree["name"], tree["root"], r.returncode,
                                                             (r.stdout + r.stderr)[-3000:]))
    with open(path) as f:
        res = json.load(f)
    print("  %s, round %d (%.0f s): %s" % (tree["name"], k + 1, time.perf_counter() - t0,
                                           ", ".join("%s %.3f s" % (key, res["steps"][key]["s"]) for key, _ in STEPS)),
          flush=True)
    return res


def med_range(xs):
    return "%.3f (%.3f-%.3f)" % (statistics.median(xs), min(xs), max(xs))


def reads_cell(runs, key):
    counts = [r["steps"][key]["reads"] for r in runs]
    if None in counts:
        return "not counted"
    lo, hi = min(counts), max(counts)
    return "%s, %.3f s" % (lo if lo == hi else "%d-%d" % (lo, hi),
                           statistics.median(r["steps"][key]["reads_s"] for r in runs))


def table(trees):
    one = len(trees) == 1
    if one:
        lines = ["| step | s, median (range) | reads: calls, s |", "|---|---|---|"]
    else:
        lines = ["| step | this tree: s, median (range) | other: s, median (range) | this / other "
                 "| reads, this tree: calls, s | reads, other: calls, s |", "|---|---|---|---|---|---|"]
    for key, label in STEPS:
        mine = [r["steps"][key]["s"] for r in trees[0]["runs"]]
        if one:
            lines.append("| %s | %s | %s |" % (label, med_range(mine), reads_cell(trees[0]["runs"], key)))
            continue
        other = [r["steps"][key]["s"] for r in trees[1]["runs"]]
        lines.append("| %s | %s | %s | %.2f | %s | %s |" % (
            label, med_range(mine), med_range(other), statistics.median(mine) / statistics.median(other),
            reads_cell(trees[0]["runs"], key), reads_cell(trees[1]["runs"], key)))
    return "\n".join(lines)


def main():
    args = parse_args()
    if args.child:
        return child(args)
    if args.engine and not args.other:
        raise SystemExit("--engine names the engine of --other's children: give --other too")
    machine = machine_info.describe()  # the load before the run, not the run's own
    if not built(os.path.join(ROOT, "python")):
        raise SystemExit("this tree's python/larap has no _core built for Blender's Python (scripts/setup)")
    trees = [dict(name="this tree", root=ROOT, engine=os.path.join(ROOT, "python"))]
    if args.other:
        other = os.path.abspath(args.other)
        if not os.path.isdir(os.path.join(other, "addon", "larap_blender")):
            raise SystemExit("%s has no addon/larap_blender" % other)
        if args.engine:
            engine, why = os.path.abspath(args.engine), "--engine"
        elif built(os.path.join(other, "python")):
            engine, why = os.path.join(other, "python"), "its own"
        else:
            engine, why = os.path.join(ROOT, "python"), "this tree's: its python/ has no built engine"
        trees.append(dict(name="other", root=other, engine=engine, engine_why=why))
    for tree in trees:
        tree.update(revision=revision(tree["root"]), runs=[])
    print("Blender %s; %d rounds of %s" % (bpy.app.version_string, args.rounds,
                                             " and ".join("%s (%s, %s)" % (t["name"], t["root"], t["revision"])
                                                          for t in trees)), flush=True)
    t_start = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="bench_addon_bind_") as work:
        for k in range(args.rounds):
            for tree in (trees if k % 2 else trees[::-1]):  # the other tree first in rounds 1, 3, ...
                tree["runs"].append(run_child(tree, args, work, k))
    wall = time.perf_counter() - t_start
    first = trees[0]["runs"][0]
    for tree in trees:
        r = tree["runs"][0]
        for key in ("vertices", "loops", "groups", "cells", "nodes"):
            if any(run[key] != first[key] for run in tree["runs"]):
                print("note: %s differs between runs: %s" % (key, [run[key] for run in tree["runs"]]))
        tree["engine_used"] = r["engine"]
        tree["addon_used"] = r["addon"]
    n = first["vertices"]
    groups = ", ".join("%s %s (%.1f%%)" % (name, format(size, ","), 100.0 * size / n)
                       for name, size in first["groups"].items())
    mesh = ("a closed quad tube of %s vertices (%s loops, %s polygons, %s edges), lattice of %d cells (%d nodes)"
            % tuple([format(first[k], ",") for k in ("vertices", "loops", "polygons", "edges")]
                    + [first["cells"], first["nodes"]]))
    who = []
    for tree in trees:
        why = " (%s)" % tree["engine_why"] if "engine_why" in tree else ""
        who.append("%s: add-on `%s` (%s), engine `%s`%s" % (
            tree["name"].capitalize(), tree["addon_used"], tree["revision"], tree["engine_used"], why))
        print("%s used the engine in %s%s" % (tree["name"], tree["engine_used"], why))
    hashes = {t["name"]: sorted({(r["pose_hash"], r["topology"]) for r in t["runs"]}) for t in trees}
    all_hashes = {h for hs in hashes.values() for h in hs}
    if len(all_hashes) == 1:
        (pose, topo), = all_hashes
        same = ("The pose key after the rebind and the bound topology hash: the same in every run%s (%s, %s)."
                % (" of both trees" if len(trees) > 1 else "", pose, topo))
    else:
        same = "The pose key after the rebind / the topology hash differ: %s." % json.dumps(hashes)
    stamp = datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%d %H:%M UTC")
    text = "\n".join([
        "", "## %s: Bind through the add-on's operators, a tube of %s vertices (`scripts/bench_addon_bind.py`)"
        % (stamp, format(n, ",")), "",
        "%s; Blender %s, headless; device %s, %d iterations, default lattice; %s; vertex groups %s of its "
        "vertices; median (range) over %d rounds, each tree in a Blender process of its own per round%s."
        % (machine, bpy.app.version_string, args.device, args.iterations, mesh, groups, args.rounds,
           ", the two alternating" if len(trees) > 1 else ""),
        "%s. Reads: foreach_get calls through `larap_blender.mesh_data._get` and their total time." % ". ".join(who),
        "", table(trees), "", same, ""])
    print(text)
    print("(%d Blender processes, %.0f s)" % (len(trees) * args.rounds, wall))
    if not args.no_write:
        info = dict(date=stamp, machine=machine, blender=bpy.app.version_string, device=args.device,
                    iterations=args.iterations, rounds=args.rounds,
                    trees=[dict(name=t["name"], root=t["root"], revision=t["revision"], addon=t["addon_used"],
                                engine=t["engine_used"],
                                runs=[dict(steps={k: {f: v for f, v in st.items() if f != "detail"}
                                                  for k, st in r["steps"].items()},
                                           **{f: r[f] for f in ("vertices", "loops", "polygons", "edges", "groups",
                                                                "cells", "nodes", "pose_hash", "topology")})
                                      for r in t["runs"]]) for t in trees])
        with open(args.out, "a") as f:
            f.write(text + "\n<!-- json: %s -->\n" % json.dumps(info))
        print("appended to", args.out)


if __name__ == "__main__":  # Blender runs a --python script as __main__; importing it runs nothing
    main()
