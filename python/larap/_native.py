"""Loads the compiled module, explaining what to do when it is missing or built for another Python."""
import sys

try:
    from . import _core  # noqa: F401
except ImportError as exc:
    raise ImportError(
        f"the compiled module larap._core could not be loaded ({exc}). It must be built for this "
        f"Python ({sys.version.split()[0]} at {sys.executable}): run scripts/setup."
    ) from exc
