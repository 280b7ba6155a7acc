# SPDX-License-Identifier: GPL-3.0-or-later
# Undo, renames, bad objects, ownership of data and failures part-way (the robustness issue).
# Run: blender -b --factory-startup --python-exit-code 1 --python tests/blender/run_tests.py -- tests/blender/test_safety.py
import contextlib
import os
import tempfile

import bpy
import numpy as np
import pytest

from conftest import activate, add_group, bar_with_handles, coarse, coords, diagonal, enable_addon, make_bar, \
    mesh_object
from test_pose_modal import event, fake_context, make_operator


# ------------------------------------------------------------------------------------------------
# helpers

def key_state(obj):
    """Everything a user could lose: mesh positions and every shape key's data and settings."""
    me = obj.data
    n = len(me.vertices)
    buf = np.empty(n * 3, np.float32)
    me.vertices.foreach_get("co", buf)
    state = {"mesh": buf.tobytes(), "keys": None}
    if me.shape_keys is not None:
        keys = []
        for kb in me.shape_keys.key_blocks:
            kb.data.foreach_get("co", buf)
            keys.append((kb.name, buf.tobytes(), kb.value, kb.mute, kb.vertex_group,
                         kb.relative_key.name, kb.slider_min, kb.slider_max))
        state["keys"] = keys
    return state


def target_state(t):
    return (tuple(t.location), tuple(t.rotation_euler), tuple(t.scale), t.rotation_mode)


@contextlib.contextmanager
def fd_stdout():
    """Capture C-level stdout (print_undo_steps prints there)."""
    import sys
    sys.stdout.flush()
    fd, path = tempfile.mkstemp()
    saved = os.dup(1)
    out = []
    try:
        os.dup2(fd, 1)
        yield out
    finally:
        os.dup2(saved, 1)
        os.close(saved)
        os.close(fd)
        with open(path) as f:
            out.append(f.read())
        os.remove(path)


def undo_steps():
    with fd_stdout() as out:
        bpy.context.window_manager.print_undo_steps()
    return [line.split("name='")[1].rstrip("'") for line in out[0].splitlines() if "name='" in line]


def push(msg):
    assert bpy.ops.ed.undo_push(message=msg) == {"FINISHED"}


def undo():
    assert bpy.ops.ed.undo() == {"FINISHED"}


# ------------------------------------------------------------------------------------------------
# 1. Undo

def test_headless_undo_is_available(addon):
    """Background mode with --factory-startup has a window, so the real memfile undo stack runs."""
    assert bpy.app.background and bpy.context.window is not None
    assert bpy.context.preferences.edit.undo_steps > 0


def test_undo_after_solve_restores_bit_exactly_and_engine_notices(core):
    obj, rest, left, right, targets = bar_with_handles(core)
    obj.larap.live = True
    targets[1].location.z += 0.6
    bpy.ops.larap.solve()
    push("moved & solved")
    before, t_before = key_state(obj), target_state(targets[1])
    rt = core.runtime(obj)
    version = rt.pose_version
    targets[1].location.z += 0.8
    push("move Empty")
    # As from the UI: the operator itself pushes one undo step.
    assert bpy.ops.larap.solve("EXEC_DEFAULT", True) == {"FINISHED"}
    assert undo_steps()[-1] == "LARAP Solve"
    undo()  # back to "move Empty": the key as before the solve
    undo()  # back to "moved & solved"
    obj = bpy.data.objects["Bar"]  # undo replaced the Python objects
    assert key_state(obj) == before
    assert target_state(obj.larap.handles[1].target) == t_before
    rt = core.runtime(obj)
    assert rt is not None and not rt.validated and not rt.lattice_current and rt.pose_version > version
    # Live is on: the depsgraph update after the undo must not rewrite what the undo restored.
    bpy.context.view_layer.update()
    bpy.context.scene.frame_set(bpy.context.scene.frame_current)
    assert key_state(obj) == before
    # The next solve uses the restored targets (no stale pose from the undone state).
    activate(obj)
    bpy.ops.larap.solve()
    pose = coords(obj, "LARAP")
    assert np.abs(pose[right, 2] - rest[right, 2] - 0.6).max() < 0.02 * diagonal(rest)


