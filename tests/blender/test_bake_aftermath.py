# SPDX-License-Identifier: GPL-3.0-or-later
# After Bake Animation: Live paused, the pose key hidden and said so, Remove Bake in one undoable
# step; the bake shows progress and Esc puts everything back.
# Run: blender -b --factory-startup --python-exit-code 1 --python tests/blender/run_tests.py -- tests/blender/test_bake_aftermath.py
import types
from unittest import mock

import bpy
import numpy as np
import pytest

from conftest import activate, bar_with_handles, coords
from test_safety import key_state, push, undo
from test_ui import draw


def animated_bar(core):
    obj, rest, left, right, targets = bar_with_handles(core)
    e = targets[1]
    z0 = e.location.z
    e.keyframe_insert("location", frame=1)
    e.location.z = z0 + 1.0
    e.keyframe_insert("location", frame=5)
    bpy.context.scene.frame_set(1)
    return obj, targets


class CountingWM:
    """Stands in for the window manager: counts Blender's progress calls."""

    def __init__(self):
        self.calls = []

    def progress_begin(self, lo, hi):
        self.calls.append(("begin", lo, hi))

    def progress_update(self, value):
        self.calls.append(("update", value))

    def progress_end(self):
        self.calls.append(("end",))

    def kinds(self):
        return [c[0] for c in self.calls]


def test_bake_pauses_live_hides_the_pose_key_and_says_so(core):
    obj, targets = animated_bar(core)
    obj.larap.live = True
    assert bpy.ops.larap.bake_animation(frame_start=1, frame_end=5) == {"FINISHED"}
    s = obj.larap
    assert not s.live and s.bake_paused_live
    assert [i.name for i in s.bake_keys] == ["LARAP_%04d" % f for f in range(1, 6)]
    assert core.is_baked(obj) and core.pose_key_hidden(obj)
    out = draw(bpy.types.VIEW3D_PT_larap)
    text = " ".join(out.labels())
    assert "Baked: 5 keys" in text and "from LARAP_0001 to LARAP_0005" in text
    assert "the LARAP key is hidden and Live paused" in text
    assert "larap.remove_bake" in out.operators()
    # No pose-key slider while the bake plays (setting it to 1 would add the pose on top of the baked key).
    assert ("prop", "value") not in out.log
    # Live stays paused: moving a target solves nothing and writes nothing.
    before = key_state(obj)
    targets[0].location.z += 0.3
    bpy.context.view_layer.update()
    assert key_state(obj) == before


def test_remove_bake_removes_keys_and_animation_in_one_undoable_step(core):
    obj, targets = animated_bar(core)
    obj.larap.live = True
    user = obj.shape_key_add(name="UserKey", from_mix=False)  # not the bake's: must stay
    user.value = 0.3
    user.keyframe_insert("value", frame=2)
    assert bpy.ops.larap.bake_animation(frame_start=1, frame_end=5) == {"FINISHED"}
    push("baked")
    baked = key_state(obj)
    assert bpy.ops.larap.remove_bake("EXEC_DEFAULT", True) == {"FINISHED"}
    keys = obj.data.shape_keys
    assert [kb.name for kb in keys.key_blocks] == ["Basis", "LARAP", "UserKey"]
    paths = [fc.data_path for fc in keys.animation_data.action.fcurves]
    assert paths == ['key_blocks["UserKey"].value']  # only the bake's animation went
    assert keys.key_blocks["LARAP"].value == 1.0 and obj.larap.live and not obj.larap.bake_paused_live
    assert len(obj.larap.bake_keys) == 0 and not core.is_baked(obj)
    undo()  # one step brings the whole bake back
    obj = bpy.data.objects["Bar"]
    assert key_state(obj) == baked and len(obj.larap.bake_keys) == 5 and not obj.larap.live
    assert len(obj.data.shape_keys.animation_data.action.fcurves) == 6
    with pytest.raises(RuntimeError, match="no baked animation"):
        activate(bpy.data.objects["Bar"])
        bpy.ops.larap.remove_bake()
        bpy.ops.larap.remove_bake()


def test_remove_bake_drops_the_action_the_bake_created(core):
    obj, targets = animated_bar(core)
    assert obj.data.shape_keys.animation_data is None
    bpy.ops.larap.bake_animation(frame_start=1, frame_end=3)
    action = obj.data.shape_keys.animation_data.action
    assert obj.larap.bake_created_action == action.name
    bpy.ops.larap.remove_bake()
    assert obj.data.shape_keys.animation_data.action is None and action.users == 0


