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
from . import apriltag_lib
from .tag_families import (aruco_dictionary, canonical_family, has_aruco_dictionary, tag_cells, tag_id_count,
                           tag_library, tag_spec)
from .base import Detection, DetectionResult, as_bgr
from .tag_edges import diagonal_centre, linearize, refine_edges

__all__ = [
    "CORNER_SEPARATOR",
    "BACKENDS",
    "REFINE_METHODS",
    "aruco_dictionary",
    "canonical_family",
    "corner_detections",
    "corner_marker_names",
    "detect_tags",
    "diagonal_centre",
    "expand_tag_corners",
    "find_tag_near",
    "tag_cells",
    "tag_corner_points",
    "tag_id_count",
    "tag_library",
    "tag_observations",
]

# Corner markers of tag NAME are NAME#0 .. NAME#3 (OpenCV corner order).
CORNER_SEPARATOR = "#"

REFINE_METHODS = ("edges", "subpix", "contour", "apriltag", "none")
# Which library finds the tags: "auto" = the AprilTag 3 library for its own
# families (unless an OpenCV-only corner refinement is asked for), OpenCV's
# aruco module for the rest.
BACKENDS = ("auto", "apriltag", "opencv")
_OPENCV_ONLY_REFINE = ("subpix", "contour", "apriltag")
# Decision margin (the library's mean grey-level distance of the data bits
# from their threshold) at which a detection's score reaches 1.
_FULL_MARGIN = 100.0

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


@functools.lru_cache(maxsize=64)
def _detector(family: str, refine: str, params: tuple[tuple[str, Any], ...]) -> Any:
    p = cv2.aruco.DetectorParameters()
    # Otherwise OpenCV's defaults, so refine="subpix" etc. are exactly OpenCV's
    # detector (tighter cornerSubPix convergence was measured to make its
    # inward bias slightly worse, not better).
    p.cornerRefinementMethod = _OPENCV_REFINE[refine]
    for key, value in params:
        setattr(p, key, value)
    return cv2.aruco.ArucoDetector(aruco_dictionary(family), p)


def _params_key(params: Mapping[str, Any] | None) -> tuple[tuple[str, Any], ...]:
    if params is None:
        return ()
    probe = cv2.aruco.DetectorParameters()
    for key, value in params.items():
        if not isinstance(key, str) or key.startswith("_") or not hasattr(probe, key):
            raise InputError(f"params: {key!r} is neither an AprilTag detector setting nor a "
                             "cv2.aruco.DetectorParameters attribute")
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


def _split_params(params: Mapping[str, Any] | None) -> tuple[tuple, tuple]:
    """(OpenCV key, AprilTag-library key) of ``params``: each name goes to the library that has it."""
    if params is None:
        return (), ()
    if not isinstance(params, Mapping):
        raise InputError("params must be a mapping of detector settings")
    at = {k: v for k, v in params.items() if k in apriltag_lib.PARAMS}
    ocv = {k: v for k, v in params.items() if k not in apriltag_lib.PARAMS}
    return _params_key(ocv or None), apriltag_lib.check_params(at)


def _backend_for(family: str, refine: str, backend: str) -> str:
    if backend == "opencv" or (backend == "auto" and (refine in _OPENCV_ONLY_REFINE or
                                                      tag_library(family) == "opencv")):
        if not has_aruco_dictionary(family):
            raise InputError(f"{family} is decoded by the AprilTag library only: refine must be 'edges' or "
                             f"'none' and backend 'auto' or 'apriltag' (got {refine!r}, {backend!r})")
        return "opencv"
    if tag_library(family) != "apriltag":
        raise InputError(f"backend='apriltag': the AprilTag library does not decode {family}")
    if refine in _OPENCV_ONLY_REFINE:
        raise InputError(f"refine={refine!r} is OpenCV's; with backend='apriltag' use 'edges' or 'none'")
    return "apriltag"


def _check_gamma(gamma: Any) -> float | str:
    if gamma in ("srgb", "linear"):
        return gamma
    if isinstance(gamma, bool) or not isinstance(gamma, (int, float)) or not (math.isfinite(gamma) and gamma > 0):
        raise InputError(f"gamma must be 'srgb', 'linear' or a finite number > 0, got {gamma!r}")
    return "linear" if gamma == 1.0 else float(gamma)