def test_undo_of_confirmed_drag_is_one_step(core):
    """The modal operator (UNDO flag) pushes one step when it finishes; headless there is no event
    loop, so the test drives its modal() with synthetic events and pushes that step as Blender's
    wm_operator_finished does, then checks one undo restores everything bit-exactly."""
    obj, rest, left, right, targets = bar_with_handles(core)
    assert "UNDO" in bpy.types.LARAP_OT_pose.bl_options
    push("before drag")
    before, t_before = key_state(obj), target_state(targets[1])
    ctx, _ = fake_context(obj)
    op = make_operator(handle=1)
    assert op.invoke(ctx, event("MOUSEMOVE", pos=(600, 400))) == {"RUNNING_MODAL"}
    for y in (420, 450, 500):
        assert op.modal(ctx, event("MOUSEMOVE", "NOTHING", pos=(600, y))) == {"RUNNING_MODAL"}
    assert undo_steps()[-1] == "before drag"  # nothing pushed during the drag
    assert op.modal(ctx, event("RET")) == {"FINISHED"}
    push("LARAP Pose (Drag Handle)")
    assert key_state(obj) != before
    undo()
    obj = bpy.data.objects["Bar"]
    assert key_state(obj) == before
    assert target_state(obj.larap.handles[1].target) == t_before
    rt = core.runtime(obj)
    assert rt.target_sig == core.target_signature(obj) and rt.weights == ""
    # Redo brings the drag back, also exactly.
    bpy.ops.ed.redo()
    obj = bpy.data.objects["Bar"]
    assert key_state(obj) != before
    assert not core.runtime(obj).validated


def test_undo_of_bake_and_rest_edit_rebuilds_engine(core):
    obj, rest, left, right, targets = bar_with_handles(core)
    targets[1].location.z += 0.5
    push("base")
    before = key_state(obj)
    assert bpy.ops.larap.bake_shape_key("EXEC_DEFAULT", True, name="Baked") == {"FINISHED"}
    undo()
    obj = bpy.data.objects["Bar"]
    assert key_state(obj) == before and "Baked" not in obj.data.shape_keys.key_blocks
    # An undone edit of the rest shape (Basis): the fast path (drags, live) re-validates.
    basis = obj.data.shape_keys.key_blocks["Basis"]
    co = coords(obj, "Basis").astype(np.float32)
    push("rest")
    basis.data.foreach_set("co", (co * 1.5).ravel())
    core.ensure_runtime(obj, "full")
    push("scaled rest")
    undo()
    obj = bpy.data.objects["Bar"]
    rt = core.ensure_runtime(obj, "fast")
    assert np.array_equal(rt.rest, co)


def test_undo_of_apply_restores_binding(core):
    obj, rest, left, right, targets = bar_with_handles(core)
    targets[1].location.z += 0.5
    bpy.ops.larap.solve()
    push("posed")
    before = key_state(obj)
    assert bpy.ops.larap.apply("EXEC_DEFAULT", True) == {"FINISHED"}
    assert not obj.larap.bound
    undo()
    obj = bpy.data.objects["Bar"]
    assert obj.larap.bound and key_state(obj) == before
    activate(obj)
    assert bpy.ops.larap.solve() == {"FINISHED"}


# ------------------------------------------------------------------------------------------------
# 2. Renames

