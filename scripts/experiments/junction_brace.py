"""Issue 9, session 21: a rotation-free brace where the solid branches, in the reference solver
(arap_variants.py, one rotation per cell copy). A copy *branches* when it is joined across one face
to two or more copies of the next cell (the copy holding a palm's end and every finger's root);
for each of its corner columns along that axis (palm-side node a, near node b, far node c) the
brace adds mu * gamma_eff * |x_a - 2 x_b + x_c|^2 to the system: a fixed quadratic, zero under
every affine map, so it needs no rotation and cannot lag when the palm turns (stiffening the
branching copy's own edges did lag: docs/method.md, "Stiff branchings and a brace").

Run from the repository root:
  PYTHONPATH=python /usr/bin/python3 scripts/experiments/junction_brace.py wrist 0,100   # palm + tips turned 90 deg
  PYTHONPATH=python /usr/bin/python3 scripts/experiments/junction_brace.py comb 0,100    # tests' comb sweep
  PYTHONPATH=python /usr/bin/python3 scripts/experiments/junction_brace.py char 0,100 [TURNED_DEGREES]
Figures (trilinear, 30 flip-flops) in scripts/experiments/README.md."""
import sys, numpy as np, scipy.sparse as sp
sys.path.insert(0, "tests/python"); sys.path.insert(0, "python"); sys.path.insert(0, "scripts/experiments")
import larap
from larap import shapes
from larap.quality import diagonal
import arap_variants as av
import test_topology as tt, test_junctions as tj
from conftest import affine, rotation

def brace_rows(lat):
    keys = [tuple(c) for c in lat.cell_coords]
    where = {}
    for c, k in enumerate(keys): where.setdefault(k, []).append(c)
    rows = set()
    for c, k in enumerate(keys):
        for ax in range(3):
            for s in (0, 1):
                nk = list(k); nk[ax] += 1 if s else -1
                cs = where.get(tuple(nk), [])
                if len(cs) < 2: continue
                far = [q for q in range(8) if ((q >> ax) & 1) == s]
                fm = set(lat.cells[c][far])
                if sum(1 for o in cs if set(lat.cells[o][[q ^ (1 << ax) for q in far]]) == fm) < 2: continue
                # palm side: the copy across the opposite face sharing c's near face
                pk = list(k); pk[ax] += -1 if s else 1
                near = [q ^ (1 << ax) for q in far]
                for d in where.get(tuple(pk), []):
                    if set(lat.cells[d][[q ^ (1 << ax) for q in near]]) != set(lat.cells[c][near]): continue
                    for q in near:
                        b = lat.cells[c][q]; cc = lat.cells[c][q ^ (1 << ax)]; a = lat.cells[d][q]
                        rows.add((a, b, cc))
    return sorted(rows)

class Braced(av.Solver):
    def __init__(self, lat, rows_h, alpha, mu, fixed=(), **kw):
        R = brace_rows(lat); self.nbrace = len(R)
        if R:
            I = np.repeat(np.arange(len(R)), 3); J = np.array(R).ravel(); W = np.tile([1.0, -2.0, 1.0], len(R))
            fixed = [(mu, sp.csr_matrix((W, (I, J)), shape=(len(R), lat.nr)))] + list(fixed)
        super().__init__(lat, rows_h, alpha, fixed=fixed, **kw)

def solver(d, V, groups, mu):
    lat = av.Lat(d, V); rows, alpha = av.group_alpha(groups)
    cw = d.cell_weights()
    s = Braced(lat, rows, alpha, mu, gamma=0.03, rotations="cell", cw=np.repeat(cw[:, None], 12, 1) if len(cw) else None, floor=1e-9)
    return lat, s

if __name__ == "__main__":
    mus = [float(x) for x in sys.argv[2].split(",")]
    if sys.argv[1] == "wrist":
        V, F, parts = shapes.character(); groups, _ = tj.finger_pose(V, parts); size = tj.hand_size(V, parts)
        wx = V[parts["hand"], 0].min(); fingers = np.concatenate(parts["fingers"])
        R = affine(rotation([0, 1, 0], -90.0), pivot=(wx + 0.02, 0.0, 1.42))
        T = np.stack([np.eye(4)] + [R] * (len(groups) - 1)); ref = V[fingers] @ R[:3, :3].T + R[:3, 3]
        d = larap.Deformer(V, F, weights="trilinear"); d.set_handle_groups(groups)
        for mu in mus:
            lat, s = solver(d, V, groups, mu)
            X = av.transfer(lat, s.solve(av.group_targets(V, groups, T), 30))
            print(f"mu {mu:g} braces {s.nbrace}: wrist 90 fingers off {100*np.linalg.norm(X[fingers]-ref,axis=1).max()/size:.2f}%", flush=True)
    elif sys.argv[1] == "comb":
        for h in tt.SWEEP_SIZES:
            V, F, tine_ids, _ = tt.comb(gap=0.1 * h); groups, T = tt.comb_pose(V, tine_ids, moved=1)
            d = larap.Deformer(V, F, cell_size=h, weights="trilinear"); d.set_handle_groups(groups)
            line = []
            for mu in mus:
                lat, s = solver(d, V, groups, mu)
                X = av.transfer(lat, s.solve(av.group_targets(V, groups, T), 30))
                drag = max(np.linalg.norm(X[tine_ids[t]] - V[tine_ids[t]], axis=1).max() / diagonal(V) for t in (0, 2))
                miss = np.linalg.norm(X[groups[2]] - tt.apply(T[2], V[groups[2]]), axis=1).max() / 6.0
                line.append(f"mu{mu:g} {100*drag:.2f}/{100*miss:.1f}")
            print(f"h {h} B{s.nbrace}: " + "  ".join(line), flush=True)
    else:
        turned = float(sys.argv[3]) if len(sys.argv) > 3 else 0.0
        V, F, parts = shapes.character(); groups, T = tj.finger_pose(V, parts); size = tj.hand_size(V, parts)
        if turned: V, T = tj.turned_about_vertical(V, T, turned)
        for cells in tj.CHARACTER_CELLS:
            d = larap.Deformer(V, F, weights="trilinear", cells=cells); d.set_handle_groups(groups)
            line = []
            for mu in mus:
                lat, s = solver(d, V, groups, mu)
                X = av.transfer(lat, s.solve(av.group_targets(V, groups, T), 30))
                drag = max(np.linalg.norm(X[parts["fingers"][j]] - V[parts["fingers"][j]], axis=1).max() for j in (0, 2, 3)) / size
                tip = groups[3]; miss = np.linalg.norm(X[tip] - (V[tip] @ T[3][:3, :3].T + T[3][:3, 3]), axis=1).max() / 0.09
                line.append(f"mu{mu:g} {100*drag:.2f}/{100*miss:.1f}")
            print(f"cells {cells} B{s.nbrace}: " + "  ".join(line), flush=True)
