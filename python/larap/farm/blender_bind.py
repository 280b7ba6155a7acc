"""The bake's optional first task: bind objects at a frame and save the file the chunks open.

    blender -b --factory-startup SHOT.blend --python-exit-code 1 --python .../larap/farm/blender_bind.py -- \\
        --object Body --frame 1 --save-as BAKE_DIR/bound.blend [--rebind] [--addon-path DIR]

Objects already bound are kept as they are unless ``--rebind`` (binding makes the targets'
transforms at ``--frame`` their rest). The copy is saved under a temporary name and renamed; the
artist's file is never written.
"""
from __future__ import annotations

import argparse
import os
import sys

if __name__ == "__main__" and __package__ in (None, ""):
    sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__)))))

from larap.farm._blender import enable_addon, find_objects, script_argv  # noqa: E402
from larap.farm.pc2 import temp_name  # noqa: E402


def main(argv=None):
    p = argparse.ArgumentParser(prog="blender_bind.py", description="Bind objects and save a copy (inside Blender)")
    p.add_argument("--object", action="append", required=True)
    p.add_argument("--frame", type=int, required=True, help="frame whose target transforms become rest")
    p.add_argument("--save-as", required=True, help="the bound copy (.blend) the chunks open")
    p.add_argument("--rebind", action="store_true", help="bind objects that are already bound again")
    p.add_argument("--addon-path", default="")
    args = p.parse_args(script_argv(argv))
    import bpy
    core = enable_addon(args.addon_path)
    target = os.path.abspath(args.save_as)
    if os.path.abspath(bpy.data.filepath) == target:
        raise ValueError("--save-as must differ from the open file (the artist's file is never written)")
    objs = find_objects(args.object)
    bpy.context.scene.frame_set(args.frame)
    for obj in objs:
        if obj.larap.bound and not args.rebind:
            print(f"larap-farm bind: {obj.name} already bound (kept)", flush=True)
            continue
        result = core.bind(obj)
        print(f"larap-farm bind: {obj.name} bound at frame {args.frame} ({result.ms:.0f} ms)", flush=True)
    os.makedirs(os.path.dirname(target) or ".", exist_ok=True)
    tmp = temp_name(target) + ".blend"
    bpy.ops.wm.save_as_mainfile(filepath=tmp, copy=True, compress=False)
    os.replace(tmp, target)
    print(f"larap-farm bind: saved {target}", flush=True)


if __name__ == "__main__":
    main()
