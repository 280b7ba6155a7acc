# SPDX-License-Identifier: GPL-3.0-or-later
"""Load farm bake: play a merged PC2 cache (``python3 -m larap.farm``, docs/farm.md) through
Blender's own Mesh Cache modifier, so the shot plays without LARAP.

The modifier (named MODIFIER_NAME, added once and updated after) goes first in the stack, reads
frames from the cache's start frame, and overwrites the positions; the object's live LARAP pose is
switched off and its pose key muted, so nothing solves or adds on top of the cache.
"""
import json
import os

import bpy
from bpy.props import StringProperty

from . import core, engine
from .operators import _LarapOp

MODIFIER_NAME = "LARAP Farm Bake"
SUMMARY = "bake.json"  # written by larap.farm.merge next to the merged caches


def _pc2():
    if engine.get() is None:
        raise core.LarapError(engine.error())
    from larap.farm import pc2
    return pc2


def cache_header(path):
    """The PC2 header of ``path`` (points, start, rate, samples); LarapError when it is not a complete cache."""
    pc2 = _pc2()
    try:
        return pc2.read_pc2_header(bpy.path.abspath(path))
    except pc2.PC2Error as exc:
        raise core.LarapError(str(exc)) from None


def load_farm_bake(obj, path):
    """Add or update ``obj``'s Mesh Cache modifier to play the PC2 cache at ``path``; returns it."""
    core.check_object(obj)
    head = cache_header(path)
    n = len(obj.data.vertices)
    if head["points"] != n:
        raise core.LarapError("%s holds %d vertices per frame, %r has %d: not a bake of this mesh"
                              % (os.path.basename(path), head["points"], obj.name, n))
    mod = obj.modifiers.get(MODIFIER_NAME)
    if mod is not None and mod.type != "MESH_CACHE":
        raise core.LarapError("%r has a %s modifier named %r; rename it first" % (obj.name, mod.type, MODIFIER_NAME))
    if mod is None:
        mod = obj.modifiers.new(MODIFIER_NAME, "MESH_CACHE")
    mod.cache_format = "PC2"
    mod.filepath = path
    mod.time_mode = "FRAME"
    mod.play_mode = "SCENE"
    mod.deform_mode = "OVERWRITE"
    mod.interpolation = "LINEAR"
    mod.forward_axis, mod.up_axis = "POS_Y", "POS_Z"  # object-local coordinates as written
    mod.flip_axis = set()
    mod.factor = 1.0
    mod.frame_start = head["start"]
    mod.frame_scale = 1.0 / head["rate"] if head["rate"] > 0 else 1.0
    if obj.modifiers[0] != mod:
        with bpy.context.temp_override(object=obj, active_object=obj):
            bpy.ops.object.modifier_move_to_index(modifier=mod.name, index=0)
    s = obj.larap
    s.live = False
    keys = obj.data.shape_keys
    kb = keys.key_blocks.get(s.shape_key) if keys is not None and s.bound else None
    if kb is not None:
        kb.mute = True
    obj.data.update_tag()
    return mod


def load_bake_summary(path):
    """{object name: cache path} from a bake folder's bake.json (or the folder itself)."""
    if os.path.isdir(path):
        path = os.path.join(path, SUMMARY)
    try:
        with open(path, "r", encoding="utf-8") as f:
            doc = json.load(f)
        folder = os.path.dirname(os.path.abspath(path))
        return {name: os.path.join(folder, e["file"]) for name, e in doc["objects"].items()}
    except (OSError, ValueError, KeyError, TypeError, AttributeError) as exc:
        raise core.LarapError("%s is not a farm bake summary (%s)" % (path, exc)) from None


class LARAP_OT_load_farm_bake(_LarapOp, bpy.types.Operator):
    """Play a farm bake with Blender's Mesh Cache modifier: a .pc2 for the active mesh, or a bake folder's bake.json for every object it names"""
    bl_idname = "larap.load_farm_bake"
    bl_label = "LARAP Load Farm Bake"

    filepath: StringProperty(name="Cache", subtype="FILE_PATH",
                             description="A merged .pc2 cache, or bake.json (every baked object of the file)")
    filter_glob: StringProperty(default="*.pc2;*.json", options={"HIDDEN"})

    def invoke(self, context, event):
        context.window_manager.fileselect_add(self)
        return {"RUNNING_MODAL"}

    def run(self, context, obj):
        path = bpy.path.abspath(self.filepath)
        if not self.filepath:
            raise core.LarapError("No cache file given")
        if path.lower().endswith(".json") or os.path.isdir(path):
            loaded, missing = [], []
            for name, cache in load_bake_summary(path).items():
                target = bpy.data.objects.get(name)
                if target is None:
                    missing.append(name)
                    continue
                load_farm_bake(target, cache)
                loaded.append(name)
            if missing:
                self.report({"WARNING"}, "Not in this file (skipped): %s" % ", ".join(missing))
            if not loaded:
                raise core.LarapError("None of the baked objects is in this file")
            self.report({"INFO"}, "Farm bake on %s" % ", ".join(loaded))
            return
        mod = load_farm_bake(obj, path)
        self.report({"INFO"}, "%r plays %s from frame %g" % (obj.name, os.path.basename(path), mod.frame_start))


classes = (LARAP_OT_load_farm_bake,)