def test_renamed_object_keeps_engine_settings_and_handles(core):
    obj, rest, left, right, targets = bar_with_handles(core)
    rt = core.runtime(obj)
    obj.larap.gamma = 0.3
    obj.name = "Renamed"
    assert core.runtime(obj) is rt  # no rebuild, no orphaned cache entry
    targets[1].location.z += 0.5
    assert bpy.ops.larap.solve() == {"FINISHED"}
    assert core.runtime(obj) is rt and abs(rt.deformer.gamma - 0.3) < 1e-6
    pose = coords(obj, "LARAP")
    assert np.abs(pose[right, 2] - rest[right, 2] - 0.5).max() < 0.02 * diagonal(rest)
    # Live follows the renamed object too, and a renamed target.
    obj.larap.live = True
    targets[1].name = "MyHandle"
    targets[1].location.z += 0.3
    bpy.context.view_layer.update()
    pose = coords(obj, "LARAP")
    assert np.abs(pose[right, 2] - rest[right, 2] - 0.8).max() < 0.03 * diagonal(rest)
    assert core.runtime(obj) is rt and len(core._RUNTIMES) == 1


def test_new_object_with_old_name_does_not_get_the_engine(core):
    obj, rest, *_ = bar_with_handles(core)
    rt = core.runtime(obj)
    obj.name = "Moved"
    other = make_bar("Bar", length=2.0)
    assert other.name == "Bar"
    assert core.runtime(other) is None
    with pytest.raises(RuntimeError, match="not bound"):
        bpy.ops.larap.solve()
    assert core.runtime(obj) is rt


def test_duplicate_gets_its_own_engine(core):
    obj, rest, left, right, targets = bar_with_handles(core)
    dup = obj.copy()
    dup.data = obj.data.copy()
    bpy.context.scene.collection.objects.link(dup)
    assert dup.larap.runtime_id == obj.larap.runtime_id  # copied with the settings
    activate(dup)
    assert bpy.ops.larap.solve() == {"FINISHED"}
    assert dup.larap.runtime_id != obj.larap.runtime_id
    assert core.runtime(dup) is not core.runtime(obj) and core.runtime(obj) is not None


def test_renamed_vertex_group_is_reported_not_a_crash(core):
    obj, rest, left, right, targets = bar_with_handles(core)
    obj.vertex_groups["Right"].name = "RightRenamed"
    targets[0].location.z += 0.4
    assert bpy.ops.larap.solve() == {"FINISHED"}
    w = core.runtime(obj).warnings
    assert any("'Right'" in m and "renamed or deleted" in m for m in w), w
    with pytest.raises(core.LarapError, match="no vertices"):
        core.PoseSession(obj, 1).begin()
    from test_ui import draw
    obj.larap.active_handle = 1
    # Messages are wrapped to the sidebar's width: read the panel's lines as one text.
    assert "'Right' missing (renamed or deleted?)" in " ".join(draw(bpy.types.VIEW3D_PT_larap).labels())
    # Pointing the handle at the new name makes it work again.
    obj.larap.handles[1].vertex_group = "RightRenamed"
    assert bpy.ops.larap.solve() == {"FINISHED"}
    assert core.runtime(obj).warnings == []


# ------------------------------------------------------------------------------------------------
# 3. Objects LARAP cannot work on: a report, never a traceback

OPS = ("bind", "unbind", "solve", "handle_add", "handle_remove", "bake_shape_key", "bake_animation", "apply")


def _call_all(match):
    for name in OPS:
        with pytest.raises(RuntimeError) as info:
            getattr(bpy.ops.larap, name)()
        msg = str(info.value)
        assert "internal error" not in msg and "Traceback" not in msg, (name, msg)
        assert match in msg, (name, msg)


def _pose_invoke_reports(obj):
    ctx, _ = fake_context(obj)
    op = make_operator(handle=0)
    assert op.invoke(ctx, event("LEFTMOUSE")) == {"CANCELLED"}
    assert op.reports and op.reports[-1][0] == {"ERROR"}
    return op.reports[-1][1]


def test_non_mesh_objects_report_for_every_operator(addon):
    for data in (None, bpy.data.curves.new("C", "CURVE"), bpy.data.cameras.new("Cam")):
        ob = bpy.data.objects.new("NotMesh", data)
        bpy.context.scene.collection.objects.link(ob)
        activate(ob)
        _call_all("works on meshes")
        assert "works on meshes" in _pose_invoke_reports(ob)


