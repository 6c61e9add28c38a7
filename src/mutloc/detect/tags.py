"""Printed square tags (AprilTag / ArUco) as mutual-localization markers.

A rig marker with a ``tag`` key (``{family: tag36h11, id: 3, size: 0.1}``) is
a printed tag whose *centre* is the marker's ``position``.  This module

* finds those tags in an image (:func:`detect_tags`) with OpenCV's
  ``cv2.aruco.ArucoDetector`` and reports, in mutloc's pixel convention, the
  tag centre as the detection's ``uv`` and the four corners as its
  ``corners``;
* turns a tag whose orientation the rig knows (``tag: {..., rotation: [rx, ry,
  rz]}``) into five point markers: the centre plus its four corners
  (:func:`tag_corner_points`, :func:`expand_tag_corners`,
  :func:`tag_observations`), so a tag-equipped pair is solved by the ordinary
  mutual solver (:func:`mutloc.localize`) with four times the constraints of
  the centre alone.

Pixel convention.  OpenCV's aruco corners already use mutloc's convention
(``(0, 0)`` = centre of the top-left pixel) for the ``none``, ``subpix`` and
``contour`` refinements; only ``CORNER_REFINE_APRILTAG`` returns the AprilTag
library's corner-origin coordinates, half a pixel off, which is undone here.

Corner accuracy.  OpenCV's ``CORNER_REFINE_SUBPIX`` (``cornerSubPix`` on an
L-shaped, blurred corner) is biased about 0.2 px towards the inside of the tag
on anti-aliased renderings; the default ``refine="edges"`` starts from it and
re-fits each side of the black square as a straight line through sub-pixel
edge points found across the whole side, then intersects adjacent sides.  The
edge position of a symmetrically blurred step is unbiased, and fitting ~all
pixels of a side averages the noise away, so corners come out several times
more accurate (see the tests for the figures).

Tag frame (for ``rotation``): origin at the tag centre, x to the right and y
down as the tag image is printed, z = x cross y pointing *into* the tag
(away from a viewer who sees it upright) -- the AprilTag library's tag frame.
The corners, in OpenCV's order (top-left, top-right, bottom-right, bottom-left
of the tag image), are then ``(-s/2, -s/2, 0), (s/2, -s/2, 0), (s/2, s/2, 0),
(-s/2, s/2, 0)`` with ``s`` the side of the black square (the tag ``size``,
quiet zone excluded).  ``rotation`` is the rotation vector of that frame in
the robot's camera frame: ``X_robot = expm([rotation]x) @ X_tag + position``.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Mapping
from dataclasses import replace
from typing import Any

import cv2
import numpy as np

from ..core.camera import Camera
from ..core.geometry import so3_exp
from ..core.rig import Marker, Rig, Robot
from ..errors import InputError, RigError
from .base import Detection, DetectionResult, as_bgr
from .tag_edges import diagonal_centre, refine_edges

__all__ = [
    "CORNER_SEPARATOR",
    "REFINE_METHODS",
    "aruco_dictionary",
    "canonical_family",
    "corner_marker_names",
    "detect_tags",
    "diagonal_centre",
    "expand_tag_corners",
    "tag_corner_points",
    "tag_observations",
]

# Corner markers of tag NAME are NAME#0 .. NAME#3 (OpenCV corner order).
CORNER_SEPARATOR = "#"

REFINE_METHODS = ("edges", "subpix", "contour", "apriltag", "none")

# Canonical family name -> cv2.aruco predefined dictionary attribute.
_DICTIONARIES: dict[str, str] = {
    "tag16h5": "DICT_APRILTAG_16h5",
    "tag25h9": "DICT_APRILTAG_25h9",
    "tag36h10": "DICT_APRILTAG_36h10",
    "tag36h11": "DICT_APRILTAG_36h11",
    "aruco_original": "DICT_ARUCO_ORIGINAL",
    "aruco_mip_36h12": "DICT_ARUCO_MIP_36h12",
}
for _bits in (4, 5, 6, 7):
    for _n in (50, 100, 250, 1000):
        _DICTIONARIES[f"{_bits}x{_bits}_{_n}"] = f"DICT_{_bits}X{_bits}_{_n}"

_OPENCV_REFINE = {
    "edges": cv2.aruco.CORNER_REFINE_SUBPIX,  # the starting point of the edge fit
    "subpix": cv2.aruco.CORNER_REFINE_SUBPIX,
    "contour": cv2.aruco.CORNER_REFINE_CONTOUR,
    "apriltag": cv2.aruco.CORNER_REFINE_APRILTAG,
    "none": cv2.aruco.CORNER_REFINE_NONE,
}

# CORNER_REFINE_APRILTAG reports corners with (0, 0) at the top-left *corner*
# of the image (the AprilTag library's origin); mutloc's origin is that pixel's
# centre.
_APRILTAG_ORIGIN_SHIFT = 0.5


# ---------------------------------------------------------------------------
# families
# ---------------------------------------------------------------------------


def canonical_family(family: Any) -> str:
    """The canonical spelling of a tag family name, or :class:`RigError`.

    Accepts AprilTag names (``tag36h11``, ``apriltag_36h11``, ``36h11``,
    ``DICT_APRILTAG_36h11``) and ArUco names (``4x4_50``, ``aruco_5x5_100``,
    ``DICT_6X6_250``, ``aruco_original``), case-insensitively.
    """
    if not isinstance(family, str) or not family.strip():
        raise RigError(f"tag family must be a non-empty string (e.g. tag36h11), got {family!r}")
    s = family.strip().lower().replace("-", "_")
    s = s.removeprefix("dict_")
    if s in _DICTIONARIES:
        return s
    for prefix in ("apriltag_", "apriltag", "tag_", "tag"):
        if s.startswith(prefix) and "tag" + s[len(prefix):] in _DICTIONARIES:
            return "tag" + s[len(prefix):]
    if "tag" + s in _DICTIONARIES:  # bare "36h11"
        return "tag" + s
    if s.startswith("aruco_") and s[6:] in _DICTIONARIES:  # "aruco_4x4_50"
        return s[6:]
    known = ", ".join(sorted(_DICTIONARIES))
    raise RigError(f"unknown tag family {family!r} (known: {known})")


@functools.cache
def _dictionary(family: str) -> Any:
    return cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, _DICTIONARIES[family]))


def aruco_dictionary(family: str) -> Any:
    """The ``cv2.aruco.Dictionary`` of a tag family (any spelling :func:`canonical_family` accepts)."""
    return _dictionary(canonical_family(family))


@functools.lru_cache(maxsize=64)
def _detector(family: str, refine: str, params: tuple[tuple[str, Any], ...]) -> Any:
    p = cv2.aruco.DetectorParameters()
    # Otherwise OpenCV's defaults, so refine="subpix" etc. are exactly OpenCV's
    # detector (tighter cornerSubPix convergence was measured to make its
    # inward bias slightly worse, not better).
    p.cornerRefinementMethod = _OPENCV_REFINE[refine]
    for key, value in params:
        setattr(p, key, value)
    return cv2.aruco.ArucoDetector(_dictionary(family), p)


def _params_key(params: Mapping[str, Any] | None) -> tuple[tuple[str, Any], ...]:
    if params is None:
        return ()
    if not isinstance(params, Mapping):
        raise InputError("params must be a mapping of cv2.aruco.DetectorParameters attributes")
    probe = cv2.aruco.DetectorParameters()
    for key, value in params.items():
        if not isinstance(key, str) or key.startswith("_") or not hasattr(probe, key):
            raise InputError(f"params: {key!r} is not a cv2.aruco.DetectorParameters attribute")
        try:
            setattr(probe, key, value)
        except (cv2.error, TypeError, ValueError, OverflowError) as exc:
            raise InputError(f"params[{key!r}]: invalid value {value!r} ({exc})") from None
        try:
            hash(value)  # the parameters key a cache of detectors
        except TypeError:
            raise InputError(f"params[{key!r}]: expected a number, got {value!r}") from None
    return tuple(sorted(params.items()))


# ---------------------------------------------------------------------------
# geometry helpers
# ---------------------------------------------------------------------------


def tag_spec(marker: Marker) -> tuple[str, int, float]:
    """(canonical family, id, size) of a tag marker, validated."""
    tag = marker.tag
    where = f"marker {marker.name!r}"
    if not isinstance(tag, Mapping):
        raise RigError(f"{where}: tag must be a mapping {{family, id, size}}")
    for key in ("family", "id", "size"):
        if key not in tag:
            raise RigError(f"{where}: tag: missing key {key!r}")
    try:
        family = canonical_family(tag["family"])
    except RigError as exc:
        raise RigError(f"{where}: {exc}") from None
    tid = tag["id"]
    if isinstance(tid, (bool, np.bool_)) or not isinstance(tid, (int, np.integer)) or tid < 0:
        raise RigError(f"{where}: tag id must be a non-negative integer, got {tid!r}")
    n_ids = int(_dictionary(family).bytesList.shape[0])
    if tid >= n_ids:
        raise RigError(f"{where}: tag id {tid} does not exist in {family} (ids 0..{n_ids - 1})")
    size = tag["size"]
    if isinstance(size, bool) or not isinstance(size, (int, float, np.integer, np.floating)) or \
            not (math.isfinite(float(size)) and float(size) > 0):
        raise RigError(f"{where}: tag size must be a finite number > 0 (metres), got {size!r}")
    return family, int(tid), float(size)


def detect_tags(image: Any, markers: Mapping[str, Marker] | Robot, *, refine: str = "edges",
                camera: Camera | None = None, gamma: float = 1.0,
                params: Mapping[str, Any] | None = None) -> DetectionResult:
    """Find the printed tags of ``markers`` in ``image``.

    Markers without a ``tag`` key are ignored (other detectors find them).
    Each found tag becomes a :class:`Detection` whose ``uv`` is the tag
    centre (the diagonals' intersection, the true projective centre, not the
    corner mean) and ``corners`` its four corners (4, 2) in OpenCV's order --
    top-left, top-right, bottom-right, bottom-left of the tag image -- all in
    mutloc's pixel convention (raw, distorted pixels).  Tags not found are
    listed in ``missing``.  Both follow the order of ``markers``.  ``info``
    holds ``family``, ``id``, ``side_px`` (mean side length), ``refine`` (the
    method that produced the corners: ``"subpix"`` when the edge fit was
    rejected), ``edge_rms_px`` (edge fit only: RMS distance of the edge
    points from the fitted sides, a quality figure) and, when the id was seen
    more than once, ``duplicates`` (the largest copy is kept, being the most
    accurately measured).

    ``refine``: ``"edges"`` (default; OpenCV's sub-pixel corners re-fitted
    from the four sides, the most accurate), or OpenCV's own corner
    refinement ``"subpix"``, ``"contour"``, ``"apriltag"``, ``"none"``.
    ``camera`` (optional) lets the edge fit and the centre account for lens
    distortion.  ``gamma``: the edge fit assumes intensities proportional to
    light; for a gamma-encoded image (sRGB: about 2.2) pass the exponent and
    intensities are linearized first -- otherwise blur moves every edge
    towards the dark side (measured ~1 px inwards at 1.5 px blur), which
    shrinks the tag and biases range.  ``params`` overrides ``cv2.aruco.DetectorParameters``
    attributes (e.g. ``{"minMarkerPerimeterRate": 0.01}`` for tiny tags).

    Raises :class:`RigError` for an unknown family, an id outside it, or two
    markers using the same tag (they could not be told apart).
    """
    if refine not in REFINE_METHODS:
        raise InputError(f"refine must be one of {', '.join(REFINE_METHODS)}; got {refine!r}")
    if camera is not None and not isinstance(camera, Camera):
        raise InputError(f"camera must be a mutloc Camera, got {type(camera).__name__}")
    if isinstance(markers, Robot):
        markers = markers.markers
    if not isinstance(markers, Mapping):
        raise InputError("markers must be a mapping {name: Marker}")
    pkey = _params_key(params)
    if isinstance(gamma, bool) or not isinstance(gamma, (int, float)) or not (math.isfinite(gamma) and gamma > 0):
        raise InputError(f"gamma must be a finite number > 0, got {gamma!r}")

    wanted: dict[str, dict[int, str]] = {}  # family -> id -> marker name
    for name, marker in markers.items():
        if not isinstance(marker, Marker):
            raise InputError(f"markers[{name!r}] must be a Marker, got {type(marker).__name__}")
        if marker.tag is None:
            continue
        family, tid, _ = tag_spec(marker)
        ids = wanted.setdefault(family, {})
        if tid in ids:
            raise RigError(f"markers {ids[tid]!r} and {name!r} both use {family} tag id {tid}: "
                           "they cannot be told apart")
        ids[tid] = name

    result = DetectionResult()
    if not wanted:
        return result
    gray = cv2.cvtColor(as_bgr(image), cv2.COLOR_BGR2GRAY)
    gray_f: np.ndarray | None = None

    # One detector pass per family; every copy of each id it found.
    copies: dict[tuple[str, int], list[np.ndarray]] = {}
    for family in wanted:
        found, found_ids, _ = _detector(family, refine, pkey).detectMarkers(gray)
        if found_ids is not None:
            for quad, tid in zip(found, np.asarray(found_ids).ravel()):
                copies.setdefault((family, int(tid)), []).append(np.asarray(quad, dtype=float).reshape(4, 2))

    for family, ids in wanted.items():
        cells = int(_dictionary(family).markerSize) + 2  # data bits plus the one-cell black border
        for tid, name in ids.items():
            quads = copies.get((family, tid))
            if not quads:
                continue
            quad = max(quads, key=lambda q: abs(cv2.contourArea(q.astype(np.float32))))
            method = refine
            info: dict[str, Any] = {"family": family, "id": tid}
            if refine == "apriltag":
                quad = quad - _APRILTAG_ORIGIN_SHIFT
            elif refine == "edges":
                if gray_f is None:
                    gray_f = gray.astype(np.float32)
                    if gamma != 1.0:
                        gray_f = 255.0 * (gray_f / 255.0) ** np.float32(gamma)
                better = refine_edges(gray_f, quad, cells, camera)
                if better is None:
                    method = "subpix"  # edge fit failed (occluded side, image border): keep OpenCV's
                else:
                    quad, info["edge_rms_px"] = better
            info["side_px"] = float(np.mean(np.linalg.norm(quad - np.roll(quad, -1, axis=0), axis=1)))
            info["refine"] = method
            if len(quads) > 1:
                info["duplicates"] = len(quads)
            result.detections[name] = Detection(marker=name, uv=diagonal_centre(quad, camera), score=1.0,
                                                corners=quad, info=info)

    # Report in the caller's marker order, whatever the family grouping.
    order = [n for n in markers if markers[n].tag is not None]
    result.detections = {n: result.detections[n] for n in order if n in result.detections}
    result.missing = [n for n in order if n not in result.detections]
    return result


# ---------------------------------------------------------------------------
# tag geometry in the rig
# ---------------------------------------------------------------------------


def corner_marker_names(name: str) -> list[str]:
    """``[NAME#0, NAME#1, NAME#2, NAME#3]``: the corner markers of tag ``NAME``."""
    return [f"{name}{CORNER_SEPARATOR}{k}" for k in range(4)]


def tag_corner_points(marker: Marker) -> np.ndarray | None:
    """3-D corners (4, 3) of a tag marker in its robot's camera frame, OpenCV corner order.

    None when the marker has no tag or its tag has no ``rotation`` (then only
    the centre is known).  See the module docstring for the tag frame.
    """
    if marker.tag is None:
        return None
    _, _, size = tag_spec(marker)
    R = tag_rotation(marker)
    return None if R is None else square_corners(marker.position, size, R)


def tag_rotation(marker: Marker, default: Any = None) -> np.ndarray | None:
    """Rotation matrix of a tag's frame in its robot's frame, from the rig's
    ``tag.rotation`` (a rotation vector), else ``default`` (None: unknown)."""
    rot = marker.tag.get("rotation", default) if isinstance(marker.tag, Mapping) else default
    if rot is None:
        return None
    try:
        rvec = np.asarray(rot, dtype=float)
    except (TypeError, ValueError):
        rvec = np.empty(0)
    if rvec.shape != (3,) or not np.all(np.isfinite(rvec)):
        raise RigError(f"marker {marker.name!r}: tag rotation must be a rotation vector of 3 finite numbers "
                       f"(radians), got {rot!r}")
    return so3_exp(rvec)


def square_corners(centre: np.ndarray, size: float, R: np.ndarray) -> np.ndarray:
    """Corners (4, 3) of a square tag of side ``size`` centred at ``centre``
    whose frame (x right, y down as printed, z into the tag) has rotation R,
    in OpenCV's order: top-left, top-right, bottom-right, bottom-left."""
    h = 0.5 * size
    local = np.array([[-h, -h, 0.0], [h, -h, 0.0], [h, h, 0.0], [-h, h, 0.0]])
    return np.asarray(centre, float) + local @ R.T


def expand_tag_corners(rig: Rig | Mapping[str, Any] | str) -> Rig:
    """A copy of ``rig`` where each oriented tag ``NAME`` also has corner markers ``NAME#0..3``.

    The corners are plain point markers (extra keys ``tag_of: NAME`` and
    ``tag_corner: k``); the tag marker itself is kept, so its centre can still
    be observed.  Tags without ``rotation`` are left as they are.  Idempotent.
    ``rig`` may be anything :func:`mutloc.load_rig` accepts.
    """
    # Imported here, not at module level: mutloc.api pulls in the whole solver stack.
    from ..api import load_rig

    rig = load_rig(rig)
    robots: dict[str, Robot] = {}
    for rname, robot in rig.robots.items():
        new: dict[str, Marker] = dict(robot.markers)
        for name, marker in robot.markers.items():
            if marker.extra.get("tag_of") is not None:
                continue
            pts = tag_corner_points(marker)
            if pts is None:
                continue
            for k, (cname, X) in enumerate(zip(corner_marker_names(name), pts)):
                if cname in new:
                    old = new[cname]
                    if old.extra.get("tag_of") == name and np.allclose(old.position, X, atol=1e-12):
                        continue  # already expanded
                    raise RigError(f"robot {rname!r}: marker {cname!r} exists, so tag {name!r}'s corner "
                                   "markers cannot be added")
                new[cname] = Marker(name=cname, robot=rname, position=X, extra={"tag_of": name, "tag_corner": k})
        robots[rname] = replace(robot, markers=new)  # keeps the camera and base frame
    return Rig(robots)


def tag_observations(result: DetectionResult, rig: Rig | None = None, *,
                     centre: bool = True) -> dict[str, tuple[float, float]]:
    """One observer's observations ``{NAME: centre, NAME#0: corner0, ...}`` from a detection result.

    Every detection contributes its ``uv`` (unless ``centre=False`` for a
    detection with corners); those with corners add ``NAME#k``.  With ``rig``
    (the :func:`expand_tag_corners` rig), names it does not know are dropped,
    e.g. the corners of a tag whose orientation is not given.  Under a pinhole
    model the centre is a function of the corners, so it adds no information
    beyond them (harmless to include; it slightly overstates the confidence
    in the covariance).
    """
    known = None
    if rig is not None:
        known = {m for robot in rig.robots.values() for m in robot.markers}
    out: dict[str, tuple[float, float]] = {}
    for name, det in result.detections.items():
        if det.corners is None or centre:
            out[name] = (float(det.uv[0]), float(det.uv[1]))
        if det.corners is not None:
            cs = np.asarray(det.corners, dtype=float).reshape(4, 2)
            for cname, (u, v) in zip(corner_marker_names(name), cs):
                out[cname] = (float(u), float(v))
    if known is not None:
        out = {k: v for k, v in out.items() if k in known}
    return out
