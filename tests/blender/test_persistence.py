# SPDX-License-Identifier: GPL-3.0-or-later
# Run: blender -b --factory-startup --python-exit-code 1 --python tests/blender/run_tests.py -- tests/blender/test_persistence.py
import bpy
import numpy as np

from conftest import activate, bar_with_handles, coords, diagonal


def test_settings_and_handles_survive_save_reload(core, tmp_path):
    obj, rest, left, right, targets = bar_with_handles(core)
    s = obj.larap
    s.gamma = 0.25
    s.iterations = 12
    s.weights_final = "trilinear"
    s.device = "cpu"
    s.live = True
    s.show_overlay = True
    s.resolution_mode = "CELLS"
    s.cells = 800
    bpy.ops.larap.bind()
    targets[1].location.z += 0.5
    bpy.ops.larap.solve()
    pose = coords(obj, "LARAP")
    rest_mats = [tuple(h.rest_matrix) for h in s.handles]
    path = str(tmp_path / "larap.blend")
    bpy.ops.wm.save_as_mainfile(filepath=path)

    bpy.ops.wm.read_factory_settings(use_empty=True)
    from conftest import enable_addon
    enable_addon()
    bpy.ops.wm.open_mainfile(filepath=path)
    from larap_blender import core as core2
    assert core2._RUNTIMES == {}  # engines are runtime-only
    obj = bpy.data.objects["Bar"]
    s = obj.larap
    assert s.bound and abs(s.gamma - 0.25) < 1e-6 and s.iterations == 12
    assert s.weights_final == "trilinear" and s.device == "cpu" and s.live and s.show_overlay
    assert s.resolution_mode == "CELLS" and s.cells == 800
    assert [h.vertex_group for h in s.handles] == ["Left", "Right"]
    assert [h.target.name for h in s.handles] == [t for t in ("LARAP_target_Left", "LARAP_target_Right")]
    assert [tuple(h.rest_matrix) for h in s.handles] == rest_mats
    assert np.array_equal(coords(obj, "LARAP"), pose)
    # Solving rebuilds the engine lazily and reproduces the saved pose.
    activate(obj)
    s.live = False
    assert bpy.ops.larap.solve() == {"FINISHED"}
    assert core2.runtime(obj) is not None
    assert np.abs(coords(obj, "LARAP") - pose).max() < 2e-3 * diagonal(rest)
    s.handles[1].target.location.z += 0.5
    bpy.ops.larap.solve()
    assert np.abs(coords(obj, "LARAP")[right, 2] - rest[right, 2] - 1.0).max() < 0.02 * diagonal(rest)


def _reload(path):
    bpy.ops.wm.read_factory_settings(use_empty=True)
    from conftest import enable_addon
    enable_addon()
    bpy.ops.wm.open_mainfile(filepath=path)
    return bpy.data.objects["Bar"]


def _old_file(core, tmp_path):
    """A bar bound and posed at Stiffness 0.1, saved as an add-on version before settings version
    1 saved it (Stiffness never changed: not stored; no version). Returns (path, pose, rest)."""
    from larap_blender import props
    obj, rest, left, right, targets = bar_with_handles(core)
    s = obj.larap
    assert s.is_property_set("gamma") and abs(s.gamma - props.GAMMA) < 1e-7  # bind stores it
    assert s.settings_version == props.SETTINGS_VERSION
    s.gamma = props.GAMMA_BEFORE_1
    targets[1].location.z += 0.5
    assert bpy.ops.larap.solve() == {"FINISHED"}
    pose = coords(obj, "LARAP")
    s.property_unset("gamma")
    s.property_unset("settings_version")
    assert abs(s.gamma - props.GAMMA) < 1e-7 and s.settings_version == 0
    path = str(tmp_path / "old.blend")
    bpy.ops.wm.save_as_mainfile(filepath=path)
    return path, pose, rest


