# SPDX-License-Identifier: GPL-3.0-or-later
"""Renders the report's pictures with Blender's Workbench engine, headless:

  blender -b --factory-startup --python-exit-code 1 --python scripts/report/render_scenes.py -- SCENES.json

SCENES.json: a list of pictures, each {"out": PNG, "objects": [{"rest": NPZ with X, offsets,
indices (the faces), "pose": NPZ with X or null, "offset": [x, y, z], "color": [r, g, b],
"rotate_z": degrees}], "view": [dx, dy, dz] (camera direction towards the scene), "zoom": 1.0,
"size": [w, h], "focus": [[xmin, ymin, zmin], [xmax, ymax, zmax]] (optional: frame this box)}.
A picture that fails is reported on stdout and skipped; the others still render."""
import json
import os
import sys
import traceback

import bpy
import numpy as np
from mathutils import Matrix, Vector

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))  # scripts/
from blender_mesh import mesh_object  # noqa: E402


def colored_mesh(name, X, offsets, indices, color):
    ob = mesh_object(name, X, offsets, indices, smooth=True)
    mat = bpy.data.materials.new(name)
    mat.diffuse_color = (*color, 1.0)
    ob.data.materials.append(mat)
    return ob


def render(spec):
    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene
    lo, hi = np.full(3, np.inf), np.full(3, -np.inf)
    for k, o in enumerate(spec["objects"]):
        rest = np.load(o["rest"])
        X = np.load(o["pose"])["X"] if o.get("pose") else rest["X"]
        X = X.astype(np.float64)
        if o.get("rotate_z"):
            t = np.radians(o["rotate_z"])
            R = np.array([[np.cos(t), -np.sin(t), 0], [np.sin(t), np.cos(t), 0], [0, 0, 1]])
            X = X @ R.T
        X = X + np.asarray(o.get("offset", (0, 0, 0)), float)
        colored_mesh("obj%d" % k, X, rest["offsets"], rest["indices"], o.get("color", (0.8, 0.8, 0.8)))
        lo, hi = np.minimum(lo, X.min(0)), np.maximum(hi, X.max(0))
    if spec.get("focus"):
        lo, hi = np.asarray(spec["focus"][0], float), np.asarray(spec["focus"][1], float)
    view = np.asarray(spec.get("view", (0.0, 1.0, -0.45)), float)
    view /= np.linalg.norm(view)
    cam = bpy.data.objects.new("cam", bpy.data.cameras.new("cam"))
    cam.data.type = "ORTHO"
    scene.collection.objects.link(cam)
    back = -view  # the camera looks down its -z; world z is up unless we look along it (then world y)
    up_world = np.array([0.0, 0.0, 1.0]) if abs(view[2]) < 0.9 else np.array([0.0, 1.0, 0.0])
    right = np.cross(up_world, back)
    right /= np.linalg.norm(right)
    R = np.stack([right, np.cross(back, right), back], 1)  # columns: camera x (right), y (up), z (back)
    rot = Matrix(R.tolist())
    corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
    local = corners @ R  # coordinates along the camera's axes
    w, h = spec.get("size", (960, 540))
    ext_x, ext_y = np.ptp(local[:, 0]), np.ptp(local[:, 1])
    cam.data.ortho_scale = 1.08 * max(ext_x, ext_y * w / h) * spec.get("zoom", 1.0)
    mid = np.array([local[:, 0].mean(), local[:, 1].mean(), local[:, 2].max() + np.ptp(local[:, 2]) + 1.0])
    cam.location = Vector((R @ mid).tolist())
    cam.rotation_euler = rot.to_euler()
    cam.data.clip_end = 10 * (np.ptp(local[:, 2]) + 10)
    scene.camera = cam
    scene.render.engine = "BLENDER_WORKBENCH"
    scene.display.shading.light = "STUDIO"
    scene.display.shading.color_type = "MATERIAL"
    scene.display.shading.show_cavity = False
    scene.display.shading.show_specular_highlight = True
    scene.render.resolution_x, scene.render.resolution_y = w, h
    scene.render.film_transparent = False
    scene.render.filepath = spec["out"]
    bpy.ops.render.render(write_still=True)


def main():
    specs = json.load(open(sys.argv[sys.argv.index("--") + 1]))
    for spec in specs:
        try:
            render(spec)
            print("rendered", spec["out"])
        except Exception:
            print("FAILED", spec.get("out"), traceback.format_exc())


main()
