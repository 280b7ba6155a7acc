# SPDX-License-Identifier: GPL-3.0-or-later
"""Find and import the compiled ``larap`` engine.

Order: a ``larap`` that is already imported in this Blender session (another add-on or a test
runner loaded it), then the copy vendored into this add-on (``larap_blender/larap``, put there by
``scripts/install_addon``), then whatever ``import larap`` finds on ``sys.path``.

Nothing here raises: :func:`get` returns the module or ``None`` and :func:`error` says why, in a
sentence meant for the panel and for operator reports.
"""
import glob
import importlib
import importlib.machinery
import importlib.util
import os
import sys

VENDORED_DIR = os.path.join(os.path.dirname(os.path.abspath(__file__)), "larap")

_module = None
_error = None
_tried = False


def _core_files(pkg_dir):
    return sorted(glob.glob(os.path.join(pkg_dir, "_core*.so")) + glob.glob(os.path.join(pkg_dir, "_core*.pyd")))


def _explain(pkg_dir, exc):
    """Turn an import failure into a message a user can act on."""
    py = "%d.%d" % sys.version_info[:2]
    suffixes = importlib.machinery.EXTENSION_SUFFIXES
    if pkg_dir:
        cores = _core_files(pkg_dir)
        if not cores:
            return ("LARAP engine not built: %s has no compiled _core module "
                    "(run scripts/install_addon)" % pkg_dir)
        names = [os.path.basename(c) for c in cores]
        if not any(n == "_core" + s for n in names for s in suffixes):
            return ("LARAP engine was built for another Python (%s) but Blender runs Python %s "
                    "(needs _core%s); rebuild with scripts/install_addon" % (", ".join(names), py, suffixes[0]))
    return "LARAP engine failed to load (Blender Python %s): %s: %s" % (py, type(exc).__name__, exc)


def _drop_partial():
    for name in [m for m in sys.modules if m == "larap" or m.startswith("larap.")]:
        del sys.modules[name]


def _load_vendored():
    init = os.path.join(VENDORED_DIR, "__init__.py")
    spec = importlib.util.spec_from_file_location("larap", init, submodule_search_locations=[VENDORED_DIR])
    mod = importlib.util.module_from_spec(spec)
    sys.modules["larap"] = mod
    try:
        spec.loader.exec_module(mod)
    except BaseException:
        _drop_partial()
        raise
    return mod


def _check(mod):
    for attr in ("Deformer", "available_devices"):
        if not hasattr(mod, attr):
            raise ImportError("module %r has no %s (not the LARAP engine?)" % (getattr(mod, "__file__", mod), attr))
    return mod


def load(force=False):
    """Import the engine once (again with ``force``); return the module or None."""
    global _module, _error, _tried
    if _tried and not force:
        return _module
    _tried = True
    _module, _error = None, None
    errors = []
    existing = sys.modules.get("larap")
    if existing is not None and not force:
        try:
            _module = _check(existing)
            return _module
        except ImportError as exc:
            errors.append(_explain(None, exc))
    if os.path.isfile(os.path.join(VENDORED_DIR, "__init__.py")):
        try:
            _module = _check(_load_vendored())
            return _module
        except Exception as exc:  # ImportError, OSError (bad .so), anything the package raises
            errors.append(_explain(VENDORED_DIR, exc))
    try:
        if force:
            _drop_partial()
        mod = importlib.import_module("larap")
        _module = _check(mod)
        return _module
    except Exception as exc:
        _drop_partial()
        spec_dir = None
        for entry in sys.path:
            cand = os.path.join(entry or ".", "larap")
            if os.path.isfile(os.path.join(cand, "__init__.py")):
                spec_dir = cand
                break
        if spec_dir is not None or not errors:
            errors.append(_explain(spec_dir, exc) if spec_dir else
                          "LARAP engine not found: no vendored copy in the add-on and no 'larap' on sys.path "
                          "(run scripts/install_addon)")
    _error = errors[0]
    return None


def get():
    return load()


def error():
    load()
    return _error


def location():
    mod = load()
    return os.path.dirname(getattr(mod, "__file__", "") or "") if mod else ""


def available_devices():
    mod = load()
    if mod is None:
        return []
    try:
        return list(mod.available_devices())
    except Exception:
        return ["cpu"]
