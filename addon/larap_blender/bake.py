# SPDX-License-Identifier: GPL-3.0-or-later
"""Baking poses into shape keys, and what a bake leaves behind.

* :func:`bake_shape_key`: the current pose as one new key.
* :func:`bake_animation` / :class:`AnimationBake`: one solve and one key per frame, as steps an
  operator can show progress between and cancel (Esc) with everything put back.
* The aftermath: the baked keys play, the pose key is hidden and Live paused (:func:`is_baked`,
  :func:`pose_key_hidden`); :func:`remove_bake` takes it all away in one step.

Scripts and tests reach these through ``core`` too (``core.bake_animation``, ...).
"""
import contextlib

from .errors import LarapError, check_object
from .handlers import suspend_live
from .mesh_data import write_key
from .progress import progress as _progress
from .runtime import runtime
from .solving import current_pose, solve
from .transaction import key_positions as snapshot_key, preserve_on_error

__all__ = ["bake_shape_key", "bake_animation", "AnimationBake", "LarapCancelled", "is_baked", "pose_key_hidden",
           "remove_bake"]


def bake_shape_key(obj, name="LARAP_pose", *, overwrite=False):
    """Store the current pose (see current_pose) as a new key (value 0) relative to Basis.
    An existing key of that name is replaced only with ``overwrite``."""
    check_object(obj, need_bound=True)
    keys = obj.data.shape_keys
    if not name:
        raise LarapError("Give the baked shape key a name")
    if name == obj.larap.shape_key or (keys is not None and keys.reference_key and name == keys.reference_key.name):
        raise LarapError("Choose a name other than %r" % name)
    if keys is not None and name in keys.key_blocks and not overwrite:
        raise LarapError("Shape key %r exists; choose another name or enable Overwrite" % name)
    existed = keys is not None and name in keys.key_blocks
    with preserve_on_error(obj) as snap:
        # The pose key and the rest shape as the snapshot read them: current_pose and its solve do
        # not read them again.
        pose = current_pose(obj, snapshot_key(snap, obj.larap.shape_key), snap["rest"])
        keys = obj.data.shape_keys
        if not existed and name in keys.key_blocks:
            # The catch-up kept hand edits of the pose key under this very name (key_edits.keep):
            # writing the pose there would lose them. Raising puts everything back as it was.
            raise LarapError("%r is the name LARAP gives the copy of hand edits to its pose key; choose "
                             "another name" % name)
        kb = write_key(obj, name, pose)
        kb.value = 0.0
    return kb


def _set_linear(key, data_path):
    ad = key.animation_data
    if ad is None or ad.action is None:
        return
    fc = ad.action.fcurves.find(data_path)
    if fc is not None:
        for kp in fc.keyframe_points:
            kp.interpolation = "LINEAR"


def bake_animation(obj, scene, frame_start, frame_end, *, step=1, prefix="LARAP_", overwrite=False,
                   progress=None):
    """One solve per frame from the animated targets (warm-started), each pose a key named
    ``<prefix><frame:04d>`` keyed to 1 on its frame and 0 on the neighbouring baked frames.
    Afterwards the baked keys play the animation: the live pose key is hidden (value 0, so it does
    not add to them) and Live is paused; :func:`remove_bake` undoes both. Existing keys of those
    names are replaced only with ``overwrite``; a failure part-way leaves the keys as they were.
    ``progress``: a Progress (one step per frame). Returns the key names."""
    job = AnimationBake(obj, scene, frame_start, frame_end, step=step, prefix=prefix, overwrite=overwrite)
    p = _progress(progress, len(job.frames))
    with p:
        job.begin()
        while not job.step():
            p.step(job.done)
        p.step(job.done)
        return job.finish()


class LarapCancelled(LarapError):
    """The artist cancelled a long operation (Esc): everything was put back."""


