# SPDX-License-Identifier: GPL-3.0-or-later
# Run: blender -b --factory-startup --python-exit-code 1 --python tests/blender/run_tests.py -- tests/blender/test_preview_shading.py
"""The preview's faces' shading (preview.face_shading): read once per change of the mesh, never
per live move or drag step, and read again on every change Blender evaluates (Shade Smooth/Flat,
a script's update, the catch-up's write), after undo and when the object gets another mesh.
Headless, with the GPU part switched on (the gpu_preview fixture)."""
import bpy
import numpy as np
import pytest

from conftest import activate, bar_with_handles, coords


@pytest.fixture
def reads(gpu_preview, monkeypatch):
    """Counts the reads of every face's smooth flag."""
    count = {"n": 0}
    orig = gpu_preview._read_face_shading

    def counted(me):
        count["n"] += 1
        return orig(me)
    monkeypatch.setattr(gpu_preview, "_read_face_shading", counted)
    return count


def live_move(targets, dz):
    targets[1].location.z += dz
    bpy.context.view_layer.update()  # depsgraph_update_post -> live


def shade(obj, smooth):
    """Shade Smooth / Flat as the artist does (the operator on the selected object)."""
    with bpy.context.temp_override(selected_editable_objects=[obj], active_object=obj, object=obj):
        op = bpy.ops.object.shade_smooth if smooth else bpy.ops.object.shade_flat
        assert op() == {"FINISHED"}


def test_live_moves_read_the_faces_once(core, gpu_preview, reads):
    obj, rest, left, right, targets = bar_with_handles(core)
    obj.larap.live = True
    for k in range(5):
        live_move(targets, 0.1)
        assert gpu_preview.showing(obj)
    assert reads["n"] == 1  # the first move's; none per move after it
    assert gpu_preview.face_shading(obj) == "flat"


def test_the_catch_up_write_is_read_again_by_its_update_not_by_the_next_move(core, gpu_preview, reads):
    from larap_blender import catchup
    obj, rest, left, right, targets = bar_with_handles(core)
    obj.larap.live = True
    live_move(targets, 0.3)
    assert reads["n"] == 1
    catchup.catch_up_all()  # writes the mesh: the next evaluation reports it changed
    assert not gpu_preview.showing(obj)
    bpy.context.view_layer.update()  # Blender evaluates the write (the timer's loop iteration)
    assert reads["n"] == 2 and not gpu_preview.shading_stale(obj)
    for k in range(3):
        live_move(targets, 0.1)
    assert reads["n"] == 2 and gpu_preview.showing(obj)


def test_shade_smooth_and_flat_are_seen_by_the_preview(core, gpu_preview, reads):
    obj, rest, left, right, targets = bar_with_handles(core)
    obj.larap.live = True
    live_move(targets, 0.2)
    assert gpu_preview.face_shading(obj) == "flat" and gpu_preview.showing(obj)
    shade(obj, True)
    bpy.context.view_layer.update()
    assert gpu_preview.face_shading(obj) == "smooth" and gpu_preview.blocker(obj) == ""
    obj.data.polygons[3].use_smooth = False  # a script's change through RNA tags the mesh
    bpy.context.view_layer.update()
    assert gpu_preview.blocker(obj) == "mixed flat and smooth faces"
    before = coords(obj, "LARAP")
    live_move(targets, 0.3)  # the preview would lie: the mesh is written instead
    assert not gpu_preview.showing(obj) and not np.array_equal(coords(obj, "LARAP"), before)
    shade(obj, False)
    bpy.context.view_layer.update()
    assert gpu_preview.face_shading(obj) == "flat" and gpu_preview.blocker(obj) == ""
    live_move(targets, 0.1)
    assert gpu_preview.showing(obj)


def test_foreach_set_without_an_update_is_seen_once_blender_is_told(core, gpu_preview, reads):
    """foreach_set bypasses Blender's update (Blender itself draws the old shading until the mesh
    is tagged); Mesh.update() tags it, and the preview reads the faces again."""
    obj, rest, left, right, targets = bar_with_handles(core)
    me = obj.data
    assert gpu_preview.face_shading(obj) == "flat"
    me.polygons.foreach_set("use_smooth", np.ones(len(me.polygons), dtype=bool))
    me.update()
    bpy.context.view_layer.update()
    assert gpu_preview.face_shading(obj) == "smooth"


