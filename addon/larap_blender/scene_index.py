# SPDX-License-Identifier: GPL-3.0-or-later
"""What the add-on asks of the whole file at every move, answered without looking at every object.

Live posing asks, at each depsgraph update, which bound meshes a scene holds; every handle asks
whether its target is still in a scene; the preview asks whether a mesh is in the view layer and
draws the bound meshes it shows; the sidebar asks which meshes an active target drives. Read from
Blender directly, each answer costs time in proportion to the objects of the file
(``scene.objects``, ``Object.users_scene``, which in Blender 3.4 is Python listing every object of
every scene, ``view_layer.objects``, ``bpy.data.objects``). With 20,000 objects the add-on's
depsgraph handler took 13 ms for the move of an unrelated Empty and 48-50 ms for a handle's Empty
(docs/results-blender.md, scripts/bench_scene_size.py). Here the answers are kept between updates:

* :func:`bound_meshes`: the bound mesh objects of a scene, or of the file (all, live or not);
* :func:`target_alive`: whether an object is in some scene (a deleted target is kept as an orphan
  by the handle's pointer and is in none);
* :func:`in_view_layer`: whether an object has a base in a view layer;
* :func:`in_visible_collection`: whether one of its collections is shown in a view layer (the
  preview's draw asks it at every redraw).

They are forgotten (:func:`invalidate`) whenever what they depend on may have changed: Blender
reports a Scene or Collection among the IDs of an update whenever an object is linked or unlinked,
deleted, duplicated or added, a collection is linked, unlinked or excluded (checked for each of
these on Blender 3.4.1; the depsgraph handler calls :func:`note_updated`, the frame-change handler
:func:`note_evaluated`, which also sees Scene > New > Full Copy), when the add-on or a script
binds or unbinds a mesh (the ``bound`` property's update), and entirely (:func:`forget_all`)
before and after an undo, a redo or a file load. A selection click and a frame step by the frame
operators (arrow keys, the timeline; not playback or ``scene.frame_set``) report the Scene too, so
the next move reads the lists again (about 1.4 ms for a scene's bound meshes and 2-4 ms per handle
target at 20,000 objects). As a net for a change made some other way (another
add-on's handler, a script writing ``bound`` as an ID property), nothing is kept longer than
:data:`MAX_AGE` seconds while it is being read, and a mesh that a list finds for the first time
is looked at by Live at the next update whatever that update reported (:func:`take_new`): such a
change shows at the first update after that second. Where a kept answer would be the reason to
drop something (the catch-up deciding that a pending mesh is gone, the runtime cache pruned), the
caller reads the file again first. The lists' object references are held until the next
invalidation, and the last list's per scene (compared by identity only, never read) until an
undo, redo or load; a reference to an object removed since raises ReferenceError, which every
reader catches. An entry is used only for the very object, scene or view layer it was made for
(a freed address is soon reused).
"""
import time

import bpy

MAX_AGE = 1.0  # seconds a cached answer is trusted without another reason to look again

_GENERATION = [0]
# Each kept answer: key -> (generation, time, owners, answer); the owners (objects and scenes by
# identity, names by value) are what the answer was read for, since a freed address is soon reused.
_BOUND = {}     # scene pointer (0: the file) -> the bound mesh objects
_ALIVE = {}     # object pointer -> whether it is in some scene
_IN_LAYER = {}  # (view layer pointer, object pointer) -> whether it has a base in the view layer
_SHOWN_IN = {}  # (view layer pointer, object pointer) -> whether a collection holding it is shown there
_SEEN = {}      # scene pointer -> (the scene, {object pointer: object} of its last list read)
_NEW = {}       # scene pointer -> pointers of meshes the lists read since the last take_new lacked before


def invalidate(*_args):
    """Something the answers depend on may have changed: read Blender again at the next question.
    Usable as a handler."""
    _GENERATION[0] += 1
    _BOUND.clear()
    _ALIVE.clear()
    _IN_LAYER.clear()
    _SHOWN_IN.clear()


def forget_all(*_args):
    """Undo, redo, a file load: the objects themselves are replaced; even which meshes were seen
    before is forgotten (every bound mesh is new to the next list)."""
    invalidate()
    _SEEN.clear()
    _NEW.clear()


def note_updated(idd):
    """From depsgraph_update_post, for each ID it reports: a Scene or Collection (objects linked,
    unlinked, added, deleted; collections linked, unlinked, excluded; also a selection click or a
    frame step, which report the Scene) makes every answer stale."""
    if isinstance(idd, (bpy.types.Scene, bpy.types.Collection)):
        invalidate()


