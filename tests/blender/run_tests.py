# SPDX-License-Identifier: GPL-3.0-or-later
# Run the add-on tests inside Blender (headless):
#   blender -b --factory-startup --python-exit-code 1 --python tests/blender/run_tests.py -- [pytest args]
# The repo's python/ (engine package, with python/larap/_core*.so built) and addon/ go on sys.path;
# LARAP_ENGINE_PATH=<dir holding larap/> uses another engine copy instead of python/ (e.g. the one
# vendored into addon/larap_blender by scripts/install_addon: LARAP_ENGINE_PATH=addon/larap_blender).
# Exits with pytest's status.
import os
import sys

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(os.path.dirname(HERE))


def main():
    engine_path = os.environ.get("LARAP_ENGINE_PATH") or os.path.join(ROOT, "python")
    for path in (os.path.join(ROOT, "addon"), os.path.abspath(engine_path)):
        if path not in sys.path:
            sys.path.insert(0, path)
    argv = sys.argv[sys.argv.index("--") + 1:] if "--" in sys.argv else []
    # Import the engine before the add-on: the add-on reuses an already imported `larap`, so the
    # tests exercise the freshly built one rather than a stale vendored copy.
    try:
        import larap  # noqa: F401
        print("LARAP tests: engine from", os.path.dirname(larap.__file__))
    except Exception as exc:  # the tests that need it fail with the add-on's own message
        print("LARAP tests: engine not importable:", exc)
    import pytest
    args = list(argv)
    if not any(not a.startswith("-") and os.path.exists(a.split("::")[0]) for a in args):
        args.insert(0, HERE)
    code = pytest.main(["-p", "no:cacheprovider", "--rootdir", HERE, *args])
    sys.stdout.flush()
    sys.exit(int(code))


main()