def test_linked_mesh_data_and_object_report_for_every_operator(addon, tmp_path):
    make_bar("LinkedBar")
    path = str(tmp_path / "lib.blend")
    bpy.ops.wm.save_as_mainfile(filepath=path, copy=True)
    bpy.ops.wm.read_factory_settings(use_empty=True)
    enable_addon()
    with bpy.data.libraries.load(path, link=True) as (src, dst):
        dst.objects = ["LinkedBar"]
        dst.meshes = ["LinkedBar"]
    linked_obj = dst.objects[0]
    bpy.context.scene.collection.objects.link(linked_obj)
    activate(linked_obj)
    _call_all("not editable")
    assert "not editable" in _pose_invoke_reports(linked_obj)
    # A local object whose mesh is linked.
    local = bpy.data.objects.new("LocalObj", dst.meshes[0])
    bpy.context.scene.collection.objects.link(local)
    activate(local)
    assert local.library is None and local.data.library is not None
    _call_all("not editable")


def test_edit_mode_every_operator_reports_or_switches(core):
    obj, rest, left, right, targets = bar_with_handles(core)
    expected = {"bind": "FINISHED", "solve": "FINISHED", "bake_shape_key": "FINISHED",
                "bake_animation": "FINISHED", "unbind": "FINISHED", "apply": "FINISHED"}
    for name in ("bind", "solve", "bake_shape_key", "bake_animation", "unbind", "bind", "apply"):
        activate(obj)
        bpy.ops.object.mode_set(mode="EDIT")
        kwargs = {"overwrite": True} if name.startswith("bake") else {}
        assert getattr(bpy.ops.larap, name)(**kwargs) == {expected[name]}, name
        assert obj.mode == "OBJECT", name
    # Pose switches to Object Mode like the others; handle_add/remove work in Edit Mode.
    bpy.ops.larap.bind()
    bpy.ops.object.mode_set(mode="EDIT")
    ctx, _ = fake_context(obj)
    ctx.view_layer = bpy.context.view_layer
    op = make_operator(handle=0)
    assert op.invoke(ctx, event("LEFTMOUSE")) == {"RUNNING_MODAL"}
    assert obj.mode == "OBJECT"
    assert op.modal(ctx, event("ESC")) == {"CANCELLED"}
    bpy.ops.object.mode_set(mode="EDIT")
    assert bpy.ops.larap.handle_remove(index=0) == {"FINISHED"}
    # Another object in Edit Mode (not the active one): a report, no mode switch behind the user's back.
    with pytest.raises(core.LarapError, match="Edit Mode"):
        core.solve(obj)
    bpy.ops.object.mode_set(mode="OBJECT")


def test_meshes_without_faces_or_vertices(core):
    edges = mesh_object("Edges", [(0, 0, 0), (1, 0, 0), (2, 0.2, 0), (3, 0, 0.1)])
    edges.data.edges.add(0)
    add_group(edges, "G", [3])
    coarse(edges, 200)
    assert bpy.ops.larap.handle_add(vertex_group="G") == {"FINISHED"}
    assert bpy.ops.larap.bind() == {"FINISHED"}
    assert bpy.ops.larap.solve() == {"FINISHED"}
    empty = mesh_object("NoVerts", [])
    for name in ("bind", "solve", "apply", "bake_shape_key"):
        with pytest.raises(RuntimeError) as info:
            getattr(bpy.ops.larap, name)()
        assert "internal error" not in str(info.value)
    assert empty.data.shape_keys is None and not empty.larap.bound


# ------------------------------------------------------------------------------------------------
# 4. Save, close, reopen mid-session (engine cache by id)