# Pixels around a tag's corners that its edge fit may read (profile length, second-pass shift).
_ROI_PAD = 12


def _refine(gray: np.ndarray, quad: np.ndarray, cells: int, camera: Camera | None,
            gamma: float | str) -> tuple[np.ndarray, float] | None:
    """The edge fit on the tag's neighbourhood only, in linearised grey levels."""
    h, w = gray.shape
    lo = np.floor(quad.min(axis=0)).astype(int) - _ROI_PAD
    hi = np.ceil(quad.max(axis=0)).astype(int) + _ROI_PAD
    x0, y0 = max(0, int(lo[0])), max(0, int(lo[1]))
    x1, y1 = min(w, int(hi[0]) + 1), min(h, int(hi[1]) + 1)
    if x1 - x0 < 4 or y1 - y0 < 4:
        return None
    roi = linearize(gray[y0:y1, x0:x1], gamma)
    return refine_edges(roi, quad, cells, camera, origin=(x0, y0))


def detect_tags(image: Any, markers: Mapping[str, Marker] | Robot, *, refine: str = "edges",
                camera: Camera | None = None, gamma: float | str = "srgb", backend: str = "auto",
                params: Mapping[str, Any] | None = None) -> DetectionResult:
    """Find the printed tags of ``markers`` in ``image``.

    Markers without a ``tag`` key are ignored (other detectors find them).
    Each found tag becomes a :class:`Detection` whose ``uv`` is the tag
    centre (the diagonals' intersection, the true projective centre, not the
    corner mean) and ``corners`` its four corners (4, 2) in OpenCV's order --
    top-left, top-right, bottom-right, bottom-left of the tag image -- all in
    mutloc's pixel convention (raw, distorted pixels).  Tags not found are
    listed in ``missing`` with the reason in ``missing_reasons``
    (``"not_found"``: no tag of that family and id was decoded).  Both follow
    the order of ``markers``.

    Quality: ``score`` is the AprilTag library's decision margin / 100,
    capped at 1 (1 on the OpenCV path, which has no margin); ``info`` holds
    ``family``, ``id``, ``library``, ``side_px`` (mean side length),
    ``refine`` (the method that produced the corners: ``edges_enlarged`` when
    the edge fit did not follow the sides -- failed, or RMS above 0.08 px, as on
    steep small tags -- and a second one did in an enlarged window around the
    tag (:func:`find_tag_near`); the library's own when both were rejected), ``decision_margin`` and ``hamming`` (bits
    corrected; AprilTag library), ``edge_rms_px`` (edge fit: RMS distance of
    the edge points from the fitted sides -- noise, blur and occlusion raise
    it) and, when the id was seen more than once, ``duplicates`` (the
    largest copy is kept, being the most accurately measured).

    ``backend``: ``"auto"`` (default) decodes the AprilTag library's families
    (tag16h5, tag25h9, tag36h11, tagStandard41h12, tagStandard52h13, the
    Circle and Custom families) with the AprilTag 3 library and the ArUco
    dictionaries (and tag36h10) with OpenCV; ``"apriltag"`` / ``"opencv"``
    force one.  ``refine``: ``"edges"`` (default: the detector's corners
    re-fitted from the four sides, the most accurate), ``"none"`` (the
    detector's corners as they are), or OpenCV's own corner refinements
    ``"subpix"``, ``"contour"``, ``"apriltag"`` (these use OpenCV).
    ``camera`` (optional) lets the edge fit and the centre account for lens
    distortion.  ``gamma``: how grey levels encode light, for the edge fit,
    which needs intensities proportional to light: ``"srgb"`` (default: what
    cameras and image files deliver), ``"linear"`` (raw sensor data), or a
    power-law exponent (2.2).  Measured on gamma-encoded renders, fitting
    the encoded levels moves every blurred edge towards the dark side, which
    shrinks the tag and biases range (see tests/test_tags_real.py).
    ``params`` overrides detector settings: the AprilTag library's
    (``quad_decimate``, ``quad_sigma``, ``decode_sharpening``,
    ``min_cluster_pixels``, ...) or ``cv2.aruco.DetectorParameters``
    attributes (e.g. ``{"minMarkerPerimeterRate": 0.01}`` for tiny tags).

    Corner order of the families both libraries know (tag16h5, tag25h9,
    tag36h11) follows OpenCV's ``generateImageMarker`` image, which is the
    AprilTag library's own drawing turned half a turn; the library's corners
    are turned to match, so both backends report the same corner order.

    Raises :class:`RigError` for an unknown family, an id outside it, or two
    markers using the same tag (they could not be told apart).
    """
    if refine not in REFINE_METHODS:
        raise InputError(f"refine must be one of {', '.join(REFINE_METHODS)}; got {refine!r}")
    if backend not in BACKENDS:
        raise InputError(f"backend must be one of {', '.join(BACKENDS)}; got {backend!r}")
    if camera is not None and not isinstance(camera, Camera):
        raise InputError(f"camera must be a mutloc Camera, got {type(camera).__name__}")
    if isinstance(markers, Robot):
        markers = markers.markers
    if not isinstance(markers, Mapping):
        raise InputError("markers must be a mapping {name: Marker}")
    ocv_key, at_key = _split_params(params)
    gamma = _check_gamma(gamma)

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
    libs = {family: _backend_for(family, refine, backend) for family in wanted}
    img = as_bgr(image) if not (isinstance(image, np.ndarray) and image.ndim == 2 and image.dtype == np.uint8) \
        else image
    gray = img if img.ndim == 2 else cv2.cvtColor(img, cv2.COLOR_BGR2GRAY)

    # Every copy of each wanted id: (corners, what the detector says about it).
    copies: dict[tuple[str, int], list[tuple[np.ndarray, dict[str, Any]]]] = {}
    at_families = tuple(f for f in wanted if libs[f] == "apriltag")
    if at_families:
        for d in apriltag_lib.detect(gray, at_families, at_key):
            if d.id not in wanted.get(d.family, {}):
                continue
            quad = np.roll(d.corners, 2, axis=0) if has_aruco_dictionary(d.family) else d.corners
            copies.setdefault((d.family, d.id), []).append(
                (quad, {"decision_margin": d.decision_margin, "hamming": d.hamming}))
    for family in wanted:
        if libs[family] != "opencv":
            continue
        found, found_ids, _ = _detector(family, refine, ocv_key).detectMarkers(gray)
        if found_ids is not None:
            for quad, tid in zip(found, np.asarray(found_ids).ravel()):
                copies.setdefault((family, int(tid)), []).append((np.asarray(quad, dtype=float).reshape(4, 2), {}))

    for family, ids in wanted.items():
        for tid, name in ids.items():
            quads = copies.get((family, tid))
            if not quads:
                result.missing_reasons[name] = "not_found"
                continue
            quad, extra = max(quads, key=lambda q: abs(cv2.contourArea(q[0].astype(np.float32))))
            if len(quads) > 1:
                extra = {**extra, "duplicates": len(quads)}
            det = _detection(name, family, tid, libs[family], quad, extra, gray, refine, camera, gamma)
            if refine == "edges" and (det.info["refine"] != "edges"
                                      or det.info["edge_rms_px"] > _NEAR_MAX_EDGE_RMS_PX):
                # The edge fit did not follow the sides (a steep or small tag): once more in a window around
                # it, enlarged, where the library's quad and the fit have more pixels to go on.
                again = find_tag_near(gray, markers[name], det.corners, camera=camera, gamma=gamma)
                if again is not None:
                    again.info.pop("looked_again", None)
                    again.info["refine"] = "edges_enlarged"
                    if "duplicates" in extra:
                        again.info["duplicates"] = extra["duplicates"]
                    det = again
            result.detections[name] = det

    # Report in the caller's marker order, whatever the family grouping.
    order = [n for n in markers if markers[n].tag is not None]
    result.detections = {n: result.detections[n] for n in order if n in result.detections}
    result.missing = [n for n in order if n not in result.detections]
    result.missing_reasons = {n: result.missing_reasons[n] for n in result.missing}
    return result


