"""mutloc: relative 6-DOF pose of two robots from reciprocal fiducial observations.

Implements and extends Dhiman, Ryde & Corso, "Mutual Localization" (IROS 2013).
Frames, pose direction and file formats follow the project's SPEC: a result
``T_qp = (R, t)`` maps ``x_q = R @ x_p + t``.
"""

from . import _jit_cache  # noqa: F401  (must precede every Numba kernel)
from .api import Estimate, load_rig, localize, solve_bearings
from .core.camera import Camera
from .core.geometry import Pose, rotation_error_deg, translation_error
from .core.rig import Marker, Rig, Robot
from . import errors

__version__ = "0.1.0"

__all__ = [
    "Camera",
    "Estimate",
    "Marker",
    "Pose",
    "Rig",
    "Robot",
    "errors",
    "load_rig",
    "localize",
    "rotation_error_deg",
    "solve_bearings",
    "translation_error",
]
