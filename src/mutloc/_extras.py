"""Optional packages: which extra installs each one, and the one way to import them.

``pip install mutloc`` is the core a robot computer needs (localize, track to
CSV/TUM, every detector, tags, simulate, calibrate).  The rest comes with an
extra (``pyproject.toml`` lists them; ``[all]`` is every one):

- ``ros``: rosbags, mcap -- ROS 1/2 bags and MCAP files in and out;
- ``viz``: matplotlib, rerun-sdk, av -- plots and marker sheets, Rerun
  recordings, videos written as they go;
- ``experiments``: pycolmap, matplotlib -- the paper's experiments;
- ``live``: cyclonedds -- DDS for live nodes.

Library code imports an optional package only inside the function that
needs it, after :func:`require` (``tests/test_architecture.py`` checks both),
so a missing one is a one-line :class:`~mutloc.errors.MissingExtraError`
naming the package and its extra, never a traceback.
"""

from __future__ import annotations

import importlib
from types import ModuleType

from .errors import MissingExtraError

__all__ = ["PACKAGES", "require"]

#: Import name -> (PyPI distribution, extra that installs it; None: a core dependency).
PACKAGES: dict[str, tuple[str, str | None]] = {
    "rosbags": ("rosbags", "ros"),
    "mcap": ("mcap", "ros"),
    "matplotlib": ("matplotlib", "viz"),
    "rerun": ("rerun-sdk", "viz"),
    "av": ("av", "viz"),
    "pycolmap": ("pycolmap", "experiments"),
    "cyclonedds": ("cyclonedds", "live"),
    "pupil_apriltags": ("pupil-apriltags", None),
}


def require(module: str, what: str, extra: str | None = None) -> ModuleType:
    """Import optional package ``module`` (a :data:`PACKAGES` key) and return it,
    or raise :class:`MissingExtraError`: ``"{what} needs {package}, part of the
    {extra} extra: pip install "mutloc[{extra}]"``.  ``extra``: name another
    extra that also installs it (``experiments`` for matplotlib)."""
    dist, default = PACKAGES[module]
    extra = extra or default
    try:
        return importlib.import_module(module)
    except ImportError as exc:
        absent = isinstance(exc, ModuleNotFoundError) and (exc.name or "").partition(".")[0] == module
        if not absent:  # installed, but broken (a missing library of its own)
            detail = " ".join(str(exc).split())
            message = f"{what} needs {dist}, which is installed but cannot be imported ({detail}): " \
                      f"pip install --force-reinstall {dist}"
        elif extra is None:
            message = f"{what} needs {dist}, a dependency of mutloc missing from this install: pip install {dist}"
        else:
            message = f'{what} needs {dist}, part of the {extra} extra: pip install "mutloc[{extra}]"'
        raise MissingExtraError(message) from None