def test_a_file_bound_before_the_stiffness_default_changed_poses_as_before(core, tmp_path):
    """Stiffness's default went from 0.1 to 0.03 (settings version 1). Blender does not store an
    unset property, so an object bound by an older version whose Stiffness was never changed
    would read the new default: it keeps 0.1 (stored explicitly on load), its saved pose is left
    as it is, and it poses as it did."""
    from larap_blender import props
    path, pose, rest = _old_file(core, tmp_path)
    obj = _reload(path)
    s = obj.larap
    assert s.is_property_set("gamma") and abs(s.gamma - props.GAMMA_BEFORE_1) < 1e-7
    assert s.settings_version == props.SETTINGS_VERSION
    assert np.array_equal(coords(obj, "LARAP"), pose)
    from larap_blender import solving
    assert solving.key_up_to_date(obj)  # the saved pose's digest still matches: no re-solve
    activate(obj)
    assert bpy.ops.larap.solve() == {"FINISHED"}
    assert np.abs(coords(obj, "LARAP") - pose).max() < 1e-4 * diagonal(rest)

    # Undo to a step stored before the upgrade: the panel shows the old value again at once.
    bpy.ops.ed.undo_push(message="upgraded")
    s.property_unset("gamma")
    s.property_unset("settings_version")
    bpy.ops.ed.undo_push(message="as an older version stored it")
    s.iterations = 7
    bpy.ops.ed.undo_push(message="a later step")
    assert bpy.ops.ed.undo() == {"FINISHED"}
    s = bpy.data.objects["Bar"].larap
    assert abs(s.gamma - props.GAMMA_BEFORE_1) < 1e-7 and s.settings_version == props.SETTINGS_VERSION

    # Settings no update has reached yet: the engine is given the old value when it is built,
    # and the settings are upgraded then.
    from larap_blender import core as core2
    obj = bpy.data.objects["Bar"]
    s = obj.larap
    s.property_unset("gamma")
    s.property_unset("settings_version")
    core2.drop_runtime(obj)
    activate(obj)
    assert bpy.ops.larap.solve() == {"FINISHED"}
    assert abs(s.gamma - props.GAMMA_BEFORE_1) < 1e-7 and s.settings_version == props.SETTINGS_VERSION
    assert abs(core2.runtime(obj).deformer.gamma - props.GAMMA_BEFORE_1) < 1e-7
    assert np.abs(coords(obj, "LARAP") - pose).max() < 1e-4 * diagonal(rest)


def test_an_object_appended_from_an_older_file_keeps_its_stiffness(core, tmp_path):
    """Append runs no load_post: the depsgraph update that reports the new object upgrades it,
    before anything is solved or drawn."""
    from larap_blender import props
    path, pose, rest = _old_file(core, tmp_path)
    bpy.ops.wm.read_factory_settings(use_empty=True)
    from conftest import enable_addon
    enable_addon()
    with bpy.data.libraries.load(path, link=False) as (src, dst):
        dst.objects = ["Bar"]
    obj = dst.objects[0]
    assert obj.larap.bound and obj.larap.settings_version == 0
    bpy.context.scene.collection.objects.link(obj)
    bpy.context.view_layer.update()
    s = obj.larap
    assert abs(s.gamma - props.GAMMA_BEFORE_1) < 1e-7 and s.settings_version == props.SETTINGS_VERSION


def test_a_new_binds_stiffness_is_stored(core, tmp_path):
    """Bind stores the Stiffness it bound with (the current default here), so a file of this
    version keeps it across save and reload, and a later change of the default."""
    from larap_blender import props
    obj, *_ = bar_with_handles(core)
    assert obj.larap.is_property_set("gamma")
    path = str(tmp_path / "new.blend")
    bpy.ops.wm.save_as_mainfile(filepath=path)
    s = _reload(path).larap
    assert s.is_property_set("gamma") and abs(s.gamma - props.GAMMA) < 1e-7
    assert s.settings_version == props.SETTINGS_VERSION


def test_the_panels_default_stiffness_is_the_engines(core):
    """The add-on's Stiffness default (props.GAMMA, needed before the engine loads) is the
    engine's own default."""
    import larap
    from larap_blender import props
    assert props.GAMMA == larap.DEFAULT_GAMMA
    assert abs(props.LARAP_PG_settings.bl_rna.properties["gamma"].default - larap.DEFAULT_GAMMA) < 1e-7
