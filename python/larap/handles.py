"""Handle files: named groups of vertices with targets, as JSON (format in README.md).

    {"handles": [
        {"name": "base", "box": {"min": [-1, -1, -1], "max": [0.4, 1, 1]}},
        {"name": "tip",  "vertices": [10, 11, 12],
         "transform": {"rotate": {"axis": [0, 0, 1], "angle": 90}, "pivot": [2, 0, 0],
                       "translate": [0, 0, 0.5], "scale": 1.0}},
        {"name": "ear",  "vertices": [40, 41], "targets": [[0, 1, 2], [0, 1.1, 2]]}
    ]}

A group selects vertices by "vertices" (ids), "box" (min/max corners) or "sphere" (center,
radius) and says where they go by "targets" (one position per vertex, with "vertices" only) or
"transform" (scale, then rotation, both about "pivot" — default the group's centroid — then
translation). A group with neither stays where it is. "weight" (default 1) is the group's pull
strength: every group pulls the same whatever its size unless weights say otherwise.
"""
from __future__ import annotations

import json
import math
from dataclasses import dataclass

import numpy as np


class HandleError(ValueError):
    """A handle file that cannot be used; the message says where and why."""


@dataclass
class HandleGroup:
    name: str
    vertices: np.ndarray            # (k,) int64
    targets: np.ndarray             # (k, 3) float64
    transform: np.ndarray | None    # (4, 4) affine map of the rest positions, or None (targets given)
    weight: float = 1.0


def rotation_matrix(spec) -> np.ndarray:
    """3x3 rotation from {"axis": [x, y, z], "angle": degrees} or {"quaternion": [w, x, y, z]}."""
    if not isinstance(spec, dict):
        raise HandleError(f"rotate must be an object, got {spec!r}")
    if "quaternion" in spec:
        q = np.asarray(spec["quaternion"], float)
        if q.shape != (4,) or not np.isfinite(q).all() or np.linalg.norm(q) == 0:
            raise HandleError(f"quaternion must be 4 finite numbers [w, x, y, z], not all zero: {spec['quaternion']!r}")
        w, x, y, z = q / np.linalg.norm(q)
        return np.array([
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ])
    if "axis" in spec:
        axis = np.asarray(spec["axis"], float)
        angle = spec.get("angle", 0.0)
        if axis.shape != (3,) or not np.isfinite(axis).all() or np.linalg.norm(axis) == 0:
            raise HandleError(f"axis must be 3 finite numbers, not all zero: {spec['axis']!r}")
        if not isinstance(angle, (int, float)) or not math.isfinite(angle):
            raise HandleError(f"angle must be a number of degrees, got {angle!r}")
        k = axis / np.linalg.norm(axis)
        t = math.radians(angle)
        K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
        return np.eye(3) + math.sin(t) * K + (1 - math.cos(t)) * K @ K
    raise HandleError(f"rotate needs 'axis' and 'angle' (degrees) or 'quaternion', got keys {sorted(spec)}")


def _vec3(value, what):
    a = np.asarray(value, dtype=float) if isinstance(value, (list, tuple)) else None
    if a is None or a.shape != (3,) or not np.isfinite(a).all():
        raise HandleError(f"{what} must be 3 finite numbers, got {value!r}")
    return a


def _select(group, where, V):
    n = len(V)
    keys = [k for k in ("vertices", "box", "sphere") if k in group]
    if len(keys) != 1:
        raise HandleError(f"{where}: give exactly one of 'vertices', 'box', 'sphere' (got {keys or 'none'})")
    if "vertices" in group:
        ids = group["vertices"]
        if not isinstance(ids, list) or not all(isinstance(i, int) and not isinstance(i, bool) for i in ids):
            raise HandleError(f"{where}: vertices must be a list of integers")
        ids = np.asarray(ids, dtype=np.int64)
        bad = ids[(ids < 0) | (ids >= n)]
        if bad.size:
            raise HandleError(f"{where}: vertex {int(bad[0])} is out of range for {n} vertices")
    elif "box" in group:
        box = group["box"]
        if not isinstance(box, dict):
            raise HandleError(f"{where}: box must be an object with 'min' and 'max'")
        lo, hi = _vec3(box.get("min"), f"{where}: box min"), _vec3(box.get("max"), f"{where}: box max")
        ids = np.flatnonzero(np.all((V >= lo) & (V <= hi), axis=1))
    else:
        sph = group["sphere"]
        if not isinstance(sph, dict):
            raise HandleError(f"{where}: sphere must be an object with 'center' and 'radius'")
        c = _vec3(sph.get("center"), f"{where}: sphere center")
        r = sph.get("radius")
        if not isinstance(r, (int, float)) or not r > 0:
            raise HandleError(f"{where}: sphere radius must be a positive number, got {r!r}")
        ids = np.flatnonzero(np.linalg.norm(V - c, axis=1) <= r)
    if ids.size == 0:
        raise HandleError(f"{where}: selects no vertex")
    if np.unique(ids).size != ids.size:
        raise HandleError(f"{where}: a vertex is listed twice")
    return ids