def test_bake_and_bind_report_progress_and_the_whole_time(core):
    obj, targets = animated_bar(core)
    wm = CountingWM()
    names = core.bake_animation(obj, bpy.context.scene, 1, 5, overwrite=True, progress=core.Progress(wm))
    assert len(names) == 5
    assert wm.calls[0] == ("begin", 0, 5) and wm.calls[-1] == ("end",)
    assert [c[1] for c in wm.calls if c[0] == "update"][-1] == 5 and wm.kinds().count("update") >= 5
    wm = CountingWM()
    p = core.Progress(wm)
    core.bind(obj, progress=p)
    assert wm.calls[0] == ("begin", 0, 3) and wm.calls[-1] == ("end",) and wm.kinds().count("update") == 4
    assert p.ms > 0
    # A failure still ends the progress (no stuck cursor).
    wm = CountingWM()
    with mock.patch.object(core, "build_runtime", side_effect=core.LarapError("boom")):
        with pytest.raises(core.LarapError):
            core.bind(obj, progress=core.Progress(wm))
    assert wm.calls[-1] == ("end",)


def test_operators_use_blenders_progress(core):
    """The operators hand the real window manager to Progress (counted through a patched Progress)."""
    from larap_blender import operators, progress
    obj, targets = animated_bar(core)
    seen = []

    class Spy(progress.Progress):
        def __init__(self, wm=None, steps=1):
            seen.append(wm)
            super().__init__(CountingWM(), steps)

    with mock.patch.object(operators, "Progress", Spy):
        assert bpy.ops.larap.bind() == {"FINISHED"}
        assert bpy.ops.larap.bake_animation(frame_start=1, frame_end=2) == {"FINISHED"}
    assert seen == [bpy.context.window_manager] * 2


def _modal_bake(obj):
    cls = bpy.types.LARAP_OT_bake_animation
    op = types.SimpleNamespace(frame_start=1, frame_end=5, step=1, prefix="LARAP_", overwrite=False,
                               interactive=True, _timer=None, reports=[])
    op.report = lambda kind, msg: op.reports.append((kind, msg))
    for name in ("run", "modal", "cancel", "_stop", "_report_done"):
        setattr(op, name, types.MethodType(getattr(cls, name), op))
    timer = object()
    wm = CountingWM()
    wm.event_timer_add = lambda *a, **k: timer
    wm.event_timer_remove = lambda t: None
    wm.modal_handler_add = lambda o: None
    status = []
    ctx = types.SimpleNamespace(window_manager=wm, window=object(), scene=bpy.context.scene, object=obj,
                                view_layer=bpy.context.view_layer,
                                workspace=types.SimpleNamespace(status_text_set=status.append))
    return op, ctx, wm, timer, status


def test_modal_bake_esc_puts_everything_back(core):
    obj, targets = animated_bar(core)
    before = key_state(obj)
    op, ctx, wm, timer, status = _modal_bake(obj)
    from larap_blender import operators
    with mock.patch.object(operators, "_windowed", lambda context: True):
        assert op.run(ctx, obj) == {"RUNNING_MODAL"}
    tick = types.SimpleNamespace(type="TIMER", value="NOTHING", timer=timer)
    assert op.modal(ctx, tick) == {"RUNNING_MODAL"}
    assert op.modal(ctx, tick) == {"RUNNING_MODAL"}
    assert "LARAP_0002" in obj.data.shape_keys.key_blocks  # two frames baked so far
    assert op.modal(ctx, types.SimpleNamespace(type="ESC", value="PRESS")) == {"CANCELLED"}
    assert key_state(obj) == before and len(obj.larap.bake_keys) == 0
    assert wm.calls[0] == ("begin", 0, 5) and wm.calls[-1] == ("end",)
    assert "Esc cancel" in status[0] and status[-1] is None
    assert "nothing was changed" in op.reports[-1][1]
    assert bpy.context.scene.frame_current == 1


def test_modal_bake_runs_to_the_end(core):
    obj, targets = animated_bar(core)
    op, ctx, wm, timer, status = _modal_bake(obj)
    from larap_blender import operators
    with mock.patch.object(operators, "_windowed", lambda context: True):
        op.run(ctx, obj)
    tick = types.SimpleNamespace(type="TIMER", value="NOTHING", timer=timer)
    results = [op.modal(ctx, tick) for _ in range(5)]
    assert results[-1] == {"FINISHED"} and results[:-1] == [{"RUNNING_MODAL"}] * 4
    assert len(obj.larap.bake_keys) == 5 and core.pose_key_hidden(obj)
    assert "Baked 5 frames in" in op.reports[-1][1]
    assert [c[1] for c in wm.calls if c[0] == "update"] == [1, 2, 3, 4, 5]
