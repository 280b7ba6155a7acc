# SPDX-License-Identifier: GPL-3.0-or-later
# Run: blender -b --factory-startup --python-exit-code 1 --python tests/blender/run_tests.py -- tests/blender/test_runtime.py
# The runtime keeps what the engine was told (handles, weights, gamma) on the Python side: a solve
# calls the engine only for what changed and never reads the engine's state back.
import bpy
import numpy as np
import pytest

from conftest import bar_with_handles, coords, diagonal


@pytest.fixture
def engine_calls(monkeypatch):
    """Counts of handle-group calls ("set_handles") and of the weights/gamma setters, and the
    handle vertices the engine was last given ("vertices"); reading handles, weights or gamma
    back from the engine fails the test."""
    import larap
    calls = {"set_handles": 0, "weights": 0, "gamma": 0, "vertices": None}
    real_set = larap.Deformer.set_handle_groups

    def set_handles(self, groups, *args, **kwargs):
        calls["set_handles"] += 1
        calls["vertices"] = None
        result = real_set(self, groups, *args, **kwargs)
        calls["vertices"] = np.sort(np.concatenate([np.asarray(g) for g in groups]))
        return result

    def no_read(name):
        def fget(self):
            raise AssertionError("the add-on read %s back from the engine" % name)
        return fget

    def counting(name):
        real = getattr(larap.Deformer, name).fset

        def fset(self, value):
            calls[name] += 1
            real(self, value)
        return fset

    monkeypatch.setattr(larap.Deformer, "set_handle_groups", set_handles)
    monkeypatch.setattr(larap.Deformer, "handles", property(no_read("handles")))
    for name in ("weights", "gamma"):
        monkeypatch.setattr(larap.Deformer, name, property(no_read(name), counting(name)))
    return calls


def test_engine_is_called_only_for_what_changed(core, engine_calls):
    obj, rest, left, right, targets = bar_with_handles(core)
    assert engine_calls["set_handles"] == 1  # bind: the handles, once
    rt = core.runtime(obj)
    assert np.array_equal(engine_calls["vertices"], np.union1d(left, right))
    before = dict(engine_calls)
    targets[1].location.z += 0.5
    bpy.context.view_layer.update()
    core.solve(obj, weights="final")
    core.solve(obj, weights="final")
    assert engine_calls["set_handles"] == before["set_handles"]  # same handles, weights and gamma:
    assert engine_calls["weights"] == before["weights"] and engine_calls["gamma"] == before["gamma"]  # no call
    pose = coords(obj, "LARAP")
    assert np.abs(pose[right, 2] - rest[right, 2] - 0.5).max() < 0.02 * diagonal(rest)
    # Interactive weights, then final again: one switch each way.
    core.solve(obj, weights="interactive")
    core.solve(obj, weights="interactive")
    core.solve(obj, weights="final")
    assert engine_calls["weights"] == before["weights"] + 2 and rt.engine_weights == obj.larap.weights_final
    # Gamma: a new value reaches the engine once.
    obj.larap.gamma = 0.3
    core.solve(obj, weights="final")
    core.solve(obj, weights="final")
    assert engine_calls["gamma"] == before["gamma"] + 1 and rt.engine_gamma == pytest.approx(0.3)
    # A handle disabled: a new set, once; enabled again: the old set again.
    obj.larap.handles[0].enabled = False
    core.solve(obj, weights="final")
    assert engine_calls["set_handles"] == before["set_handles"] + 1
    assert np.array_equal(engine_calls["vertices"], right)
    obj.larap.handles[0].enabled = True
    core.solve(obj, weights="final")
    core.solve(obj, weights="final")
    assert engine_calls["set_handles"] == before["set_handles"] + 2
    assert np.array_equal(engine_calls["vertices"], np.union1d(left, right))
    assert core.runtime(obj) is rt


def test_failed_engine_call_is_repeated_at_the_next_solve(core, engine_calls, monkeypatch):
    import larap
    obj, rest, left, right, targets = bar_with_handles(core)
    rt = core.runtime(obj)
    obj.larap.handles[0].enabled = False  # the next solve needs new handles
    counting = larap.Deformer.set_handle_groups

    def boom(self, groups, *args, **kwargs):
        raise MemoryError("simulated engine failure")

    monkeypatch.setattr(larap.Deformer, "set_handle_groups", boom)
    with pytest.raises(RuntimeError, match="out of memory"):
        bpy.ops.larap.solve()
    assert rt.engine_handles is None  # unknown: the engine may hold either set
    monkeypatch.setattr(larap.Deformer, "set_handle_groups", counting)
    obj.larap.handles[0].enabled = True  # back to what the engine had before the failed call
    before = engine_calls["set_handles"]
    targets[1].location.z += 0.5
    assert bpy.ops.larap.solve() == {"FINISHED"}
    assert engine_calls["set_handles"] == before + 1
    pose = coords(obj, "LARAP")
    assert np.abs(pose[right, 2] - rest[right, 2] - 0.5).max() < 0.02 * diagonal(rest)
    assert np.abs(pose[left] - rest[left]).max() < 0.02 * diagonal(rest)