def test_reopen_mid_session_keeps_handles_settings_and_ids(core, tmp_path):
    obj, rest, left, right, targets = bar_with_handles(core)
    obj.larap.gamma = 0.2
    targets[1].location.z += 0.5
    bpy.ops.larap.solve()
    rid = obj.larap.runtime_id
    pose = coords(obj, "LARAP")
    path = str(tmp_path / "mid.blend")
    bpy.ops.wm.save_as_mainfile(filepath=path)
    bpy.ops.wm.read_homefile(use_empty=True)  # close
    assert core._RUNTIMES == {}
    bpy.ops.wm.open_mainfile(filepath=path)
    obj = bpy.data.objects["Bar"]
    s = obj.larap
    assert s.bound and s.runtime_id == rid and abs(s.gamma - 0.2) < 1e-6 and s.owned_key_name == "LARAP"
    assert [h.vertex_group for h in s.handles] == ["Left", "Right"] and all(h.created_target for h in s.handles)
    assert np.array_equal(coords(obj, "LARAP"), pose)
    activate(obj)
    assert bpy.ops.larap.solve() == {"FINISHED"}
    assert np.abs(coords(obj, "LARAP") - pose).max() < 2e-3 * diagonal(rest)


# ------------------------------------------------------------------------------------------------
# 5. Unbind removes only LARAP's own data

def test_unbind_keeps_everything_the_user_made(core):
    obj = make_bar()
    rest = coords(obj)
    obj.shape_key_add(name="Basis")
    smile = obj.shape_key_add(name="Smile")
    smile.data.foreach_set("co", (rest * 1.1).astype(np.float32).ravel())
    add_group(obj, "Left", np.flatnonzero(rest[:, 0] < -1.8))
    add_group(obj, "Right", np.flatnonzero(rest[:, 0] > 1.8))
    obj.vertex_groups.new(name="UserGroup")
    obj.modifiers.new("Sub", "SUBSURF")
    user_empty = bpy.data.objects.new("UserEmpty", None)
    bpy.context.scene.collection.objects.link(user_empty)
    activate(obj)
    bpy.ops.larap.handle_add(vertex_group="Left", target="UserEmpty")
    bpy.ops.larap.handle_add(vertex_group="Right")
    coarse(obj)
    before = key_state(obj)
    assert bpy.ops.larap.bind() == {"FINISHED"}
    assert [kb.name for kb in obj.data.shape_keys.key_blocks] == ["Basis", "Smile", "LARAP"]
    user_empty.location.z += 1.0
    bpy.ops.larap.solve()
    assert bpy.ops.larap.unbind() == {"FINISHED"}
    assert key_state(obj) == before  # Basis, Smile (data and settings) and the mesh, bit-exact
    assert {"Left", "Right", "UserGroup"} <= set(obj.vertex_groups.keys())
    assert [m.name for m in obj.modifiers] == ["Sub"]
    assert "UserEmpty" in bpy.data.objects and "LARAP_target_Right" in bpy.data.objects
    # Removing handles with "delete target": only the Empty LARAP created goes.
    assert bpy.ops.larap.handle_remove(index=0, delete_target=True) == {"FINISHED"}
    assert "UserEmpty" in bpy.data.objects
    assert bpy.ops.larap.handle_remove(index=0, delete_target=True) == {"FINISHED"}
    assert "LARAP_target_Right" not in bpy.data.objects
    # A user Empty named like LARAP's is not LARAP's.
    fake = bpy.data.objects.new("LARAP_target_Mine", None)
    bpy.context.scene.collection.objects.link(fake)
    activate(obj)
    bpy.ops.larap.handle_add(vertex_group="Left", target=fake.name)
    bpy.ops.larap.handle_remove(index=0, delete_target=True)
    assert "LARAP_target_Mine" in bpy.data.objects


def test_unbind_without_keys_restores_plain_mesh(core):
    obj, rest, *_ = bar_with_handles(core)
    assert bpy.ops.larap.unbind() == {"FINISHED"}
    assert obj.data.shape_keys is None and np.array_equal(coords(obj), rest)