def _detection(name: str, family: str, tid: int, lib: str, quad: np.ndarray, extra: dict[str, Any],
               gray: np.ndarray, refine: str, camera: Camera | None, gamma: float | str) -> Detection:
    """The :class:`Detection` of one decoded tag: its corners refined as ``refine`` says, the centre, the info."""
    method = refine if refine != "edges" else ("apriltag_lib" if lib == "apriltag" else "subpix")
    if refine == "none" and lib == "apriltag":
        method = "apriltag_lib"
    info: dict[str, Any] = {"family": family, "id": tid, "library": lib,
                            **{k: v for k, v in extra.items() if k != "duplicates"}}
    if refine == "apriltag":
        quad = quad - _APRILTAG_ORIGIN_SHIFT
    elif refine == "edges":
        better = _refine(gray, quad, tag_cells(family), camera, gamma)
        if better is not None:  # else (occluded side, image border) keep the detector's corners
            quad, info["edge_rms_px"] = better
            method = "edges"
    info["side_px"] = float(np.mean(np.linalg.norm(quad - np.roll(quad, -1, axis=0), axis=1)))
    info["refine"] = method
    if "duplicates" in extra:
        info["duplicates"] = extra["duplicates"]
    score = min(1.0, extra["decision_margin"] / _FULL_MARGIN) if "decision_margin" in extra else 1.0
    return Detection(marker=name, uv=diagonal_centre(quad, camera), score=score, corners=quad, info=info)


