"""Issue 9, session 31: branch_copies.py's lattice (one copy per branch where separate parts meet,
`--anchor --couple`) solved by the engine itself. Research code, not used by the add-on.

The lattice surgery is still branch_copies.split_per_branch's (Python, on the engine's lattice);
its copies, nodes, weights, vertex copies and couplings go to a new larap.Deformer through the
private `_lattice_copies` hook (Lattice::replace_copies), and the engine's CPU backend solves it
with the couplings (Lattice::couplings: a branch copy's rotation also answers for its trunk copy's
edges). So what the reference solver showed can be measured where the reference solver cannot go:
the engine's coarse-to-fine levels, its B-spline transfer, a drag in steps.

  --check     the engine's pose against the reference solver's on the same lattice (trilinear,
              levels 1): they solve the same energy, so they must agree
  --sweep     the neighbours' drag (worse weight kind, 30 flip-flops) over the turned sweeps,
              split per branch and the engine's lattice, at `--levels`
  --follow    the palm turned 90 degrees with the fingers free: how far they stay off its turn,
              at once (`--iterations`) and dragged in 12 steps of 5 flip-flops

Run from the repository root:
  PYTHONPATH=python /usr/bin/python3 scripts/experiments/branch_engine.py --check
  PYTHONPATH=python /usr/bin/python3 scripts/experiments/branch_engine.py --sweep --levels 1 2
  PYTHONPATH=python /usr/bin/python3 scripts/experiments/branch_engine.py --follow --levels 1 2
"""
import argparse
import sys
import time

import numpy as np

sys.path.insert(0, "tests/python")
sys.path.insert(0, "scripts/experiments")
import arap_variants as av  # noqa: E402
import branch_copies as bc  # noqa: E402
import test_junctions as tj  # noqa: E402

import larap  # noqa: E402

LAMBDA = 10.0


def copies_of(lat, d, weights, lam=LAMBDA):
    """The `_lattice_copies` dict of a lattice changed by split_per_branch: copies sorted into grid
    order (the new ones after their cell's), kinds copied from the copy each was split from."""
    C = len(lat.cells)
    source = np.arange(C)
    for b, t in lat.branch_pairs:
        source[b] = t
    kinds = d._core.cell_kinds()
    kind = np.asarray(kinds)[source]
    cc = lat.cell_coords
    order = np.lexsort((np.arange(C), cc[:, 0], cc[:, 1], cc[:, 2]))  # grid order: x fastest
    new = np.empty(C, np.int64)
    new[order] = np.arange(C)
    pairs = np.array(lat.branch_pairs, np.int64).reshape(-1, 2)
    w = np.asarray(weights, float)
    return dict(cell_coords=lat.cell_coords[order].astype(np.int32), cell_nodes=lat.cells[order].astype(np.int32),
                cell_kind=kind[order].astype(np.uint8), cell_weight=w[order],
                vertex_cell=new[lat.vcell].astype(np.int32),
                couplings=new[pairs].astype(np.int32) if len(pairs) else np.zeros((0, 2), np.int32),
                coupling_weights=lam * w[pairs[:, 1]] if len(pairs) else np.zeros(0))


class EngineCase(bc.Case):
    """branch_copies.Case, solved by the engine on the split lattice (or the engine's own)."""

    def __init__(self, turn, cells, **kw):
        super().__init__(turn, cells, **kw)
        self.cells = cells
        self.hold = "anchor"
        self._copies = None

    def copies(self, samples=16, lam=LAMBDA):
        if self._copies is None:
            lat = av.Lat(self.d, self.V)
            w, split, side = bc.split_per_branch(lat, self.solids, 2.0, samples, self.region, "anchor", False)
            self._copies = (copies_of(lat, self.d, w, lam), lat, w)
        return self._copies

    def deformer(self, per_branch, weights="trilinear", levels=1, samples=16):
        kw = dict(weights=weights, cells=self.cells, levels=levels)
        if per_branch:
            kw["_lattice_copies"] = self.copies(samples)[0]
        d = larap.Deformer(self.V, self.F, **kw)
        d.set_handle_groups(self.groups)
        return d


def check(a):
    """Engine against the reference solver on the same split lattice."""
    for turn, cells in ((30.0, 4000), (45.0, 4000), (15.0, 7000)):
        c = EngineCase(turn, cells)
        copies, lat, w = c.copies(a.samples)
        d = c.deformer(True)
        X = d.solve(transforms=c.T, iterations=a.iterations)
        s = bc.solver(lat, c.groups, w, LAMBDA)
        Y = av.transfer(lat, s.solve(av.group_targets(c.V, c.groups, c.T), a.iterations))
        print(f"{turn:g} deg, {cells} cells: {len(copies['couplings'])} couplings, engine {d.num_nodes} nodes;"
              f" largest difference engine/reference {np.abs(X - Y).max() / c.size * 100:.2e}% of the hand;"
              f" drag engine {c.figures(X)[0]:.2f}%, reference {c.figures(Y)[0]:.2f}%", flush=True)