def test_drag_steps_read_no_face(core, gpu_preview, reads):
    obj, rest, left, right, targets = bar_with_handles(core)
    session = core.PoseSession(obj, 1).begin()
    at_click = reads["n"]
    assert at_click <= 1
    for k in range(4):
        session.update(translation=(0.0, 0.0, 0.1 * (k + 1)))
        assert gpu_preview.showing(obj)
    assert reads["n"] == at_click
    session.confirm()  # writes the mesh
    session = core.PoseSession(obj, 1).begin()  # evaluates that write, reads the faces at the click
    at_click = reads["n"]
    for k in range(3):
        session.update(translation=(0.0, 0.1 * (k + 1), 0.0))
    assert reads["n"] == at_click
    session.cancel()


def test_undo_and_another_mesh_read_the_faces_again(core, gpu_preview, reads):
    from test_safety import push, undo
    obj, rest, left, right, targets = bar_with_handles(core)
    assert gpu_preview.face_shading(obj) == "flat"
    push("flat")
    shade(obj, True)
    bpy.context.view_layer.update()
    assert gpu_preview.face_shading(obj) == "smooth"
    push("smooth")
    undo()
    obj = bpy.data.objects["Bar"]
    assert gpu_preview.shading_stale(obj)
    assert gpu_preview.face_shading(obj) == "flat"
    # Another mesh on the object (not evaluated yet): its own faces are read.
    other = obj.data.copy()
    other.polygons.foreach_set("use_smooth", np.ones(len(other.polygons), dtype=bool))
    obj.data = other
    assert gpu_preview.face_shading(obj) == "smooth"


def test_a_draw_uses_the_shading_read_last(core, gpu_preview):
    """The shader's smooth/flat mode comes from the faces' shading as last read (Shade Flat after
    the per-binding data was built is drawn flat), not from the data built once per binding."""
    obj, rest, left, right, targets = bar_with_handles(core)
    obj.larap.live = True
    shade(obj, True)
    bpy.context.view_layer.update()
    live_move(targets, 0.2)
    assert gpu_preview.showing(obj) and gpu_preview.draws_smooth(obj)
    shade(obj, False)
    bpy.context.view_layer.update()
    assert not gpu_preview.draws_smooth(obj)


def duplicate(obj, linked=False):
    """Shift+D (Alt+D with ``linked``) as the artist does: the copy shares the original's runtime
    id, bound and preview settings until it is bound or posed itself (runtime.claim_key)."""
    activate(obj)
    assert bpy.ops.object.duplicate(linked=linked) == {"FINISHED"}
    dup = bpy.context.active_object
    assert dup != obj and dup.larap.runtime_id == obj.larap.runtime_id and dup.larap.bound
    return dup


def test_a_duplicate_and_its_original_keep_their_own_shading(core, gpu_preview, reads):
    """The panel asks about the duplicate (blocker) and the preview about the original: each mesh
    is read once, and the original is drawn flat while its smooth duplicate is smooth."""
    obj, rest, left, right, targets = bar_with_handles(core)
    dup = duplicate(obj)
    assert dup.data != obj.data  # Duplicate Data: Mesh (the default)
    shade(dup, True)
    bpy.context.view_layer.update()
    before = reads["n"]
    for k in range(3):
        assert gpu_preview.blocker(obj) == ""  # a live move of the original
        assert gpu_preview.blocker(dup) == ""  # the panel, showing the duplicate
        assert not gpu_preview.draws_smooth(obj)  # the original's faces are flat
        assert gpu_preview.face_shading(obj) == "flat"
        assert gpu_preview.draws_smooth(dup)
    assert reads["n"] - before <= 2  # one read per mesh, not one per question


def test_linked_duplicates_share_their_mesh_shading(core, gpu_preview, reads):
    """Alt+D: one mesh, one answer for both objects, read once and again after its change."""
    obj, rest, left, right, targets = bar_with_handles(core)
    dup = duplicate(obj, linked=True)
    assert dup.data == obj.data
    before = reads["n"]
    for k in range(3):
        assert gpu_preview.face_shading(obj) == "flat" and gpu_preview.face_shading(dup) == "flat"
    assert reads["n"] - before <= 1
    shade(dup, True)
    bpy.context.view_layer.update()
    assert gpu_preview.shading_stale(obj) or gpu_preview.face_shading(obj) == "smooth"
    assert gpu_preview.face_shading(obj) == "smooth" and gpu_preview.face_shading(dup) == "smooth"
    assert gpu_preview.draws_smooth(obj) and gpu_preview.draws_smooth(dup)


def assert_caught_up(core, obj, before):
    """The preview ended where Blender draws the mesh again: the pose key holds the final pose of
    the current targets (what the catch-up writes) and the object is shown again."""
    from larap_blender.solving import key_up_to_date
    assert not core.preview.showing(obj) and not obj.hide_get()
    assert not core.runtime(obj).needs_catchup and key_up_to_date(obj)
    assert not np.array_equal(coords(obj, "LARAP"), before)