def note_evaluated(depsgraph):
    """From frame_change_post: the same for what a frame's evaluation reports, asked by type
    (walking ``depsgraph.updates`` at every frame of playback costs a millisecond at 20,000
    objects; asking costs microseconds)."""
    try:
        if depsgraph.id_type_updated("SCENE") or depsgraph.id_type_updated("COLLECTION"):
            invalidate()
    except (ReferenceError, TypeError):
        invalidate()


def _kept(store, key, owners, read):
    """The answer kept in ``store[key]`` for these ``owners`` while it is fresh (this generation,
    at most MAX_AGE old), or ``read()``, kept now. (``type``, not ``isinstance``: the latter
    reads ``__class__``, which raises ReferenceError on a removed object.)"""
    entry = store.get(key)
    if (entry is not None and entry[0] == _GENERATION[0] and time.monotonic() - entry[1] <= MAX_AGE
            and all(a is b or (type(a) is str and a == b) for a, b in zip(entry[2], owners))):
        return entry[3]
    answer = read()
    store[key] = (_GENERATION[0], time.monotonic(), owners, answer)
    return answer


def bound_meshes(scene):
    """The bound mesh objects of ``scene`` (None: of the whole file), in the order Blender lists
    them. A reader must catch ReferenceError (an object removed since the list was made)."""
    key = scene.as_pointer() if scene is not None else 0
    return _kept(_BOUND, key, (scene,), lambda: _read_bound(scene, key))


def _read_bound(scene, key):
    found = []
    for obj in (scene.objects if scene is not None else bpy.data.objects):
        try:
            if obj.type == "MESH" and obj.larap.bound:
                found.append(obj)
        except ReferenceError:
            continue
    if scene is not None:  # what this list has that the scene's last one lacked
        owner, seen = _SEEN.get(key, (None, {}))
        if owner is not scene:
            seen = {}
        now = {obj.as_pointer(): obj for obj in found}
        _NEW.setdefault(key, set()).update(p for p, obj in now.items() if seen.get(p) is not obj)
        _SEEN[key] = (scene, now)
    return found


def take_new(scene):
    """Pointers of the bound meshes of ``scene`` that the lists read since the last call found
    and the list before them lacked (a mesh linked, bound or duplicated in a way no update
    reported): Live looks at these whatever the update reported. Clears them."""
    return _NEW.pop(scene.as_pointer(), set())


def target_alive(target):
    """Whether ``target`` (an object, or None) exists and is in some scene."""
    if target is None:
        return False
    try:
        # Object.users_scene lists every object of every scene (Python in Blender 3.4: 2-4 ms at
        # 20,000 objects); users_collection, which could answer too, walks every collection's
        # objects in Python and costs more in files of many collections.
        return _kept(_ALIVE, target.as_pointer(), (target,), lambda: len(target.users_scene) > 0)
    except ReferenceError:
        return False


def in_view_layer(obj, view_layer):
    """Whether ``obj`` has a base in ``view_layer`` (is in one of its collections that is not
    excluded)."""
    if view_layer is None:
        return False

    def read():
        found = view_layer.objects.get(obj.name)
        # (a linked object of the same name may be the one found by name)
        return found == obj or (found is not None and obj in view_layer.objects[:])
    try:
        # A view layer has no lasting Python object to compare: its scene and name stand for it.
        return _kept(_IN_LAYER, (view_layer.as_pointer(), obj.as_pointer()),
                     (obj, view_layer.id_data, view_layer.name), read)
    except ReferenceError:
        return False


def in_visible_collection(obj, view_layer):
    """Whether a collection holding ``obj`` is visible in ``view_layer`` and not excluded there
    (its eye, its Disable in Viewports and its parents' taken into account; the object's own
    hiding is not asked). Hiding, showing or excluding a collection reports the Scene (checked on
    Blender 3.4.1), which makes the kept answer stale."""
    if view_layer is None:
        return False

    def read():
        # Walks the view layer's collections asking each by name (in C), instead of
        # Object.users_collection, which is Python listing every object of every collection:
        # 1.2 against 0.8 ms with 20,000 objects in one collection, 16-50 against 7-8 ms with one
        # collection per object (Blender 3.4.1, this machine).
        name = obj.name
        stack = [view_layer.layer_collection]
        while stack:
            lc = stack.pop()
            if lc.is_visible and not lc.exclude:
                objects = lc.collection.objects
                found = objects.get(name)
                # (a linked object of the same name may be the one found by name)
                if found is not None and (found == obj or obj in objects[:]):
                    return True
            stack.extend(lc.children)
        return False
    try:
        return _kept(_SHOWN_IN, (view_layer.as_pointer(), obj.as_pointer()),
                     (obj, view_layer.id_data, view_layer.name), read)
    except ReferenceError:
        return False