class AnimationBake:
    """Bake Animation as steps of one frame, so an operator can show progress between them and
    cancel (Esc) with everything put back: ``begin()``, ``step()`` until it returns True,
    ``finish()``; or ``cancel()`` at any point. A step that raises puts everything back too."""

    def __init__(self, obj, scene, frame_start, frame_end, *, step=1, prefix="LARAP_", overwrite=False):
        check_object(obj, need_bound=True)
        if frame_end < frame_start:
            raise LarapError("Frame range is empty (%d..%d)" % (frame_start, frame_end))
        self.obj, self.scene, self.prefix = obj, scene, prefix
        self.step_size = max(1, int(step))
        self.frames = list(range(int(frame_start), int(frame_end) + 1, self.step_size))
        keys = obj.data.shape_keys
        wanted = ["%s%04d" % (prefix, f) for f in self.frames]
        if keys is not None:
            taken = [nm for nm in wanted if nm in keys.key_blocks]
            protected = {obj.larap.shape_key, keys.reference_key.name if keys.reference_key else ""}
            if any(nm in protected for nm in wanted):
                raise LarapError("The prefix %r would overwrite the Basis or pose key; choose another" % prefix)
            if taken and not overwrite:
                raise LarapError("Shape keys %s exist; choose another prefix or enable Overwrite"
                                 % ", ".join(repr(nm) for nm in taken[:3]) + (" ..." if len(taken) > 3 else ""))
        self.names = []
        self.done = 0
        self._stack = None

    def begin(self):
        obj, scene = self.obj, self.scene
        keys = obj.data.shape_keys
        self.had_action = bool(keys and keys.animation_data and keys.animation_data.action)
        self.old_frame = (scene.frame_current, scene.frame_subframe)
        self._stack = contextlib.ExitStack()
        self._stack.enter_context(preserve_on_error(obj))
        self._stack.enter_context(suspend_live())
        return self

    def step(self):
        """Bake the next frame; True when every frame is baked."""
        if self.done >= len(self.frames):
            return True
        try:
            self._bake_frame(self.frames[self.done])
        except BaseException as exc:
            self._abort(exc)
            raise
        self.done += 1
        return self.done >= len(self.frames)

    def _bake_frame(self, f):
        obj, step = self.obj, self.step_size
        self.scene.frame_set(f)
        solve(obj, weights="final", validate="full" if self.done == 0 else "fast")
        name = "%s%04d" % (self.prefix, f)
        kb = write_key(obj, name, runtime(obj).out)
        keys = obj.data.shape_keys
        path = 'key_blocks["%s"].value' % name
        ad = keys.animation_data
        if ad is not None and ad.action is not None:
            fc = ad.action.fcurves.find(path)
            if fc is not None:
                ad.action.fcurves.remove(fc)
        for frame, value in ((f - step, 0.0), (f, 1.0), (f + step, 0.0)):
            kb.value = value
            kb.keyframe_insert("value", frame=frame)
        _set_linear(keys, path)
        self.names.append(name)

    def _restore_frame(self):
        self.scene.frame_set(self.old_frame[0], subframe=self.old_frame[1])

    def _abort(self, exc):
        stack, self._stack = self._stack, None
        if stack is None:
            return
        try:
            self._restore_frame()
        finally:
            stack.__exit__(type(exc), exc, exc.__traceback__)  # puts the keys back; does not raise

    def cancel(self):
        """Put everything back as before begin() (Esc)."""
        self._abort(LarapCancelled("Bake cancelled"))

    def finish(self):
        """The aftermath, said in the data: the baked keys play, the pose key is hidden, Live paused."""
        obj = self.obj
        s = obj.larap
        try:
            self._restore_frame()
            keys = obj.data.shape_keys
            pose = keys.key_blocks.get(s.shape_key)
            if pose is not None:
                pose.value = 0.0
            recorded = {item.name for item in s.bake_keys}
            for name in self.names:
                if name not in recorded:
                    s.bake_keys.add().name = name
            if s.live:
                s.bake_paused_live = True
                s.live = False
            action = keys.animation_data.action if keys.animation_data else None
            if not self.had_action and action is not None and not s.bake_created_action:
                s.bake_created_action = action.name
            obj.data.update_tag()
        except BaseException as exc:
            self._abort(exc)
            raise
        stack, self._stack = self._stack, None
        stack.close()
        return list(self.names)


def is_baked(obj):
    """Bake Animation's keys are on the object (Remove Bake takes them away)."""
    return len(obj.larap.bake_keys) > 0


def pose_key_hidden(obj):
    """The pose key exists but does not show (value 0 or muted): what Live and Solve write is not seen."""
    keys = obj.data.shape_keys
    kb = keys.key_blocks.get(obj.larap.shape_key) if keys is not None else None
    return kb is not None and (kb.value == 0.0 or kb.mute)


def remove_bake(obj):
    """Remove what Bake Animation made, in one step: its shape keys and their animation (the
    f-curves; the action too when the bake created it and nothing else is left in it), show the
    pose key again and resume Live if the bake paused it. Keys LARAP did not bake are kept."""
    check_object(obj)
    s = obj.larap
    if not is_baked(obj):
        raise LarapError("%r has no baked animation to remove" % obj.name)
    with preserve_on_error(obj):
        names = [item.name for item in s.bake_keys]
        keys = obj.data.shape_keys
        removed = 0
        if keys is not None:
            ad = keys.animation_data
            action = ad.action if ad is not None else None
            for name in names:
                if action is not None:
                    fc = action.fcurves.find('key_blocks["%s"].value' % name)
                    if fc is not None:
                        action.fcurves.remove(fc)
                kb = keys.key_blocks.get(name)
                if kb is not None and kb != keys.reference_key and kb.name != s.shape_key:
                    obj.shape_key_remove(kb)
                    removed += 1
            keys = obj.data.shape_keys
            if (action is not None and keys is not None and keys.animation_data is not None
                    and action.name == s.bake_created_action and len(action.fcurves) == 0):
                keys.animation_data.action = None  # left without users: Blender drops it on save
            pose = keys.key_blocks.get(s.shape_key) if keys is not None else None
            if pose is not None and pose.value == 0.0:
                pose.value = 1.0
        s.bake_keys.clear()
        s.bake_created_action = ""
        if s.bake_paused_live:
            s.bake_paused_live = False
            s.live = True
        obj.data.update_tag()
    return removed