def test_mixed_shading_while_the_preview_shows_ends_it_there(core, gpu_preview, reads):
    """A script sets a few faces flat on a smooth mesh the preview shows: the preview would draw
    them smooth, so it ends at that update (the mesh catches up), not at the next move."""
    obj, rest, left, right, targets = bar_with_handles(core)
    obj.larap.live = True
    shade(obj, True)
    bpy.context.view_layer.update()
    live_move(targets, 0.3)
    assert gpu_preview.showing(obj) and gpu_preview.draws_smooth(obj) and obj.hide_get()
    before = coords(obj, "LARAP")
    obj.data.polygons[3].use_smooth = False
    bpy.context.view_layer.update()
    assert gpu_preview.blocker(obj) == "mixed flat and smooth faces"
    assert_caught_up(core, obj, before)


def test_a_modifier_added_while_the_preview_shows_ends_it_there(core, gpu_preview):
    obj, rest, left, right, targets = bar_with_handles(core)
    obj.larap.live = True
    live_move(targets, 0.3)
    assert gpu_preview.showing(obj)
    before = coords(obj, "LARAP")
    obj.modifiers.new("Subdivision", "SUBSURF")
    bpy.context.view_layer.update()
    assert gpu_preview.blocker(obj).startswith("modifiers after the pose key")
    assert_caught_up(core, obj, before)


def test_the_shading_refresh_walks_the_updated_objects_not_the_scene(core, gpu_preview, reads, monkeypatch):
    """Each depsgraph update that touches a mesh (every Edit Mode step) looks only at the objects
    it reports (Blender reports a changed mesh's objects with it), not at every object of the
    scene. Live's own walk (its targets moved) is not this test's: it is switched off here."""
    from types import SimpleNamespace
    from larap_blender import handlers
    obj, rest, left, right, targets = bar_with_handles(core)
    obj.larap.live = True
    gpu_preview.face_shading(obj)
    gpu_preview.meshes_changed({obj.data.as_pointer()})
    assert gpu_preview.shading_stale(obj)
    monkeypatch.setattr(handlers, "live_update", lambda scene, names: 0)

    class Scene:
        walks = 0

        @property
        def objects(self):
            Scene.walks += 1
            return bpy.context.scene.objects

    update = SimpleNamespace(updates=[SimpleNamespace(id=obj), SimpleNamespace(id=obj.data)])
    handlers.larap_depsgraph_update_post(Scene(), update)
    assert Scene.walks == 0
    assert not gpu_preview.shading_stale(obj)  # read now, ahead of the next live move


def test_a_change_the_preview_cannot_draw_during_a_drag_is_left_to_the_drag(core, gpu_preview):
    """Mid-drag, the handler does not catch up (that would write behind the drag's back, and
    cancel would no longer restore the pose key): the drag's next step writes the mesh itself,
    and cancel still restores it exactly."""
    obj, rest, left, right, targets = bar_with_handles(core)
    shade(obj, True)
    bpy.context.view_layer.update()
    before = coords(obj, "LARAP") if obj.data.shape_keys else None
    session = core.PoseSession(obj, 1).begin()
    session.update(translation=(0.0, 0.0, 0.2))
    assert gpu_preview.showing(obj)
    start = coords(obj, "LARAP")
    obj.data.polygons[3].use_smooth = False
    bpy.context.view_layer.update()
    assert np.array_equal(coords(obj, "LARAP"), start)  # nothing written by the handler
    session.update(translation=(0.0, 0.0, 0.3))
    assert not gpu_preview.showing(obj) and not np.array_equal(coords(obj, "LARAP"), start)
    session.cancel()
    assert np.array_equal(coords(obj, "LARAP"), start)
    assert before is None or np.array_equal(before, start)


def test_with_no_usable_handle_a_live_move_never_hides_the_mesh(core, gpu_preview):
    """Both handles' vertex groups renamed: a live move writes the rest pose (with its warning)
    and Blender keeps drawing the mesh; the preview, with no posed lattice to draw, used to hide
    it until the catch-up (the mesh vanished while an Empty was dragged)."""
    obj, rest, left, right, targets = bar_with_handles(core)
    obj.larap.live = True
    live_move(targets, 0.1)
    assert gpu_preview.showing(obj)  # the preview path is the one taken
    core.preview.stop(obj)
    for g in obj.vertex_groups:
        g.name = "renamed_" + g.name
    for k in range(3):
        live_move(targets, 0.1)
        assert not gpu_preview.showing(obj) and not obj.hide_get()
    np.testing.assert_allclose(coords(obj, "LARAP"), rest, atol=1e-6)
    assert any("no usable handles" in w for w in core.runtime(obj).warnings)
    assert not gpu_preview.show(obj)  # nothing posed to draw