def sweep(a):
    for levels in a.levels:
        rows = {True: [], False: []}
        t0 = time.time()
        for turn in a.angles:
            for cells in tj.CHARACTER_CELLS:
                c = EngineCase(turn, cells, palm_part=a.palm_part)
                for per_branch in (True, False):
                    worst, miss = 0.0, 0.0
                    for weights in a.weights:
                        d = c.deformer(per_branch, weights, levels, a.samples)
                        X = d.solve(transforms=c.T, iterations=a.iterations)
                        f = c.figures(X)
                        worst, miss = max(worst, f[0]), max(miss, f[1])
                    rows[per_branch].append((turn, cells, worst, miss))
                print(f"levels {levels} {turn:g} deg {cells}: split {rows[True][-1][2]:.2f}% (miss {rows[True][-1][3]:.1f}%)"
                      f", engine's lattice {rows[False][-1][2]:.2f}%", flush=True)
        for per_branch in (True, False):
            x = np.array([r[2] for r in rows[per_branch]])
            print(f"levels {levels}, {'split per branch' if per_branch else 'engine lattice'}: within 1% "
                  f"{(x <= 1).sum()} of {len(x)}, median {np.median(x):.2f}%, worst {x.max():.2f}%"
                  f" ({time.time() - t0:.0f} s)")


def follow(a):
    for levels in a.levels:
        for turn in a.angles:
            for cells in a.cells:
                c = EngineCase(turn, cells, follow=True)
                out = []
                for per_branch in (True, False):
                    d = c.deformer(per_branch, "trilinear", levels, a.samples)
                    X = d.solve(transforms=c.T, iterations=a.iterations)
                    once = c.figures(X)[3]
                    d.reset()
                    lag = 0.0
                    for k in range(1, 13):  # 12 steps of the turn, 5 flip-flops each
                        Tk = np.stack([interp(T, k / 12) for T in c.T])
                        X = d.solve(transforms=Tk, iterations=5)
                        lag = max(lag, off_turn(c, X, Tk[1]))
                    out.append((once, lag))
                print(f"levels {levels} {turn:g} deg {cells}: fingers off the palm's turn: split {out[0][0]:.2f}% "
                      f"({a.iterations} flip-flops), dragged {out[0][1]:.2f}%; engine's lattice {out[1][0]:.2f}%, "
                      f"dragged {out[1][1]:.2f}%", flush=True)


def interp(T, t):
    """The affine map T reached a fraction t of the way: rotation by the same axis, t of the angle."""
    from scipy.spatial.transform import Rotation
    R = Rotation.from_matrix(T[:3, :3])
    Rt = Rotation.from_rotvec(R.as_rotvec() * t).as_matrix()
    # keep the map's fixed point: T x = R x + u; the pivot p solves (I - R) p = u (least squares)
    p = np.linalg.lstsq(np.eye(3) - T[:3, :3], T[:3, 3], rcond=None)[0]
    M = np.eye(4)
    M[:3, :3] = Rt
    M[:3, 3] = p - Rt @ p
    return M


def off_turn(c, X, Tw):
    f = np.concatenate(c.parts["fingers"])
    return 100 * np.linalg.norm(X[f] - (c.V[f] @ Tw[:3, :3].T + Tw[:3, 3]), axis=1).max() / c.size


def main():
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--check", action="store_true")
    p.add_argument("--sweep", action="store_true")
    p.add_argument("--follow", action="store_true")
    p.add_argument("--palm-part", action="store_true")
    p.add_argument("--levels", type=int, nargs="+", default=[1])
    p.add_argument("--angles", type=lambda s: [float(x) for x in s.split(",")], default=[15.0, 30.0, 45.0])
    p.add_argument("--cells", type=lambda s: [int(x) for x in s.split(",")], default=[4000, 8000])
    p.add_argument("--weights", nargs="+", default=["trilinear"])
    p.add_argument("--samples", type=int, default=16)
    p.add_argument("--iterations", type=int, default=30)
    a = p.parse_args()
    if a.check:
        check(a)
    if a.sweep:
        sweep(a)
    if a.follow:
        follow(a)


if __name__ == "__main__":
    main()