def test_user_key_named_like_the_pose_key_is_never_touched(core):
    obj = make_bar()
    rest = coords(obj)
    obj.shape_key_add(name="Basis")
    mine = obj.shape_key_add(name="LARAP")
    mine.data.foreach_set("co", (rest + 0.25).astype(np.float32).ravel())
    mine.value = 0.3
    add_group(obj, "Right", np.flatnonzero(rest[:, 0] > 1.8))
    bpy.ops.larap.handle_add(vertex_group="Right")
    coarse(obj)
    before = key_state(obj)
    with pytest.raises(RuntimeError, match="did not create"):
        bpy.ops.larap.bind()
    assert key_state(obj) == before and not obj.larap.bound
    bpy.ops.larap.unbind()  # not bound: removes nothing of the user's
    assert key_state(obj) == before
    obj.larap.shape_key = "LARAP_pose_key"
    assert bpy.ops.larap.bind() == {"FINISHED"}
    bpy.ops.larap.unbind()
    assert key_state(obj) == before


# ------------------------------------------------------------------------------------------------
# 6. Nothing is destroyed without asking

def test_apply_asks_for_confirmation(core):
    obj, rest, left, right, targets = bar_with_handles(core)
    targets[1].location.z += 0.5
    bpy.ops.larap.solve()
    before = key_state(obj)
    asked = []

    class WM:
        def invoke_confirm(self, op, event):
            asked.append(op)
            return {"CANCELLED"}  # the user clicks away

    ctx = type("Ctx", (), {"window_manager": WM(), "object": obj})()
    assert bpy.types.LARAP_OT_apply.invoke(object(), ctx, None) == {"CANCELLED"}
    assert len(asked) == 1 and key_state(obj) == before and obj.larap.bound


def test_bakes_do_not_overwrite_user_keys(core):
    obj, rest, left, right, targets = bar_with_handles(core)
    mine = obj.shape_key_add(name="Mine")
    mine.data.foreach_set("co", (rest * 0.5).astype(np.float32).ravel())
    frame1 = obj.shape_key_add(name="LARAP_0001")
    targets[1].location.z += 0.5
    bpy.ops.larap.solve()
    before = key_state(obj)
    with pytest.raises(RuntimeError, match="exists"):
        bpy.ops.larap.bake_shape_key(name="Mine")
    with pytest.raises(RuntimeError, match="exist"):
        bpy.ops.larap.bake_animation(frame_start=1, frame_end=2)
    assert key_state(obj) == before
    assert bpy.ops.larap.bake_shape_key(name="Mine", overwrite=True) == {"FINISHED"}
    assert not np.array_equal(coords(obj, "Mine"), rest * 0.5)
    assert frame1.name == "LARAP_0001"


def test_no_operator_deletes_user_objects_groups_or_keys(core):
    """Every operator (apply included, which the UI confirms) on a scene with user data."""
    obj, rest, left, right, targets = bar_with_handles(core)
    obj.shape_key_add(name="UserKey")
    obj.vertex_groups.new(name="UserGroup")
    obj.modifiers.new("Bevel", "BEVEL")
    other = make_bar("Other", length=1.0)
    activate(obj)
    names = set(bpy.data.objects.keys())
    for op, kw in (("solve", {}), ("bake_shape_key", {"name": "B"}),
                   ("bake_animation", {"frame_start": 1, "frame_end": 2}), ("unbind", {}), ("bind", {}),
                   ("handle_remove", {"index": 0}), ("apply", {})):
        assert getattr(bpy.ops.larap, op)(**kw) == {"FINISHED"}, op
        assert names <= set(bpy.data.objects.keys()), op
        assert "UserKey" in obj.data.shape_keys.key_blocks and "UserGroup" in obj.vertex_groups, op
        assert [m.name for m in obj.modifiers] == ["Bevel"], op
    assert other.name in bpy.data.objects


# ------------------------------------------------------------------------------------------------
# 7. A failure part-way leaves the object untouched

class Boom:
    def __init__(self, exc=MemoryError, after=0):
        self.exc, self.left = exc, after

    def __call__(self, *args, **kwargs):
        if self.left <= 0:
            raise self.exc("simulated engine failure")
        self.left -= 1
        return self.real(*args, **kwargs)


def _patch(monkeypatch, name, boom):
    import larap
    boom.real = getattr(larap.Deformer, name)
    monkeypatch.setattr(larap.Deformer, name, lambda self, *a, **k: boom(self, *a, **k))


