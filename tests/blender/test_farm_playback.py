# SPDX-License-Identifier: GPL-3.0-or-later
# Run: blender -b --factory-startup --python-exit-code 1 --python tests/blender/run_tests.py -- tests/blender/test_farm_playback.py
# A chunk baked in this Blender (larap.farm.blender_chunk.bake_chunk), written as PC2, played back by
# the Mesh Cache modifier that "Load Farm Bake" sets up, also after the add-on is disabled.
import json
import os

import bpy
import numpy as np
import pytest

from conftest import bar_with_handles, diagonal, disable_addon, evaluated_coords


def _animated_bar(core):
    obj, rest, left, right, targets = bar_with_handles(core)
    e = targets[1]
    z0 = e.location.z
    for f, dz, rx in ((1, 0.0, 0.0), (8, 1.0, 0.8)):
        e.location.z = z0 + dz
        e.rotation_euler.x = rx
        e.keyframe_insert("location", frame=f)
        e.keyframe_insert("rotation_euler", frame=f)
    return obj, rest, right


def _bake(core, obj, first, last):
    from larap.farm.blender_chunk import bake_chunk
    from larap.farm.plan import BakeJob, Chunk
    job = BakeJob(blend="", objects=[obj.name], frame_start=first, frame_end=last, out_dir="", chunk_size=99)
    positions, timing = bake_chunk(core, bpy.context.scene, [obj], job, Chunk(first, last, first))
    return positions[obj.name], timing


def test_mesh_cache_plays_the_bake(core, tmp_path):
    from larap.farm.pc2 import write_pc2
    from larap_blender.farm import MODIFIER_NAME
    obj, rest, right = _animated_bar(core)
    scene = bpy.context.scene
    P, timing = _bake(core, obj, 2, 7)
    assert P.shape == (6, len(rest), 3) and timing["frames_solved"] == 6
    diag = diagonal(rest)
    rises = P[:, right, 2].mean(axis=1) - rest[right, 2].mean()
    assert np.all(np.diff(rises) > 0.05) and 0.5 < rises[-1] < 1.0  # the handle rises frame after frame
    path = str(tmp_path / "Bar.pc2")
    write_pc2(path, P, 2)
    obj.modifiers.new("Keep", "DISPLACE").strength = 0.0  # an artist's modifier: the cache goes before it
    obj.larap.live = True
    assert bpy.ops.larap.load_farm_bake(filepath=path) == {"FINISHED"}
    mods = list(obj.modifiers)
    assert [m.name for m in mods] == [MODIFIER_NAME, "Keep"]
    mc = mods[0]
    assert mc.type == "MESH_CACHE" and mc.cache_format == "PC2" and mc.frame_start == 2.0
    assert obj.larap.live is False
    assert obj.data.shape_keys.key_blocks[obj.larap.shape_key].mute is True
    for f in (2, 4, 7):
        scene.frame_set(f)
        assert np.abs(evaluated_coords(obj) - P[f - 2]).max() < 1e-6 * diag, f
    # Loading again updates the same modifier.
    assert bpy.ops.larap.load_farm_bake(filepath=path) == {"FINISHED"}
    assert [m.type for m in obj.modifiers].count("MESH_CACHE") == 1
    # The shot plays without LARAP.
    disable_addon()
    assert not hasattr(bpy.types.Object, "larap")
    scene.frame_set(6)
    assert np.abs(evaluated_coords(obj) - P[4]).max() < 1e-6 * diag


def test_load_farm_bake_rejects_bad_caches(core, tmp_path):
    from larap.farm.pc2 import write_pc2
    obj, rest, right = _animated_bar(core)
    with pytest.raises(RuntimeError, match="no such file"):
        bpy.ops.larap.load_farm_bake(filepath=str(tmp_path / "missing.pc2"))
    other = str(tmp_path / "other.pc2")
    write_pc2(other, np.zeros((3, 10, 3), np.float32), 1)
    with pytest.raises(RuntimeError, match="not a bake of this mesh"):
        bpy.ops.larap.load_farm_bake(filepath=other)
    good = str(tmp_path / "Bar.pc2")
    write_pc2(good, np.repeat(rest[None].astype(np.float32), 4, axis=0), 1)
    with open(good, "r+b") as f:
        f.truncate(os.path.getsize(good) - 12)
    with pytest.raises(RuntimeError, match="truncated"):
        bpy.ops.larap.load_farm_bake(filepath=good)
    assert not any(m.type == "MESH_CACHE" for m in obj.modifiers)


def test_load_farm_bake_summary_names_objects(core, tmp_path):
    from larap.farm.pc2 import write_pc2
    obj, rest, right = _animated_bar(core)
    write_pc2(str(tmp_path / "Bar.pc2"), np.repeat(rest[None].astype(np.float32), 3, axis=0), 5)
    summary = {"frames": [5, 7], "objects": {"Bar": {"file": "Bar.pc2"}, "Ghost": {"file": "Ghost.pc2"}}}
    (tmp_path / "bake.json").write_text(json.dumps(summary))
    assert bpy.ops.larap.load_farm_bake(filepath=str(tmp_path / "bake.json")) == {"FINISHED"}
    assert obj.modifiers[0].type == "MESH_CACHE" and obj.modifiers[0].frame_start == 5.0
