"""mutloc: relative 6-DOF pose of two robots from reciprocal fiducial observations.

Implements and extends Dhiman, Ryde & Corso, "Mutual Localization" (IROS 2013).
Frames, pose direction and file formats are those of the manual's Formats
page (docs/formats.md): a result ``T_qp = (R, t)`` maps ``x_q = R @ x_p + t``.

Names load on first use, so ``import mutloc`` (and ``mutloc --help``) does not
pull in Numba, SciPy or OpenCV.

``mutloc.track`` is always the subpackage (tracking from streams and logs),
whatever was imported first; the trackers themselves are
:func:`mutloc.track_streams` (two image streams) and :func:`mutloc.track_log`
(an observation log).
"""

from __future__ import annotations

import importlib
from typing import Any

from ._jit_cache import CACHE_DIR  # noqa: F401  (must precede every Numba kernel)
from . import errors

__version__ = "0.1.0"

# public name -> module that defines it ("module:name" when the name there differs)
_EXPORTS = {
    "CalibrationResult": "calibration",
    "Camera": "core.camera",
    "Estimate": "api",
    "calibrate_markers": "calibration",
    "FisheyeCamera": "core.lenses",
    "FrameStatus": "track.status",
    "Marker": "core.rig",
    "MarkerKind": "core.rig",
    "Observation": "core.observations",
    "ObservationSet": "core.observations",
    "OmniCamera": "core.lenses",
    "Pose": "core.pose",
    "Rig": "core.rig",
    "TeamEstimate": "team",
    "Robot": "core.rig",
    "load_observations": "io.observations",
    "load_rig": "api",
    "localize": "api",
    "localize_batch": "api",
    "localize_images": "track.frames",
    "localize_team": "team",
    "rotation_error_deg": "core.geometry",
    "save_rig": "io.rig",
    "solve_bearings": "api",
    "track_log": "track.tracker",
    "track_streams": "track.tracker:track",
    "translation_error": "core.geometry",
}

# Subpackages loaded on first use of ``mutloc.NAME``: ``mutloc.track`` is the
# package before and after ``import mutloc.track`` (never a function).
_SUBPACKAGES = ("track",)

__all__ = sorted([*_EXPORTS, "errors"])


def __getattr__(name: str) -> Any:
    if name in _SUBPACKAGES:
        return importlib.import_module(f".{name}", __name__)
    spec = _EXPORTS.get(name)
    if spec is None:
        raise AttributeError(f"module 'mutloc' has no attribute {name!r}")
    module, _, attr = spec.partition(":")
    value = getattr(importlib.import_module(f".{module}", __name__), attr or name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted({*globals(), *_EXPORTS, *_SUBPACKAGES})