def test_bind_memory_error_leaves_mesh_untouched(core, monkeypatch):
    obj = make_bar()
    rest = coords(obj)
    add_group(obj, "Right", np.flatnonzero(rest[:, 0] > 1.8))
    bpy.ops.larap.handle_add(vertex_group="Right")
    coarse(obj)
    h = obj.larap.handles[0]
    h_before = (tuple(h.rest_matrix), h.has_rest)
    obj.larap.handles[0].target.location.z += 1.0  # bind would record this as the new rest
    for name in ("__init__", "set_handle_groups", "solve"):
        before = key_state(obj)
        import larap
        if name == "__init__":
            def init(self, *a, **k):
                raise MemoryError("lattice needs 99999 MiB")
            monkeypatch.setattr(larap.Deformer, "__init__", init)
        else:
            _patch(monkeypatch, name, Boom())
        with pytest.raises(RuntimeError, match="out of memory"):
            bpy.ops.larap.bind()
        assert key_state(obj) == before and obj.data.shape_keys is None, name
        s = obj.larap
        assert not s.bound and s.bind_vertex_count == 0 and s.owned_key_name == "" and not s.created_basis
        assert (tuple(h.rest_matrix), h.has_rest) == h_before
        assert core.runtime(obj) is None
        monkeypatch.undo()
    assert bpy.ops.larap.bind() == {"FINISHED"}


def test_rebind_failure_keeps_previous_binding(core, monkeypatch):
    obj, rest, left, right, targets = bar_with_handles(core)
    obj.shape_key_add(name="UserKey")
    targets[1].location.z += 0.5
    bpy.ops.larap.solve()
    before, rt = key_state(obj), core.runtime(obj)
    mats = [tuple(h.rest_matrix) for h in obj.larap.handles]
    _patch(monkeypatch, "solve", Boom(RuntimeError))
    with pytest.raises(RuntimeError, match="simulated"):
        bpy.ops.larap.bind()
    assert key_state(obj) == before and obj.larap.bound
    assert [tuple(h.rest_matrix) for h in obj.larap.handles] == mats
    assert core.runtime(obj) is rt
    monkeypatch.undo()
    assert bpy.ops.larap.solve() == {"FINISHED"}


def test_solve_apply_bake_failures_leave_mesh_untouched(core, monkeypatch):
    obj, rest, left, right, targets = bar_with_handles(core)
    obj.shape_key_add(name="UserKey")
    targets[1].location.z += 0.5
    bpy.ops.larap.solve()
    targets[1].location.z += 0.3  # the key is now out of date: apply/bake must solve again
    before = key_state(obj)
    _patch(monkeypatch, "solve", Boom(MemoryError))
    for op, kw in (("solve", {}), ("apply", {}), ("bake_shape_key", {"name": "B"})):
        with pytest.raises(RuntimeError, match="out of memory"):
            getattr(bpy.ops.larap, op)(**kw)
        assert key_state(obj) == before and obj.larap.bound, op
    monkeypatch.undo()
    # Failing on the third frame of an animation bake: no half-baked keys, no stray f-curves.
    scene = bpy.context.scene
    e = targets[1]
    e.keyframe_insert("location", frame=1)
    e.location.z += 1.0
    e.keyframe_insert("location", frame=5)
    scene.frame_set(2)
    obj.data.shape_keys.key_blocks["UserKey"].keyframe_insert("value", frame=1)
    before = key_state(obj)
    fcurves = [(fc.data_path, [tuple(k.co) for k in fc.keyframe_points])
               for fc in obj.data.shape_keys.animation_data.action.fcurves]
    _patch(monkeypatch, "solve", Boom(MemoryError, after=2))
    with pytest.raises(RuntimeError, match="out of memory"):
        bpy.ops.larap.bake_animation(frame_start=1, frame_end=5)
    assert key_state(obj) == before and scene.frame_current == 2
    assert [(fc.data_path, [tuple(k.co) for k in fc.keyframe_points])
            for fc in obj.data.shape_keys.animation_data.action.fcurves] == fcurves
    monkeypatch.undo()
    assert bpy.ops.larap.bake_animation(frame_start=1, frame_end=5) == {"FINISHED"}