#: :func:`find_tag_near`: the window around the predicted corners, in tag sides (at least
#: :data:`_NEAR_MIN_MARGIN_PX`); the window is enlarged (bicubic, at most :data:`_NEAR_MAX_ZOOM` times)
#: until the predicted side is :data:`_NEAR_SIDE_PX`.  Measured on 30 steep tags (55-65 degrees, 21-27 px,
#: the windows around their true corners): 13 decoded at full resolution, 14 enlarged twice, 19 three
#: times, 21 four times.
_NEAR_MARGIN_SIDES = 0.75
_NEAR_MIN_MARGIN_PX = 16
_NEAR_SIDE_PX = 96.0
_NEAR_MAX_ZOOM = 4
#: A tag found there is kept only when the edge fit followed its sides this closely (RMS px; measured on
#: 167 tags found 50-75 degrees off their normal, ``bench/tags_steep.py``'s renders: the worst corner
#: 0.04 / 0.08 / 0.21 px median / p90 / max below 0.05 px, 0.12 / 0.33 / 0.64 px at 0.05-0.08 px,
#: 0.67-1.07 px median above; the library's own corners, where the edge fit fails, 0.5-1.0 px off).
_NEAR_MAX_EDGE_RMS_PX = 0.08


def find_tag_near(image: Any, marker: Marker, quad: Any, *, camera: Camera | None = None,
                  gamma: float | str = "srgb", margin_px: float | None = None) -> Detection | None:
    """Look again for the tag of ``marker`` where ``quad`` (its four predicted corners, (4, 2) pixels) puts it.

    For a tag :func:`detect_tags` missed but a pose predicts -- small, or seen far off its normal, which
    the whole-image search (the AprilTag library at quad decimation 2) loses past about 50 degrees at 30
    px: only the window around the prediction (``margin_px``, default three quarters of the predicted side,
    at least 16 px) is searched, at full resolution and enlarged (bicubic, up to four times, to a side of
    96 px), so that the library's quad finder still sees a steep tag's narrow cells.  Only ``marker``'s family and id
    count.  The corners are then fitted at the image's own resolution as :func:`detect_tags`'s default
    ``refine="edges"`` does (``camera`` and ``gamma`` as there); ``info["looked_again"]`` is True.

    Returns None when the tag is not decoded there, the window lies outside the image, or the edge fit did
    not follow the tag's sides (failed, or RMS above 0.08 px: a steep tag's corners are then pixels off).  The caller
    judges whether the pose it came from agrees (the decoded id is the library's, not the prediction's).
    """
    if not isinstance(marker, Marker) or marker.tag is None:
        raise InputError("find_tag_near needs a tag marker")
    if camera is not None and not isinstance(camera, Camera):
        raise InputError(f"camera must be a mutloc Camera, got {type(camera).__name__}")
    family, tid, _ = tag_spec(marker)
    gamma = _check_gamma(gamma)
    q = np.asarray(quad, dtype=float)
    if q.shape != (4, 2) or not np.all(np.isfinite(q)):
        raise InputError(f"quad must be four finite (u, v) corners, got shape {q.shape}")
    img = as_bgr(image) if not (isinstance(image, np.ndarray) and image.ndim == 2 and image.dtype == np.uint8) \
        else image
    gray = img if img.ndim == 2 else cv2.cvtColor(img, cv2.COLOR_BGR2GRAY)
    side = float(np.mean(np.linalg.norm(q - np.roll(q, -1, axis=0), axis=1)))
    margin = max(_NEAR_MARGIN_SIDES * side, _NEAR_MIN_MARGIN_PX) if margin_px is None else float(margin_px)
    h, w = gray.shape
    x0, y0 = max(0, int(math.floor(q[:, 0].min() - margin))), max(0, int(math.floor(q[:, 1].min() - margin)))
    x1, y1 = min(w, int(math.ceil(q[:, 0].max() + margin)) + 1), min(h, int(math.ceil(q[:, 1].max() + margin)) + 1)
    if x1 - x0 < 8 or y1 - y0 < 8:
        return None
    crop = gray[y0:y1, x0:x1]
    k = int(min(_NEAR_MAX_ZOOM, max(1, math.ceil(_NEAR_SIDE_PX / max(side, 1.0)))))
    if k > 1:
        crop = cv2.resize(crop, None, fx=k, fy=k, interpolation=cv2.INTER_CUBIC)
    lib = _backend_for(family, "edges", "auto")
    found: list[tuple[np.ndarray, dict[str, Any]]] = []
    if lib == "apriltag":
        for d in apriltag_lib.detect(crop, (family,), (("quad_decimate", 1.0),)):
            if d.id == tid:
                quad_k = np.roll(d.corners, 2, axis=0) if has_aruco_dictionary(d.family) else d.corners
                found.append((quad_k, {"decision_margin": d.decision_margin, "hamming": d.hamming}))
    else:
        quads, ids, _ = _detector(family, "edges", ()).detectMarkers(crop)
        if ids is not None:
            found += [(np.asarray(c, dtype=float).reshape(4, 2), {}) for c, i in zip(quads, np.asarray(ids).ravel())
                      if int(i) == tid]
    if not found:
        return None
    quad_k, extra = max(found, key=lambda f: abs(cv2.contourArea(f[0].astype(np.float32))))
    # The enlarged window's pixel centres back to the image's: x = (x' + 0.5) / k - 0.5 + x0.
    back = (quad_k + 0.5) / k - 0.5 + np.array([x0, y0], dtype=float)
    det = _detection(marker.name, family, tid, lib, back, extra, gray, "edges", camera, gamma)
    if det.info["refine"] != "edges" or det.info["edge_rms_px"] > _NEAR_MAX_EDGE_RMS_PX:
        return None  # a tag this steep whose sides the edge fit could not follow: its corners are pixels off
    det.info["looked_again"] = True
    return det


# ---------------------------------------------------------------------------
# tag geometry in the rig
# ---------------------------------------------------------------------------


def corner_marker_names(name: str) -> list[str]:
    """``[NAME#0, NAME#1, NAME#2, NAME#3]``: the corner markers of tag ``NAME``."""
    return [f"{name}{CORNER_SEPARATOR}{k}" for k in range(4)]


def corner_detections(det: Detection) -> dict[str, Detection]:
    """The four corners of a found tag as detections of its corner markers ``NAME#0..3`` (the tag's score;
    ``info`` keeps ``looked_again``), for a rig whose oriented tags are expanded (:func:`expand_tag_corners`)."""
    if det.corners is None:
        return {}
    info = {"looked_again": True} if det.info.get("looked_again") else {}
    return {c: Detection(c, np.asarray(uv, float), det.score, info=dict(info))
            for c, uv in zip(corner_marker_names(det.marker), det.corners)}


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
