"""Every exception mutloc raises on purpose.

Library code raises only these (all subclasses of :class:`MutlocError`); the
command line turns them into a one-line message and a non-zero exit status.
Input errors are also ``ValueError`` so callers that already catch that keep
working.
"""

from __future__ import annotations


class MutlocError(Exception):
    """Base class of all mutloc errors."""


class InputError(MutlocError, ValueError):
    """The caller's input is malformed: wrong shape, NaN/inf, missing keys."""


class FileFormatError(InputError):
    """A file cannot be read or does not have the expected structure."""


class RigError(InputError):
    """The rig description is invalid (bad camera, duplicate marker, ...)."""


class ObservationError(InputError):
    """Observations are invalid: unknown marker, self-observation, too few."""


class UnknownMarkerError(ObservationError):
    """An observation names a marker the rig does not have."""


class TooFewObservationsError(ObservationError):
    """Fewer than three marker observations between the two robots."""


class OdometryError(InputError):
    """A robot's odometry cannot be used: too few usable samples, a robot
    frame that is not the rig's, an increment it does not cover; the
    message names the file or topic and the line or stamp."""


class MissingExtraError(MutlocError, ImportError):
    """The call needs an optional package this install does not have; the
    message names it and the extra that installs it (``pip install
    "mutloc[ros]"``).  Also an ``ImportError``, so code that already treats
    optional parts that way keeps working."""


class GeometryError(MutlocError):
    """The problem is well formed but geometrically unsolvable."""


class DegenerateGeometryError(GeometryError):
    """Coincident markers or a configuration with no isolated solution."""


class InconsistentObservationsError(GeometryError):
    """The observations do not fit one pose with the stated pixel noise (a
    wrong detection, a wrong rig, or more noise than stated) and no
    consistent subset explains them.  ``estimate`` holds the best attempt,
    for inspection only."""

    def __init__(self, message: str, estimate: object = None):
        super().__init__(message)
        self.estimate = estimate


class UnverifiedError(GeometryError):
    """Exactly three observations: several poses fit them exactly, so nothing
    can confirm the one chosen (raised only where the caller asked for
    verified poses, e.g. the command line without ``--allow-unverified``)."""

    def __init__(self, message: str, estimate: object = None):
        super().__init__(message)
        self.estimate = estimate


class UnobservableMarkersError(GeometryError):
    """An observation log cannot determine the markers' positions (one pose
    repeated, pure translation along the line of sight, too few frames); the
    message names what is undetermined and the motion that would fix it."""


class NoSolutionError(GeometryError):
    """No pose explains the observations (e.g. every solution puts a marker
    behind a camera)."""


__all__ = [
    "MutlocError",
    "InputError",
    "FileFormatError",
    "RigError",
    "ObservationError",
    "UnknownMarkerError",
    "TooFewObservationsError",
    "OdometryError",
    "MissingExtraError",
    "GeometryError",
    "DegenerateGeometryError",
    "NoSolutionError",
    "UnobservableMarkersError",
    "InconsistentObservationsError",
    "UnverifiedError",
    "positive_number",
    "confidence_level",
]


def positive_number(value: object, what: str, error: type[InputError] = InputError) -> float:
    """``value`` as a finite float > 0, else ``error`` naming ``what`` (the one
    check of "a positive number" for every option and rig key)."""
    import math

    if isinstance(value, (str, bytes, bool)) or value is None:
        raise error(f"{what} must be a finite number > 0, got {value!r}")
    try:
        x = float(value)  # type: ignore[arg-type]
    except (TypeError, ValueError, OverflowError):
        raise error(f"{what} must be a finite number > 0, got {value!r}") from None
    if not (math.isfinite(x) and x > 0):
        raise error(f"{what} must be a finite number > 0, got {value!r}")
    return x


def confidence_level(value: object) -> float:
    """``value`` as a test's confidence in (0, 1] (1 disables the test), else
    InputError (the one check of ``confidence`` for every estimator)."""
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not 0.0 < value <= 1.0:
        raise InputError(f"confidence must be a number in (0, 1] (1 disables the test), got {value!r}")
    return float(value)