def test_cell_splitting_out_of_memory_names_the_panel_settings(core, monkeypatch):
    """The engine's MemoryError for cell splitting names its Python keywords (split_resolution,
    split_cells); the add-on's report names what the panel shows instead (Cells, Cell Size, Parts
    Apart). The engine's own text comes from a real bind of two close boxes under a tight limit."""
    import larap
    from larap import shapes
    V, F = shapes.concat(shapes.box((0, 0, 0), (4, 1, 1), 4), shapes.box((0, 0, 1.3), (4, 1, 2.3), 4))
    with pytest.raises(MemoryError) as caught:
        larap.Deformer(V, F, cell_size=1.0, split_resolution=64, max_bytes=200_000)
    engine_text = str(caught.value)
    assert engine_text.startswith("cell splitting") and "split_resolution" in engine_text
    obj, rest, left, right, targets = bar_with_handles(core)
    bpy.ops.larap.unbind()

    def init(self, *a, **k):
        raise MemoryError(engine_text)
    monkeypatch.setattr(larap.Deformer, "__init__", init)
    with pytest.raises(RuntimeError) as report:
        bpy.ops.larap.bind()
    text = str(report.value)
    assert "out of memory" in text and "Parts Apart" in text and "Cell Size" in text, text
    assert "split_resolution" not in text and "split_cells" not in text, text
    assert not obj.larap.bound


def test_linked_duplicates_never_overwrite_each_others_pose(core):
    """Alt+D shares the mesh data, and with it the pose key: two bound users of one mesh would
    each overwrite the other's pose. Solve on either says so and writes nothing; Unbind of the
    copy keeps the key (it is the original's pose too), after which the original poses again and
    the copy shows it (linked data); binding the copy again is refused while the original is bound."""
    obj, rest, left, right, targets = bar_with_handles(core)
    targets[1].location.z += 0.3
    bpy.context.view_layer.update()
    assert bpy.ops.larap.solve() == {"FINISHED"}
    posed = coords(obj, "LARAP")
    activate(obj)
    assert bpy.ops.object.duplicate(linked=True) == {"FINISHED"}
    copy = bpy.context.active_object
    assert copy != obj and copy.data == obj.data and copy.larap.bound
    for o in (obj, copy):
        activate(o)
        with pytest.raises(RuntimeError, match="shares its mesh data with .* Make Single User"):
            bpy.ops.larap.solve()
    np.testing.assert_array_equal(coords(obj, "LARAP"), posed)
    activate(copy)
    assert bpy.ops.larap.unbind() == {"FINISHED"}
    assert obj.data.shape_keys.key_blocks.get("LARAP") is not None and obj.larap.bound
    # the key is the original's now: the unbound copy no longer claims it (or a Basis it made)
    assert copy.larap.owned_key_name == "" and not copy.larap.created_basis
    assert obj.larap.owned_key_name == "LARAP"
    activate(obj)
    targets[1].location.z += 0.2
    bpy.context.view_layer.update()
    assert bpy.ops.larap.solve() == {"FINISHED"}
    assert np.abs(coords(obj, "LARAP") - posed).max() > 0.1
    activate(copy)
    with pytest.raises(RuntimeError, match="shares its mesh data"):
        bpy.ops.larap.bind()
    assert not copy.larap.bound
    # a bound copy in no scene (unlinked, kept by a fake user) poses nothing and blocks nothing
    activate(obj)
    assert bpy.ops.object.duplicate(linked=True) == {"FINISHED"}
    orphan = bpy.context.active_object
    for coll in list(orphan.users_collection):
        coll.objects.unlink(orphan)
    orphan.use_fake_user = True
    bpy.context.view_layer.update()
    activate(obj)
    assert orphan.larap.bound and bpy.ops.larap.solve() == {"FINISHED"}