def parse_handles(data, V: np.ndarray) -> list[HandleGroup]:
    """Handle groups from parsed JSON `data` for a mesh with vertices V (n, 3)."""
    if not isinstance(data, dict) or not isinstance(data.get("handles"), list):
        raise HandleError("the handle file must be an object with a list 'handles'")
    groups, owner = [], {}
    for k, group in enumerate(data["handles"]):
        try:
            _parse_group(k, group, V, groups, owner)
        except OverflowError as exc:  # a JSON integer beyond a float or int64
            raise HandleError(f"handles[{k}]: a number is too large ({exc})") from None
    return groups


def _parse_group(k, group, V, groups, owner):
    """handles[k] of the file, appended to ``groups``; ``owner``: vertex -> its group's name."""
    if not isinstance(group, dict):
        raise HandleError(f"handles[{k}] must be an object")
    name = str(group.get("name", f"group{k}"))
    where = f"handle group '{name}'"
    ids = _select(group, where, V)
    if "targets" in group and "transform" in group:
        raise HandleError(f"{where}: give 'targets' or 'transform', not both")
    weight = group.get("weight", 1.0)
    if isinstance(weight, bool) or not isinstance(weight, (int, float)) or not math.isfinite(weight) \
            or weight < 0:
        raise HandleError(f"{where}: weight must be a non-negative number, got {weight!r}")
    M = None
    if "targets" in group:
        if "vertices" not in group:
            raise HandleError(f"{where}: 'targets' needs an explicit 'vertices' list")
        T = np.asarray(group["targets"], dtype=float) if isinstance(group["targets"], list) else None
        if T is None or T.shape != (ids.size, 3) or not np.isfinite(T).all():
            raise HandleError(f"{where}: targets must be {ids.size} finite [x, y, z] positions")
    else:
        tf = group.get("transform", {})
        if not isinstance(tf, dict):
            raise HandleError(f"{where}: transform must be an object")
        unknown = set(tf) - {"translate", "rotate", "scale", "pivot"}
        if unknown:
            raise HandleError(f"{where}: unknown transform keys {sorted(unknown)}")
        P = V[ids]
        pivot = P.mean(axis=0) if tf.get("pivot", "centroid") == "centroid" else _vec3(tf["pivot"], f"{where}: pivot")
        R = rotation_matrix(tf["rotate"]) if "rotate" in tf else np.eye(3)
        s = tf.get("scale", 1.0)
        if not isinstance(s, (int, float)) or not math.isfinite(s) or s <= 0:
            raise HandleError(f"{where}: scale must be a positive number, got {s!r}")
        t = _vec3(tf["translate"], f"{where}: translate") if "translate" in tf else np.zeros(3)
        M = np.eye(4)
        M[:3, :3] = s * R
        M[:3, 3] = pivot + t - s * R @ pivot
        T = P @ M[:3, :3].T + M[:3, 3]
    for i in ids.tolist():
        if i in owner:
            raise HandleError(f"vertex {i} is in both '{owner[i]}' and '{name}'")
        owner[i] = name
    groups.append(HandleGroup(name, ids, T, M, float(weight)))


def load_handles(path, V: np.ndarray) -> list[HandleGroup]:
    try:
        with open(path, encoding="utf-8") as f:
            data = json.load(f)
    except FileNotFoundError:
        raise
    except json.JSONDecodeError as exc:
        raise HandleError(f"{path}: not valid JSON ({exc})") from None
    except UnicodeDecodeError as exc:
        raise HandleError(f"{path}: not UTF-8 text (byte {exc.start}: {exc.reason})") from None
    return parse_handles(data, V)


def flatten(groups: list[HandleGroup]):
    """(indices (m,), targets (m, 3)) of all groups, in order."""
    if not groups:
        return np.zeros(0, np.int64), np.zeros((0, 3))
    return np.concatenate([g.vertices for g in groups]), np.concatenate([g.targets for g in groups])
