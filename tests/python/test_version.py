# Run: PYTHONPATH=python /usr/bin/python3 -m pytest tests/python/test_version.py
"""The version is written once (CMakeLists.txt); the module reports it, and the add-on's two
literals that Blender reads without running code (bl_info, blender_manifest.toml) agree."""
import ast
import os
import re

import larap
from conftest import REPO


def cmake_version():
    text = open(os.path.join(REPO, "CMakeLists.txt")).read()
    return re.search(r"project\(larap VERSION (\d+\.\d+\.\d+)", text).group(1)


def test_every_version_is_cmakes():
    v = cmake_version()
    assert larap.__version__ == v
    init = open(os.path.join(REPO, "addon", "larap_blender", "__init__.py")).read()
    bl_info = ast.literal_eval(re.search(r"bl_info = (\{.*?\n\})", init, re.S).group(1))
    assert ".".join(map(str, bl_info["version"])) == v
    manifest = open(os.path.join(REPO, "addon", "larap_blender", "blender_manifest.toml")).read()
    assert re.search(r'^version = "([^"]+)"', manifest, re.M).group(1) == v
