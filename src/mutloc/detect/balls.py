"""Coloured-ball detector with sub-pixel, perspective-corrected centres.

Pipeline, per image:

1. **Coarse search** (half resolution by default, with a full-resolution
   pass for small balls of markers it did not find): HSV hue window around each marker's nominal colour
   (red wraps around 0 deg); the saturation floor is a fraction of the
   marker's own saturation (shading scales RGB and leaves saturation alone)
   and the value floor follows the image's exposure, so shaded and dimly lit
   balls survive.  External contours of the mask are the candidate blobs; a
   RANSAC circle on each contour gives a first centre and radius that ignore
   straight occluding edges and ragged clutter.
2. **Sub-pixel rim** at full resolution, only near the blob: along rays from
   the coarse centre the colour is unmixed into ball and background
   fractions, and each ray's rim radius is the integral of the ball fraction
   across a short window around the edge (see :func:`_edges_kernel`).  That
   integral is the edge position for any symmetric blur (optics, pixel
   area), and the unmixing makes it independent of the ball's shading and
   of the background's brightness.  (Values are partly linearised first:
   see ``_MIX_GAMMA`` for why not fully.)
3. **Fit**: with a :class:`~mutloc.core.camera.Camera` the rim points become
   bearings and a circular cone is fitted robustly (IRLS, Tukey); its axis
   is the direction of the sphere centre, whose projection is reported.  The
   image of a sphere is an ellipse whose centre is *not* that projection
   (0.6 px apart for a 3 cm ball at 1 m near the corner of a 960x540,
   f = 800 px frame); the cone removes this bias and handles lens
   distortion.  Without a camera an ellipse is fitted and its centre is
   reported (the bias cannot be removed without ``K``).  A second round of
   rays from the fitted centre, windows centred on the fitted outline,
   polishes the result.  Occluded or out-of-frame parts of the rim are
   outliers of the fit, so the visible arc alone determines the ball.
4. **Choice**: each candidate is scored by the fraction of its rim that fits,
   the fit residual, the hue and chroma of the ball, how solid the blob is,
   and the length of fitting rim (bigger blobs are stronger evidence); the
   markers then take their best blobs greedily so two never share one.

Accuracy on exact supersampled renders of shaded balls (3 cm, 1-3 m,
f = 800 px, 960x540, textured background; ``tests/test_detect_balls.py``):
median error about 0.02 px clean and 0.1 px with noise, blur and JPEG.
Speed: over 100 frames/s of CPU time for four markers on one core;
``python -m mutloc.detect.balls`` measures it.

Pixels follow the SPEC: ``(0, 0)`` is the centre of the top-left pixel.
"""

from __future__ import annotations

import colorsys
import itertools
import math
import time
from collections.abc import Mapping
from dataclasses import dataclass, field
from numbers import Real
from typing import Any

import cv2
import numba
import numpy as np

from ..core.camera import Camera, project_many
from ..core.rig import Marker
from ..errors import InputError
from .base import Detection, DetectionResult, as_bgr

__all__ = ["DEFAULT_BALL_RADIUS_M", "BallSearch", "detect_balls", "time_detector"]

# Marker.extra["radius"] when a rig does not say (metres).
DEFAULT_BALL_RADIUS_M = 0.03

# A nominal colour with less saturation than this (0..1) has no usable hue:
# white, grey and black balls need a brightness test, which textured scenes
# defeat, so they are refused with a clear error instead of failing silently.
_MIN_NOMINAL_SATURATION = 0.25
_MIN_NOMINAL_VALUE = 0.2

# sRGB-encoded uint8 -> linear light (for nominal colours).
_SRGB_LUT = np.array(
    [c / 12.92 if c <= 0.04045 else ((c + 0.055) / 1.055) ** 2.4 for c in np.arange(256) / 255.0],
    dtype=np.float32,
)
_LINEAR_LUT = (np.arange(256) / 255.0).astype(np.float32)

# The values in which rim profiles of sRGB images are unmixed: encoded
# values raised to 1.7, part way to linear light.  Optics and pixel area mix
# *light* (a profile is a linear mixture only in linear values), but JPEG and
# video codecs blur the chroma of the *encoded* values (4:2:0), and a fully
# linear unmixing turns that into an edge bias of ~0.2 px that follows the
# lighting.  Measured on exact renders (tests/test_detect_balls.py), the
# exponent 1.7 keeps the median error at ~0.02 px clean, ~0.07 px blurred,
# ~0.1 px after JPEG and after blur + noise + JPEG together, where linear
# light (~2.4) gives 0.01 / 0.03 / 0.21 / 0.15 px and encoded values (1.0)
# 0.06 / 0.10 / 0.05 / 0.16 px.
_MIX_GAMMA = 1.7
_MIX_LUT = ((np.arange(256) / 255.0) ** _MIX_GAMMA).astype(np.float32)

# Sampling step along the rays (pixels).  Half a pixel keeps the trapezoid
# integral of a pixel-area-blurred step accurate to a few hundredths.
_STEP = 0.5

# Half-width (pixels) of the second, local window around each ray's edge:
# room for the blur of optics, pixels and JPEG, little for the background
# to change within.
_LOCAL_HALF_WINDOW = 2.5

# Without a camera, fitted ellipses more elongated than this are refused (a
# sphere's image reaches 1.4 only 45 deg off-axis).
_MAX_AXIS_RATIO = 1.6

# The rig check tries at most this many candidates per marker, and gives up
# (keeping each marker's best) beyond this many combinations.
_MAX_JOINT_OPTIONS = 4
_MAX_JOINT_COMBOS = 5000

# Once a blob of a marker scores this well, only bigger blobs of that
# marker are still refined (see detect_balls).
_GOOD_ENOUGH = 0.85

# Largest ball radius (full-resolution pixels) the full-resolution fallback
# of the hybrid search looks for: the half-resolution search finds balls of
# 1.5 coarse pixels and more, so this leaves a wide margin.
_FALLBACK_MAX_R = 8.0


@dataclass(frozen=True)
class BallSearch:
    """What the detector looks for for one marker (derived from its colour)."""

    name: str
    rgb: tuple[int, int, int]
    hue_deg: float
    saturation: float
    value: float
    radius_m: float = DEFAULT_BALL_RADIUS_M
    # The robot carrying the ball and the ball's position on it: balls of one
    # robot must be seen at mutually consistent places.
    robot: str | None = None
    position: np.ndarray | None = None

    @classmethod
    def from_marker(cls, name: str, marker: Marker, srgb: bool = True) -> BallSearch:
        """Validate the marker's colour; raise InputError for achromatic ones.

        The rig gives nominal sRGB colours; for linear images (``srgb=False``)
        hue and saturation are those of the linearised colour, since e.g.
        orange (255, 128, 0) has a hue of 30 deg in sRGB but 13 deg in linear
        values.
        """
        rgb = marker.color
        try:
            r, g, b = (int(c) for c in rgb)  # type: ignore[union-attr]
        except (TypeError, ValueError):
            raise InputError(f"marker {name!r}: color must be 3 integers [r, g, b] in 0..255, got {rgb!r}") from None
        if not all(0 <= c <= 255 for c in (r, g, b)):
            raise InputError(f"marker {name!r}: color must be 3 integers [r, g, b] in 0..255, got {rgb!r}")
        h, s, v = colorsys.rgb_to_hsv(r / 255.0, g / 255.0, b / 255.0)
        # Achromatic or not is judged on the nominal (sRGB) colour.
        if s < _MIN_NOMINAL_SATURATION or v < _MIN_NOMINAL_VALUE:
            kind = "black" if v < _MIN_NOMINAL_VALUE else ("white" if v > 0.85 else "grey")
            raise InputError(
                f"marker {name!r}: color [{r}, {g}, {b}] is {kind} (saturation {s:.2f}); the ball detector "
                f"matches hue and needs a saturated colour (saturation >= {_MIN_NOMINAL_SATURATION})"
            )
        radius = DEFAULT_BALL_RADIUS_M
        extra = getattr(marker, "extra", None) or {}
        if "radius" in extra:
            try:
                radius = float(extra["radius"])
            except (TypeError, ValueError):
                raise InputError(f"marker {name!r}: radius must be a number, got {extra['radius']!r}") from None
            if not (radius > 0 and math.isfinite(radius)):
                raise InputError(f"marker {name!r}: radius must be positive, got {extra['radius']!r}")
        if not srgb:
            h, s, v = colorsys.rgb_to_hsv(*(float(_SRGB_LUT[c]) for c in (r, g, b)))
        robot = getattr(marker, "robot", None)
        pos = getattr(marker, "position", None)
        pos = np.asarray(pos, float) if pos is not None and np.shape(pos) == (3,) else None
        return cls(name, (r, g, b), 360.0 * h, s, v, radius, robot, pos)


@dataclass
class _Candidate:
    """A refined blob for one marker."""

    search: BallSearch
    uv: np.ndarray
    centre_px: np.ndarray  # centre of the fitted image curve (ray origin)
    radius_px: float
    score: float
    info: dict[str, Any] = field(default_factory=dict)
    # With a camera: the ball's centre in the camera frame, from its
    # direction and apparent size (metres).
    xyz: np.ndarray | None = None
    # The fitted outline (n, 2) pixels.
    rim: np.ndarray | None = None


# ---------------------------------------------------------------------------
# public API
# ---------------------------------------------------------------------------


def detect_balls(
    image: Any,
    markers: Mapping[str, Marker],
    *,
    camera: Camera | None = None,
    min_radius_px: float = 2.0,
    hue_tol_deg: float = 12.0,
    max_radius_px: float | None = None,
    downscale: int | None = None,
    srgb: bool = True,
    max_candidates: int = 3,
    min_score: float = 0.25,
    distance_range_m: tuple[float, float] = (0.05, 200.0),
) -> DetectionResult:
    """Find the coloured balls of ``markers`` in a BGR image.

    Parameters
    ----------
    image:
        ``uint8`` BGR ``(H, W, 3)`` (grayscale and float images are converted
        by :func:`~mutloc.detect.base.as_bgr`).
    markers:
        ``{name: Marker}``; markers without a ``color`` are ignored.  A colour
        without a usable hue (white, grey, black) raises :class:`InputError`.
        ``Marker.extra["radius"]`` (metres, default 0.03) is used with
        ``camera`` to reject blobs of implausible size and to report distance.
    camera:
        The camera that took the image.  With it the reported pixel is the
        projection of the sphere centre (perspective-corrected, distortion
        aware); without it, the centre of the fitted ellipse.
    min_radius_px, max_radius_px:
        Image radius range of a ball (max defaults to a third of the shorter
        image side).
    hue_tol_deg:
        Half-width of the hue window around the nominal hue.  Light of a
        strong colour (or a bad white balance) turns hues: raise it then.
    downscale:
        Factor of the coarse search image; ``None`` picks the largest of 1, 2,
        4 that keeps ``min_radius_px`` at least 1.5 coarse pixels, and when
        that is 1 (the default ``min_radius_px=2``) searches at half
        resolution and falls back to full resolution (small blobs only) for
        markers left without a candidate.
    srgb:
        Pixel values are sRGB-encoded (cameras, PNG, JPEG).  ``False`` for
        linear images.
    max_candidates:
        Blobs per marker refined at full resolution (the best coarse ones).
    min_score:
        Detections scoring below this are reported missing.
    distance_range_m:
        With ``camera``: distances (from the ball's apparent size) outside
        this range make a blob implausible.

    Returns
    -------
    DetectionResult
        ``detections[name]`` has ``uv``, ``score`` in (0, 1] and ``info``
        (``radius_px``, ``rim_fraction`` (share of the rim that fits; lower
        when occluded), ``rms_px``, ``hue_deg``, ``chroma``, ``ellipse`` (the
        fitted outline) and, with a camera, ``distance_m`` to the ball's
        centre); every marker with a
        colour that was not found is listed in ``missing``.  Never raises for
        "not found".
    """
    img = as_bgr(image)
    if not isinstance(markers, Mapping):
        raise InputError(f"markers must be a mapping name -> Marker, got {type(markers).__name__}")
    for what, val in (("min_radius_px", min_radius_px), ("hue_tol_deg", hue_tol_deg)):
        if isinstance(val, bool) or not (isinstance(val, Real) and math.isfinite(val) and val > 0):
            raise InputError(f"{what} must be a positive number, got {val!r}")
    try:
        dmin, dmax = (float(x) for x in distance_range_m)
    except (TypeError, ValueError):
        raise InputError(f"distance_range_m must be (min, max) in metres, got {distance_range_m!r}") from None
    if not (0 <= dmin < dmax):
        raise InputError(f"distance_range_m must be (min, max) with 0 <= min < max, got {distance_range_m!r}")
    if max_radius_px is not None and (
        isinstance(max_radius_px, bool)
        or not (isinstance(max_radius_px, Real) and math.isfinite(max_radius_px) and max_radius_px > min_radius_px)
    ):
        raise InputError(f"max_radius_px must be a number above min_radius_px, got {max_radius_px!r}")
    if isinstance(max_candidates, bool) or not (isinstance(max_candidates, (int, np.integer)) and max_candidates >= 1):
        raise InputError(f"max_candidates must be a positive integer, got {max_candidates!r}")
    if camera is not None and not isinstance(camera, Camera):
        raise InputError(f"camera must be a mutloc Camera, got {type(camera).__name__}")
    if hue_tol_deg >= 90:
        raise InputError(f"hue_tol_deg must be below 90, got {hue_tol_deg!r}")
    searches: list[BallSearch] = []
    for name, m in markers.items():
        if getattr(m, "color", None) is None:
            continue
        searches.append(BallSearch.from_marker(str(name), m, srgb=srgb))
    result = DetectionResult()
    if not searches:
        return result

    Himg, Wimg = img.shape[:2]
    rmax = float(max_radius_px) if max_radius_px is not None else min(Himg, Wimg) / 3.0
    k = _pick_downscale(downscale, min_radius_px, Wimg, Himg)
    # Hybrid search (the default when min_radius_px needs full resolution):
    # the coarse search runs at half resolution, which finds every ball of
    # more than ~1.5 coarse pixels, and only markers it leaves without a
    # candidate are searched again at full resolution, for small blobs.
    fallback = downscale is None and k == 1 and min(Wimg, Himg) // 2 >= 120
    if fallback:
        k = 2
    lut = _MIX_LUT if srgb else _LINEAR_LUT
    # Exposure from the full image (every 4th row and column): the same
    # floor whatever the search resolution.
    v_floor = _value_floor(img)

    # Balls that share a robot with another searched ball at a different
    # place can be checked against each other (needs a camera for their 3-D
    # positions).
    mates = _rig_mates(searches) if camera is not None else {}

    cam = _CameraContext(camera) if camera is not None else None

    def refine(s: BallSearch, blob: tuple[float, float, float, float, float]) -> _Candidate | None:
        cu, cv_, r, _q, fill = blob
        c = _refine(img, lut, s, np.array([cu, cv_]), r, fill, cam, hue_tol_deg, min_radius_px, rmax, (dmin, dmax))
        return c if c is not None and c.score >= min_score else None

    per_marker: dict[str, list[_Candidate]] = {}
    skipped: dict[str, list[tuple[float, float, float, float, float]]] = {}

    def search(level: list[BallSearch], k: int, blob_rmax: float) -> None:
        coarse = img if k == 1 else cv2.resize(img, (Wimg // k, Himg // k), interpolation=cv2.INTER_AREA)
        hsv = cv2.cvtColor(coarse, cv2.COLOR_BGR2HSV_FULL)
        sx = Wimg / coarse.shape[1]
        sy = Himg / coarse.shape[0]
        for s, mask in zip(level, _hue_masks(hsv, level, hue_tol_deg, v_floor)):
            blobs = _coarse_blobs(mask, sx, sy, min_radius_px, blob_rmax)
            # Best first: round, solid, vivid and (other things equal) big, as
            # in the final score; blobs that are clearly not discs are not
            # refined.
            blobs = [b for b in blobs if b[3] >= 0.25]
            blobs.sort(key=lambda b: -b[3] * _evidence(2.0 * math.pi * b[2]) * _vivid(_blob_chroma(coarse, b, sx, sy)))
            good_r = math.inf
            found: list[_Candidate] = []
            skipped[s.name] = []
            for blob in blobs[: int(max_candidates)]:
                # Once a blob fits well, a lower-ranked blob can only win by
                # being bigger (more rim evidence): smaller ones are not refined
                # (unless the rig check below asks for them), which saves time in
                # cluttered scenes.
                if good_r == math.inf or blob[2] > good_r:
                    c = refine(s, blob)
                    if c is not None:
                        found.append(c)
                        if c.score >= _GOOD_ENOUGH:
                            good_r = min(good_r, c.radius_px)
                else:
                    skipped[s.name].append(blob)
            per_marker[s.name] = found

    search(searches, k, rmax)
    if fallback:
        lost = [s for s in searches if not per_marker[s.name]]
        if lost:
            # Balls big enough for the half-resolution search were found
            # there: full resolution only looks for the small ones.
            search(lost, 1, min(rmax, _FALLBACK_MAX_R))

    chosen: list[_Candidate] = []
    for group in mates.values():
        # Per robot, the combination of blobs (or none) that best agrees
        # with the rig: balls of one robot keep their mutual distances.
        picked, consistent = _choose_consistent(group, per_marker, min_score)
        if not consistent and any(skipped[g.name] for g in group):
            # Something does not fit: the blobs passed over may hold the
            # right ball.
            for g in group:
                per_marker[g.name] += [c for b in skipped[g.name] if (c := refine(g, b)) is not None]
            picked, _ = _choose_consistent(group, per_marker, min_score)
        chosen.extend(picked)
    rest = [c for s in searches if s.robot not in mates for c in per_marker[s.name]]

    # Greedy one-to-one assignment: the best-scoring (marker, blob) pairs first,
    # so a blob is never reported for two markers of similar colour.
    taken: list[_Candidate] = []
    for c in sorted(chosen, key=lambda c: -c.score) + sorted(rest, key=lambda c: -c.score):
        if c.search.name in result.detections:
            continue
        if any(_same_blob(c, t) for t in taken):
            continue
        taken.append(c)
        c.info["ellipse"] = _ellipse_info(c.rim)
        result.detections[c.search.name] = Detection(marker=c.search.name, uv=c.uv, score=c.score, info=c.info)
    result.missing = [s.name for s in searches if s.name not in result.detections]
    return result


def _rig_mates(searches: list[BallSearch]) -> dict[str, list[BallSearch]]:
    """Per robot, its searched balls, for robots with two or more at distinct known places."""
    groups: dict[str, list[BallSearch]] = {}
    for s in searches:
        if s.robot is not None and s.position is not None:
            groups.setdefault(s.robot, []).append(s)
    out = {}
    for robot, g in groups.items():
        pos = np.array([s.position for s in g])
        if len(g) >= 2 and np.ptp(pos, axis=0).max() > 1e-6:
            out[robot] = g
    return out


def _same_blob(a: _Candidate, b: _Candidate) -> bool:
    return bool(np.hypot(*(a.centre_px - b.centre_px)) < 0.5 * (a.radius_px + b.radius_px))


def _range_sigma(c: _Candidate) -> float:
    """Allowed error of a ball's distance (m): Z dr / r for dr = 0.2 px, plus 3 % for its true size."""
    z = float(c.info["distance_m"])
    return z * (0.03 + 0.2 / max(c.radius_px, 1e-9))


def _choose_consistent(
    group: list[BallSearch], per_marker: Mapping[str, list[_Candidate]], min_score: float
) -> tuple[list[_Candidate], bool]:
    """The candidates of one robot's balls (or none of some) that best fit the rig.

    Maximises the sum of log scores, with a marker left out costing a score
    below ``min_score``, plus, for each pair of chosen balls, the Gaussian
    log-likelihood of their distance in the camera frame (from directions and
    apparent sizes) given their distance on the robot; the error allowed
    grows with range (see :func:`_range_sigma`).  Exhaustive: a few markers
    with a few candidates each.  Also says whether the choice is clean:
    every marker with a candidate has one and every pair is within 3 sigma.
    """
    top = [sorted(per_marker.get(s.name, []), key=lambda c: -c.score)[:_MAX_JOINT_OPTIONS] for s in group]
    options: list[list[_Candidate | None]] = [[None, *t] for t in top]
    if math.prod(len(o) for o in options) > _MAX_JOINT_COMBOS:
        # Too many to try (a robot with many balls): each marker's best.
        return [t[0] for t in top if t], False
    n = len(group)
    miss = math.log(0.5 * min_score)
    best_val = -math.inf
    best: tuple[_Candidate | None, ...] = tuple(None for _ in group)
    best_worst = 0.0
    for combo in itertools.product(*options):
        val = 0.0
        for c in combo:
            val += miss if c is None else math.log(c.score)
        if val <= best_val:
            continue  # consistency can only lower it
        worst = 0.0
        for i in range(n):
            ci = combo[i]
            if ci is None or ci.xyz is None:
                continue
            for j in range(i + 1, n):
                cj = combo[j]
                if cj is None or cj.xyz is None:
                    continue
                if _same_blob(ci, cj):
                    val = -math.inf
                    break
                L = float(np.linalg.norm(group[i].position - group[j].position))  # type: ignore[operator]
                if L < 1e-6:
                    continue  # same place on the robot: nothing to check
                z = (float(np.linalg.norm(ci.xyz - cj.xyz)) - L) / (0.01 + _range_sigma(ci) + _range_sigma(cj))
                val -= 0.5 * z * z
                worst = max(worst, abs(z))
            if val == -math.inf:
                break
        if val > best_val:
            best_val, best, best_worst = val, combo, worst
    clean = best_worst <= 3.0 and all(c is not None or not opts[1:] for c, opts in zip(best, options))
    return [c for c in best if c is not None], clean


# ---------------------------------------------------------------------------
# coarse search
# ---------------------------------------------------------------------------


def _pick_downscale(downscale: int | None, min_radius_px: float, w: int, h: int) -> int:
    """Coarse-search factor: the largest of 1, 2, 4 keeping ``min_radius_px / k >= 1.5``.

    The hue mask and contours are the frame-sized part of the work, so a
    smaller search image is faster; everything that needs accuracy is done at
    full resolution anyway.  But area-averaging mixes a small ball with its
    background, and below ~1.5 coarse pixels of radius its hue no longer
    survives reliably (balls of 2 px were missed about one time in ten at
    half resolution).
    """
    if downscale is not None:
        if isinstance(downscale, bool) or not (isinstance(downscale, (int, np.integer)) and downscale >= 1):
            raise InputError(f"downscale must be a positive integer, got {downscale!r}")
        k = int(downscale)
    else:
        k = 1
        for cand in (2, 4):
            if min_radius_px / cand >= 1.5 and min(w, h) // cand >= 120:
                k = cand
    # Never shrink below a usable search image.
    while k > 1 and (w // k < 16 or h // k < 16):
        k //= 2
    return k


def _value_floor(img: np.ndarray) -> int:
    """Value threshold adapted to the image's exposure.

    Hue is meaningless in near-black pixels (noise dominates), but a dim image
    must still find its dim balls: the floor is a fraction of the 99th
    percentile of V, kept within [12, 40].  Every 4th row and column is
    plenty for a percentile.
    """
    sub = cv2.cvtColor(np.ascontiguousarray(img[::4, ::4]), cv2.COLOR_BGR2HSV_FULL)
    hist = np.bincount(cv2.extractChannel(sub, 2).ravel(), minlength=256)
    cum = np.cumsum(hist)
    p99 = int(np.searchsorted(cum, 0.99 * cum[-1]))
    return int(np.clip(0.12 * p99, 12, 40))


def _hue_masks(hsv: np.ndarray, searches: list[BallSearch], tol_deg: float, v_floor: int) -> list[np.ndarray]:
    """One mask per marker: hue within ``tol_deg`` of its own, saturated and bright enough.

    Shading scales RGB, which leaves saturation unchanged; haze, highlights
    and JPEG chroma blur lower it, so the saturation floor is a fraction of
    the nominal saturation (the lowest over the markers: one pass for all).
    The hue test is a lookup table on the hue channel, which handles red's
    wrap-around for free and serves eight markers per pass, one bit each.
    """
    hue = cv2.extractChannel(hsv, 0)
    s_floor = min(int(np.clip(0.4 * 255 * s.saturation, 40, 110)) for s in searches)
    sv = cv2.inRange(hsv, (0, s_floor, v_floor), (255, 255, 255))
    # Degrees of each 8-bit HSV_FULL hue bin; half a bin (0.7 deg) of slack.
    deg = np.arange(256) * (360.0 / 256.0)
    masks: list[np.ndarray] = []
    for start in range(0, len(searches), 8):
        chunk = searches[start : start + 8]
        table = np.zeros(256, np.uint8)
        for bit, s in enumerate(chunk):
            dh = np.abs((deg - s.hue_deg + 180.0) % 360.0 - 180.0)
            table[dh <= tol_deg + 0.71] |= np.uint8(1 << bit)
        label = cv2.bitwise_and(cv2.LUT(hue, table), sv)
        masks.extend(np.bitwise_and(label, np.uint8(1 << bit)) for bit in range(len(chunk)))
    return masks


def _coarse_blobs(
    mask: np.ndarray, sx: float, sy: float, min_r: float, max_r: float
) -> list[tuple[float, float, float, float, float]]:
    """Candidate blobs ``(u, v, radius, quality, fill)`` in full-resolution pixels.

    Each external contour may hold several circles: a ball touching another
    blob of a similar hue (a printed disc behind it, a second ball) merges
    with it in the mask, so after the best circle of a contour the points it
    does not explain are searched again.
    """
    contours, _ = cv2.findContours(mask, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
    scale = 0.5 * (sx + sy)
    # A contour through pixel centres of a disc of radius r has ~0.87 * 2 pi r
    # points (8-connected); a partly hidden ball still shows over half of it.
    min_len = max(4, int(0.5 * 0.87 * 2 * math.pi * (0.7 * min_r / scale)))
    out = []
    for c in [c for c in contours if len(c) >= min_len]:
        cpts = c.reshape(-1, 2).astype(np.float64)  # coarse pixel centres
        area = cv2.contourArea(c) + 0.5 * len(c) + 1.0  # pixel count of the filled blob
        r_eq = math.sqrt(area / math.pi) * scale
        if r_eq < 0.6 * min_r:
            continue
        if len(cpts) < 6:
            m = cpts.mean(axis=0)
            out.append(((m[0] + 0.5) * sx - 0.5, (m[1] + 0.5) * sy - 0.5, r_eq, 0.3, 1.0))
            continue
        # No circle is much bigger than the contour holding it.
        span = 0.5 * float(np.hypot(*(cpts.max(axis=0) - cpts.min(axis=0))))
        rmin_c, rmax_c = 0.5 * min_r / scale, min(1.2 * span + 1.0, 1.5 * max_r / scale)
        rest = cpts
        for _ in range(3):
            fit = _ransac_circle(rest, max(1.0, 0.08 * r_eq / scale), rmin_c, rmax_c)
            if fit is None:
                break
            cu, cv_, r, frac = fit
            # Support: how much of the circle's own circumference the contour
            # covers (a clean disc ~1, a rectangle's inscribed circle little).
            support = min(1.0, frac * len(rest) / (0.87 * 2 * math.pi * max(r, 0.5)))
            if support >= 0.25:
                fill = _fill_fraction(mask, cu, cv_, r + 0.5)
                # The contour runs through the outermost pixel centres: half
                # a (coarse) pixel inside the true rim.
                R = (r + 0.5) * scale
                if 0.6 * min_r <= R <= 1.5 * max_r:
                    # Quality: support times how well the blob fills its
                    # circle (a ring or a crescent does not).
                    out.append(((cu + 0.5) * sx - 0.5, (cv_ + 0.5) * sy - 0.5, R, support * fill, fill))
            # Whatever this circle explains is set aside; the rest may hold
            # another one.
            far = np.abs(np.hypot(rest[:, 0] - cu, rest[:, 1] - cv_) - r) > 2.0 * max(1.0, 0.08 * r)
            rest = rest[far]
            if len(rest) < max(12, min_len):
                break
    return out


def _fill_fraction(mask: np.ndarray, cu: float, cv_: float, r: float) -> float:
    """Share of the disc ``(cu, cv_, r)`` (mask pixels) that is set in ``mask``."""
    return float(_fill_kernel(mask, float(cu), float(cv_), float(r)))


@numba.njit(cache=True, fastmath=False)
def _fill_kernel(mask, cu, cv_, r):
    h, w = mask.shape
    x0, x1 = max(0, int(math.floor(cu - r))), min(w, int(math.ceil(cu + r)) + 1)
    y0, y1 = max(0, int(math.floor(cv_ - r))), min(h, int(math.ceil(cv_ + r)) + 1)
    n = 0
    k = 0
    r2 = r * r
    for y in range(y0, y1):
        dy2 = (y - cv_) ** 2
        for x in range(x0, x1):
            if (x - cu) ** 2 + dy2 <= r2:
                n += 1
                if mask[y, x] != 0:
                    k += 1
    return k / n if n > 0 else 0.0


# Fixed random triplets: detections are repeatable.
_TRIPLETS = np.random.default_rng(12345).random((48, 3))


def _ransac_circle(pts: np.ndarray, tol: float, rmin: float, rmax: float) -> tuple[float, float, float, float] | None:
    """Circle (radius in [rmin, rmax]) through most of the contour ``pts``: ``(u, v, r, inlier fraction)``.

    A straight occluding edge or a ragged side of the blob does not pull it,
    unlike a least-squares circle or the blob's moments.
    """
    if len(pts) < 6:
        return None
    ok, cu, cv_, r, frac = _ransac_circle_kernel(np.ascontiguousarray(pts), float(tol), _TRIPLETS, rmin, rmax)
    return (cu, cv_, r, frac) if ok else None


@numba.njit(cache=True, fastmath=False)
def _solve3(M, b, x) -> bool:
    """``x = M^-1 b`` for a 3x3 ``M`` by cofactors; False if singular."""
    c00 = M[1, 1] * M[2, 2] - M[1, 2] * M[2, 1]
    c01 = M[1, 2] * M[2, 0] - M[1, 0] * M[2, 2]
    c02 = M[1, 0] * M[2, 1] - M[1, 1] * M[2, 0]
    det = M[0, 0] * c00 + M[0, 1] * c01 + M[0, 2] * c02
    if not (abs(det) > 1e-300) or not math.isfinite(det):
        return False
    c10 = M[0, 2] * M[2, 1] - M[0, 1] * M[2, 2]
    c11 = M[0, 0] * M[2, 2] - M[0, 2] * M[2, 0]
    c12 = M[0, 1] * M[2, 0] - M[0, 0] * M[2, 1]
    c20 = M[0, 1] * M[1, 2] - M[0, 2] * M[1, 1]
    c21 = M[0, 2] * M[1, 0] - M[0, 0] * M[1, 2]
    c22 = M[0, 0] * M[1, 1] - M[0, 1] * M[1, 0]
    x[0] = (c00 * b[0] + c10 * b[1] + c20 * b[2]) / det
    x[1] = (c01 * b[0] + c11 * b[1] + c21 * b[2]) / det
    x[2] = (c02 * b[0] + c12 * b[1] + c22 * b[2]) / det
    return True


@numba.njit(cache=True, fastmath=False)
def _kasa_kernel(pts, mask, out) -> bool:
    """Algebraic least-squares circle of ``pts[mask]`` into ``out`` = (u, v, r)."""
    n = pts.shape[0]
    mx = 0.0
    my = 0.0
    k = 0
    for i in range(n):
        if mask[i]:
            mx += pts[i, 0]
            my += pts[i, 1]
            k += 1
    if k < 3:
        return False
    mx /= k
    my /= k
    # Centred for conditioning: x^2 + y^2 = a x + b y + c.
    M = np.zeros((3, 3))
    rhs = np.zeros(3)
    for i in range(n):
        if mask[i]:
            x = pts[i, 0] - mx
            y = pts[i, 1] - my
            z = x * x + y * y
            row = (x, y, 1.0)
            for r in range(3):
                rhs[r] += row[r] * z
                for c in range(3):
                    M[r, c] += row[r] * row[c]
    sol = np.empty(3)
    if not _solve3(M, rhs, sol):
        return False
    cx = 0.5 * sol[0]
    cy = 0.5 * sol[1]
    r2 = sol[2] + cx * cx + cy * cy
    if not (r2 > 0.0) or not math.isfinite(r2):
        return False
    out[0] = cx + mx
    out[1] = cy + my
    out[2] = math.sqrt(r2)
    return True


@numba.njit(cache=True, fastmath=False)
def _ransac_circle_kernel(pts, tol, triplets, rmin, rmax):
    n = pts.shape[0]
    best = -1
    bu = bv = br = 0.0
    for h in range(triplets.shape[0]):
        # Three points spaced along the contour by a third of it (a lone
        # ball: well-conditioned circles), a sixth or a tenth (a ball whose
        # outline is only a part of a contour it shares with another blob).
        div = 3 if h % 3 == 0 else (6 if h % 3 == 1 else 10)
        sp = max(1, n // div)
        i0 = int(triplets[h, 0] * n) % n
        i1 = (i0 + sp + int(triplets[h, 1] * 0.5 * sp)) % n
        i2 = (i1 + sp + int(triplets[h, 2] * 0.5 * sp)) % n
        ax, ay = pts[i0, 0], pts[i0, 1]
        bx, by = pts[i1, 0], pts[i1, 1]
        cx, cy = pts[i2, 0], pts[i2, 1]
        d = 2.0 * (ax * (by - cy) + bx * (cy - ay) + cx * (ay - by))
        if abs(d) < 1e-9:
            continue
        a2 = ax * ax + ay * ay
        b2 = bx * bx + by * by
        c2 = cx * cx + cy * cy
        ux = (a2 * (by - cy) + b2 * (cy - ay) + c2 * (ay - by)) / d
        uy = (a2 * (cx - bx) + b2 * (ax - cx) + c2 * (bx - ax)) / d
        r = math.hypot(ax - ux, ay - uy)
        # Nearly collinear points give huge circles that hug straight edges.
        if r < rmin or r > rmax:
            continue
        cnt = 0
        for i in range(n):
            if abs(math.hypot(pts[i, 0] - ux, pts[i, 1] - uy) - r) <= tol:
                cnt += 1
        if cnt > best:
            best = cnt
            bu, bv, br = ux, uy, r
    if best < 5:
        return False, 0.0, 0.0, 0.0, 0.0
    # Polish: least squares on the inliers, twice (the inlier set of the
    # refined circle is a little larger).
    out = np.array([bu, bv, br])
    mask = np.empty(n, np.bool_)
    k = 0
    for _ in range(2):
        k = 0
        for i in range(n):
            mask[i] = abs(math.hypot(pts[i, 0] - out[0], pts[i, 1] - out[1]) - out[2]) <= tol
            if mask[i]:
                k += 1
        if k < 5 or not _kasa_kernel(pts, mask, out):
            return False, 0.0, 0.0, 0.0, 0.0
    k = 0
    for i in range(n):
        if abs(math.hypot(pts[i, 0] - out[0], pts[i, 1] - out[1]) - out[2]) <= tol:
            k += 1
    return True, out[0], out[1], out[2], k / n


# ---------------------------------------------------------------------------
# sub-pixel refinement
# ---------------------------------------------------------------------------
#
# The work here is many tiny loops (a few dozen rays of a few dozen samples,
# a 3x3 solve per IRLS step); in NumPy the per-call overhead alone would cost
# about a millisecond per ball, so the kernels are compiled with Numba.


@numba.njit(cache=True, fastmath=False)
def _sample(img, lut, x, y, out) -> None:
    """Bilinear sample of the linearised image at ``(x, y)`` in [0, W-1] x [0, H-1]."""
    H = img.shape[0]
    W = img.shape[1]
    x0 = int(math.floor(x))
    y0 = int(math.floor(y))
    # The last row/column: interpolate from the one before (weight 1).
    x0 = min(x0, W - 2)
    y0 = min(y0, H - 2)
    fx = x - x0
    fy = y - y0
    w00 = (1.0 - fx) * (1.0 - fy)
    w01 = fx * (1.0 - fy)
    w10 = (1.0 - fx) * fy
    w11 = fx * fy
    for c in range(3):
        out[c] = (
            w00 * lut[img[y0, x0, c]]
            + w01 * lut[img[y0, x0 + 1, c]]
            + w10 * lut[img[y0 + 1, x0, c]]
            + w11 * lut[img[y0 + 1, x0 + 1, c]]
        )


@numba.njit(cache=True, fastmath=False)
def _edges_kernel(img, lut, cx, cy, ang, rexp, h, w2, step, e, valid, inner, contrast) -> None:
    """Sub-pixel rim radius along each ray ``(cx, cy) + t (cos a, sin a)``.

    The window ``t in rexp[i] +- h`` is sampled every ``step`` pixels, and
    the edge is found in it, then again in a window of ``+- w2`` around that
    first estimate (see :func:`_unmix_edge`).  In a window, the first two
    samples give the ray's ball colour B, the last two its background
    colour G, and each sample is unmixed into
    ``p = beta B + gamma G``.  With a shading factor s on the ball and a
    brightness factor g on the background, a pixel covering a fraction a of
    ball has beta = a s and gamma = (1 - a) g, so ``beta / (beta + gamma)``
    is exactly a wherever a pixel is pure ball or pure background, however
    they are lit: neither the limb darkening of a shaded ball nor a textured
    background biases the edge; only the one or two mixed pixels feel the
    small local change of brightness.  The rim is then the start of the
    window plus the integral of that fraction, which for a symmetric blur
    (optics, pixel area, JPEG) is the position of the step.

    The unmixing needs B and G to differ in colour, not only in brightness;
    when they do not (a background of the ball's own hue, or black) the
    fraction falls back to the projection on the segment G -> B, which
    assumes constant shading across the window.

    Outputs: ``e`` (NaN where invalid), ``valid``, ``inner`` (B per ray) and
    ``contrast`` (|B - G|).
    """
    H = img.shape[0]
    W = img.shape[1]
    n = ang.shape[0]
    K = int(round(2.0 * h / step)) + 1
    P = np.empty((K, 3))
    alpha = np.empty(K)
    B = np.empty(3)
    for i in range(n):
        valid[i] = False
        e[i] = np.nan
        contrast[i] = 0.0
        for c in range(3):
            inner[i, c] = np.nan
        cs = math.cos(ang[i])
        sn = math.sin(ang[i])
        t0 = rexp[i] - h
        t1 = t0 + (K - 1) * step
        xa = cx + cs * t0
        xb = cx + cs * t1
        ya = cy + sn * t0
        yb = cy + sn * t1
        # Rays leaving the image cannot be measured.
        if min(xa, xb) < 0.0 or max(xa, xb) > W - 1 or min(ya, yb) < 0.0 or max(ya, yb) > H - 1:
            continue
        for j in range(K):
            t = t0 + j * step
            _sample(img, lut, cx + cs * t, cy + sn * t, P[j])
        # First over the whole window, then over a window of +-w2 around
        # that first edge: the colours next to the rim are the ones that
        # mix in its pixels (a background that changes a few pixels out, a
        # poster's border, must not count).
        ok, ei, con = _unmix_edge(P, 0, K - 1, step, alpha, B)
        if not ok:
            continue
        j0 = int(round((ei - w2) / step))
        j1 = int(round((ei + w2) / step))
        if j0 > 0 or j1 < K - 1:
            j0 = max(j0, 0)
            j1 = min(j1, K - 1)
            if j1 - j0 < 6:
                continue
            ok, e2, con = _unmix_edge(P, j0, j1, step, alpha, B)
            if not ok:
                continue
            ei = t0 + j0 * step + e2
        else:
            ei = t0 + ei
        for c in range(3):
            inner[i, c] = B[c]
        contrast[i] = con
        if ei > t0 + step and ei < t1 - step:
            valid[i] = True
            e[i] = ei


@numba.njit(cache=True, fastmath=False)
def _unmix_edge(P, j0, j1, step, alpha, B):
    """Edge position (relative to sample ``j0``) of the profile ``P[j0..j1]``.

    Writes the ball colour B (first two samples) and returns
    ``(ok, edge, contrast)``; not ok when the profile is not one clean
    ball-to-background step.
    """
    G = np.empty(3)
    dd = 0.0
    bb = 0.0
    gg = 0.0
    bg = 0.0
    for c in range(3):
        B[c] = 0.5 * (P[j0, c] + P[j0 + 1, c])
        G[c] = 0.5 * (P[j1 - 1, c] + P[j1, c])
        dd += (B[c] - G[c]) ** 2
        bb += B[c] * B[c]
        gg += G[c] * G[c]
        bg += B[c] * G[c]
    contrast = math.sqrt(dd)
    if dd <= 1e-12 or contrast <= 0.015:
        return False, 0.0, contrast
    det = bb * gg - bg * bg
    sin2 = det / max(bb * gg, 1e-30)
    wch = min(max((sin2 - 0.02) / 0.08, 0.0), 1.0)
    for j in range(j0, j1 + 1):
        pb = 0.0
        pg = 0.0
        pd = 0.0
        for c in range(3):
            pb += P[j, c] * B[c]
            pg += P[j, c] * G[c]
            pd += (P[j, c] - G[c]) * (B[c] - G[c])
        a = pd / dd
        if wch > 0.0:
            gam = (bb * pg - bg * pb) / det
            bet = (gg * pb - bg * pg) / det
            # Floor on the denominator: a pixel much darker than both sides
            # (noise) must not blow up.
            a = wch * bet / max(bet + gam, 0.25) + (1.0 - wch) * a
        alpha[j] = a
    integ = 0.0
    tv = 0.0
    amax = -1e30
    amin = 1e30
    for j in range(j0, j1 + 1):
        integ += alpha[j]
        amax = max(amax, alpha[j])
        amin = min(amin, alpha[j])
        if j > j0:
            tv += abs(alpha[j] - alpha[j - 1])
    edge = step * (integ - 0.5 * (alpha[j0] + alpha[j1]))
    # A clean profile goes from ~1 to ~0 without large excursions; others
    # hold a second edge (occluder, clutter) inside the window.
    ok = math.isfinite(edge) and amax < 1.35 and amin > -0.35 and tv < 1.8
    return ok, edge, contrast


@numba.njit(cache=True, fastmath=False)
def _median_inplace(a, k) -> float:
    """Median of ``a[:k]`` (k >= 1; sorts it in place).

    Insertion sort: k is at most a hundred, and it compiles in a fraction of
    the time ``np.median`` takes.
    """
    for i in range(1, k):
        x = a[i]
        j = i - 1
        while j >= 0 and a[j] > x:
            a[j + 1] = a[j]
            j -= 1
        a[j + 1] = x
    if k % 2 == 1:
        return a[k // 2]
    return 0.5 * (a[k // 2 - 1] + a[k // 2])


@numba.njit(cache=True, fastmath=False)
def _cone_fit_kernel(bear, fin, init, f, d, w):
    """Robust circular cone ``b . d = cos(theta)`` through the rim's bearings.

    ``bear`` (n, 3) are unit bearings, usable where ``fin``.  The fit is
    linear in ``m = d / cos(theta)`` (``b . m = 1``), whose residual is the
    angular distance to the cone times a constant, i.e. the geometric fit to
    first order; IRLS with Tukey weights starts from the rays in ``init``.
    Writes the axis ``d`` and the final weights ``w``; returns
    ``(ok, cos_theta, rms_px)`` with ``f`` the focal length in pixels.
    """
    n = bear.shape[0]
    for i in range(n):
        w[i] = 1.0 if (fin[i] and init[i]) else 0.0
    m = np.empty(3)
    res = np.zeros(n)
    absr = np.empty(n)
    cos_t = 0.0
    for it in range(8):
        M = np.zeros((3, 3))
        rhs = np.zeros(3)
        cnt = 0
        for i in range(n):
            if w[i] > 0.0:
                cnt += 1
                for r in range(3):
                    rhs[r] += w[i] * bear[i, r]
                    for c in range(3):
                        M[r, c] += w[i] * bear[i, r] * bear[i, c]
        if cnt < 5:
            return False, 0.0, 0.0
        # Eigenvalues of M ~ n and ~ n theta^2 / 2: fine in double
        # precision down to rims of a couple of pixels.
        if not _solve3(M, rhs, m):
            return False, 0.0, 0.0
        m0, m1, m2 = m[0], m[1], m[2]
        nm = math.sqrt(m0 * m0 + m1 * m1 + m2 * m2)
        if not (nm > 1.0 and math.isfinite(nm)) or m2 <= 0.0:
            return False, 0.0, 0.0
        d[0] = m0 / nm
        d[1] = m1 / nm
        d[2] = m2 / nm
        cos_t = 1.0 / nm
        sin_t = math.sqrt(max(1.0 - cos_t * cos_t, 1e-18))
        k = 0
        for i in range(n):
            res[i] = ((bear[i, 0] * d[0] + bear[i, 1] * d[1] + bear[i, 2] * d[2]) - cos_t) / sin_t * f
            if w[i] > 0.0:
                absr[k] = abs(res[i])
                k += 1
        # Tukey biweight at 4 robust sigmas, the sigma floored at 0.08 px so
        # clean data keeps all its points.
        sig = max(1.4826 * _median_inplace(absr, k), 0.08)
        cthr = 4.0 * sig
        change = 0.0
        for i in range(n):
            wn = 0.0
            if fin[i]:
                u = res[i] / cthr
                if abs(u) < 1.0:
                    wn = (1.0 - u * u) ** 2
            change = max(change, abs(wn - w[i]))
            w[i] = wn
        if it >= 1 and change < 0.02:
            break
    sw = 0.0
    s2 = 0.0
    for i in range(n):
        sw += w[i]
        s2 += w[i] * res[i] * res[i]
    if sw < 3.0:
        return False, 0.0, 0.0
    return True, cos_t, math.sqrt(s2 / sw)


class _CameraContext:
    """A camera and what the refinement needs of it, computed once per image."""

    def __init__(self, camera: Camera) -> None:
        self.camera = camera
        self.f = 0.5 * float(camera.K[0, 0] + camera.K[1, 1])
        self.pinhole = not np.any(camera.dist)
        self.Kinv = np.linalg.inv(camera.K)


def _cone_rim(camera: Camera, d: np.ndarray, cos_t: float, n: int = 48) -> np.ndarray | None:
    """Pixels (n, 2) of the cone's rim: the outline of the sphere's image."""
    uv = np.empty((n, 2))
    _cone_rim_kernel(camera.K, camera.dist, d, cos_t, uv)
    return uv if np.all(np.isfinite(uv)) else None


@numba.njit(cache=True, fastmath=False)
def _cone_rim_kernel(K, dist, d, cos_t, uv) -> None:
    n = uv.shape[0]
    sin_t = math.sqrt(max(1.0 - cos_t * cos_t, 0.0))
    # Orthonormal e1, e2 perpendicular to d (d[2] > 0, so never degenerate).
    h = math.hypot(d[0], d[2])
    e10, e11, e12 = d[2] / h, 0.0, -d[0] / h
    e20 = d[1] * e12 - d[2] * e11
    e21 = d[2] * e10 - d[0] * e12
    e22 = d[0] * e11 - d[1] * e10
    rays = np.empty((n, 3))
    for i in range(n):
        phi = i * (2.0 * math.pi / n)
        c = math.cos(phi)
        sn = math.sin(phi)
        rays[i, 0] = cos_t * d[0] + sin_t * (c * e10 + sn * e20)
        rays[i, 1] = cos_t * d[1] + sin_t * (c * e11 + sn * e21)
        rays[i, 2] = cos_t * d[2] + sin_t * (c * e12 + sn * e22)
    project_many(K, dist, rays, uv)


@numba.njit(cache=True, fastmath=False)
def _pinhole_bearings_kernel(Ki, pts, ok, bear) -> None:
    for i in range(pts.shape[0]):
        bear[i, 0] = 0.0
        bear[i, 1] = 0.0
        bear[i, 2] = 0.0
        if not (ok[i] and math.isfinite(pts[i, 0]) and math.isfinite(pts[i, 1])):
            ok[i] = False
            continue
        x = Ki[0, 0] * pts[i, 0] + Ki[0, 1] * pts[i, 1] + Ki[0, 2]
        y = Ki[1, 1] * pts[i, 1] + Ki[1, 2]
        nrm = math.sqrt(x * x + y * y + 1.0)
        bear[i, 0] = x / nrm
        bear[i, 1] = y / nrm
        bear[i, 2] = 1.0 / nrm


def _bearings(cam: _CameraContext, pts: np.ndarray, ok: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Unit bearings of pixels ``pts`` where ``ok``; also the rows that have one."""
    if cam.pinhole:
        bear = np.empty((len(pts), 3))
        ok = ok.copy()
        _pinhole_bearings_kernel(cam.Kinv, pts, ok, bear)
        return bear, ok
    bear = np.zeros((len(pts), 3))
    ok = ok & np.isfinite(pts[:, 0]) & np.isfinite(pts[:, 1])
    if not np.any(ok):
        return bear, ok
    if cam.pinhole:
        # K^-1 [u, v, 1], no iteration needed.
        Ki = cam.Kinv
        p = pts[ok]
        b = np.empty((len(p), 3))
        b[:, 0] = Ki[0, 0] * p[:, 0] + Ki[0, 1] * p[:, 1] + Ki[0, 2]
        b[:, 1] = Ki[1, 1] * p[:, 1] + Ki[1, 2]
        b[:, 2] = 1.0
        bear[ok] = b / np.sqrt((b * b).sum(axis=1))[:, None]
        return bear, ok
    try:
        bear[ok] = cam.camera.pixels_to_bearings(pts[ok])
    except InputError:
        # Some rim point lies where the distortion cannot be inverted
        # (beyond its fold): drop those points one by one.
        for i in np.flatnonzero(ok):
            try:
                bear[i] = cam.camera.pixels_to_bearings(pts[i])
            except InputError:
                ok[i] = False
    return bear, ok


@numba.njit(cache=True, fastmath=False)
def _rim_radii(rim: np.ndarray, cx: float, cy: float, ang: np.ndarray) -> np.ndarray:
    """Radius of the closed outline ``rim`` (n, 2) seen from ``(cx, cy)`` at angles ``ang``."""
    dx = rim[:, 0] - cx
    dy = rim[:, 1] - cy
    th = np.arctan2(dy, dx)
    rr = np.hypot(dx, dy)
    o = np.argsort(th)
    th, rr = th[o], rr[o]
    # Periodic interpolation: pad one sample on each side across +-pi.
    th = np.concatenate((th[-1:] - 2 * math.pi, th, th[:1] + 2 * math.pi))
    rr = np.concatenate((rr[-1:], rr, rr[:1]))
    return np.interp((ang + math.pi) % (2 * math.pi) - math.pi, th, rr)


def _window(rexp: np.ndarray) -> float:
    """Half-width of the sampling window around the expected rim (pixels).

    Wide enough for the blur of a small ball and the error of the coarse
    circle, never reaching the centre.
    """
    r = float(rexp.mean())
    h = min(max(0.25 * r + 2.0, 2.5), 6.0)
    return min(h, max(float(rexp.min()) - 0.75, 1.5))


def _refine(
    img: np.ndarray,
    lut: np.ndarray,
    s: BallSearch,
    c0: np.ndarray,
    r0: float,
    fill: float,
    cam: _CameraContext | None,
    hue_tol_deg: float,
    min_r: float,
    max_r: float,
    distance_range_m: tuple[float, float],
) -> _Candidate | None:
    """Sub-pixel fit of one coarse blob; None if it is not a plausible ball."""
    cx, cy = float(c0[0]), float(c0[1])
    r = float(r0)
    n_rays = int(np.clip(round(2 * math.pi * r), 24, 96))
    ang = np.arange(n_rays) * (2.0 * math.pi / n_rays)
    rexp = np.full(n_rays, r)
    e = np.empty(n_rays)
    valid = np.empty(n_rays, np.bool_)
    inner = np.empty((n_rays, 3))
    contrast = np.empty(n_rays)
    w = np.empty(n_rays)
    d = np.empty(3)
    rim = np.empty((48, 2))
    cos_t = rms = 0.0
    uv = np.full(2, np.nan)
    # Two rounds: the second casts its rays from the fitted centre, with its
    # windows centred on the fitted rim (an ellipse off-axis).
    for it in range(2):
        _edges_kernel(img, lut, cx, cy, ang, rexp, _window(rexp), _LOCAL_HALF_WINDOW, _STEP, e, valid, inner, contrast)
        # Rays far off the expected rim are occluders, clutter or a bad
        # coarse circle: the ones close to it are the initial inlier set.
        tol0 = max(1.5, 0.15 * r) if it == 0 else max(0.75, 0.05 * r)
        init = valid & (np.abs(np.where(valid, e, 1e9) - rexp) <= tol0)
        if init.sum() < 6:
            return None
        pts = np.column_stack([cx + np.cos(ang) * e, cy + np.sin(ang) * e])
        if cam is not None:
            bear, fin = _bearings(cam, pts, valid)
            ok, cos_t, rms = _cone_fit_kernel(bear, fin, init, cam.f, d, w)
            rim_or_none = _cone_rim(cam.camera, d, cos_t) if ok else None
            if rim_or_none is None:
                return None
            rim = rim_or_none
        else:
            fit = _ellipse_irls(pts, init)
            if fit is None:
                return None
            rim, w, rms, uv = fit
        cx, cy = float(rim[:, 0].mean()), float(rim[:, 1].mean())
        rexp = _rim_radii(rim, cx, cy, ang)
        r = float(np.mean(rexp))
        if not (0.7 * min_r <= r <= 1.5 * max_r) or not np.all(np.isfinite(rexp)):
            return None

    inl = w > 0
    rim_frac = float(inl.sum()) / n_rays
    # Hue of the ball as seen (inner colours of the inlier rays), vs nominal.
    hue, chroma = _hue_chroma_of_bgr_linear(np.median(inner[inl], axis=0), lut)
    dh = abs((hue - s.hue_deg + 180.0) % 360.0 - 180.0)
    colour = math.exp(-0.5 * (dh / (1.5 * hue_tol_deg)) ** 2)
    # Dim, barely tinted patches can have the right hue; a ball of a
    # saturated colour has a strong chroma even in dim light (0..255 units
    # of the encoded image).
    vivid = _vivid(chroma)
    shape = 1.0 / (1.0 + (rms / 0.5) ** 2)
    # A blob that fills little of its circle is a ring or a crescent.
    solid = min(1.0, fill / 0.6)
    # A lit sphere is shaded (its limb or one side darker than its middle);
    # a printed disc of the same colour is flat.  A soft cue: balls in
    # perfectly diffuse light look flat too.
    shading = _shading_contrast(img, lut, cx, cy, inner[inl])
    relief = 0.6 + 0.4 * min(1.0, shading / 0.12)
    # Evidence grows with the length of rim that fits: a blob of a few
    # pixels is round by default, so, other things equal, the bigger of two
    # blobs of the right colour is the ball.
    evidence = _evidence(rim_frac * 2.0 * math.pi * r)
    score = rim_frac * colour * vivid * shape * solid * evidence * relief
    info: dict[str, Any] = {
        "radius_px": r,
        "rim_fraction": rim_frac,
        "rms_px": float(rms),
        "hue_deg": float(hue),
        "chroma": chroma,
        "shading": shading,
    }
    xyz = None
    if cam is not None:
        uv = cam.camera.project(d)
        dist_m = s.radius_m / max(math.sqrt(max(1.0 - cos_t * cos_t, 0.0)), 1e-12)
        info["distance_m"] = float(dist_m)
        if not (distance_range_m[0] <= dist_m <= distance_range_m[1]):
            return None
        xyz = d * dist_m
    if not np.all(np.isfinite(uv)):
        return None
    return _Candidate(s, np.asarray(uv, float), np.array([cx, cy]), r, float(score), info, xyz, rim)


def _shading_contrast(img: np.ndarray, lut: np.ndarray, cx: float, cy: float, inner: np.ndarray) -> float:
    """Relative brightness range over the ball: its middle and the ring just inside the rim (0..1)."""
    Himg, Wimg = img.shape[:2]
    ring = np.sort(inner.sum(axis=1))
    if len(ring) < 4:
        return 0.0
    # 10th and 90th percentiles (robust to a stray ray).
    vals = [float(ring[len(ring) // 10]), float(ring[(9 * len(ring)) // 10])]
    i, j = int(round(cy)), int(round(cx))
    if 1 <= i < Himg - 1 and 1 <= j < Wimg - 1:
        vals.append(float(lut[img[i - 1 : i + 2, j - 1 : j + 2]].sum(axis=2).mean()))
    hi = max(vals)
    return (hi - min(vals)) / hi if hi > 0 else 0.0


def _vivid(chroma: float) -> float:
    """How clearly coloured (chroma = max - min of the encoded 0..255 BGR), 0..1."""
    return 1.0 - math.exp(-((chroma / 40.0) ** 2))


def _blob_chroma(coarse: np.ndarray, blob: tuple[float, float, float, float, float], sx: float, sy: float) -> float:
    """Chroma of a blob: the best of its centre and four points halfway to its rim.

    Several points, because an occluder may cover the centre.
    """
    h, w = coarse.shape[:2]
    cu, cv_, r = (blob[0] + 0.5) / sx - 0.5, (blob[1] + 0.5) / sy - 0.5, 0.5 * blob[2] / sx
    best = 0.0
    for du, dv in ((0.0, 0.0), (r, 0.0), (-r, 0.0), (0.0, r), (0.0, -r)):
        i, j = int(round(cv_ + dv)), int(round(cu + du))
        if 0 <= i < h and 0 <= j < w:
            px = coarse[i, j]
            best = max(best, float(max(px)) - float(min(px)))
    return best


def _evidence(rim_length_px: float) -> float:
    """Confidence from the length of rim that fits the model (0..1)."""
    return 1.0 - math.exp(-rim_length_px / 15.0)


def _hue_chroma_of_bgr_linear(b: np.ndarray, lut: np.ndarray) -> tuple[float, float]:
    """Hue (deg) and chroma (max - min, 0..255 encoded) of a linear BGR colour."""
    enc = np.searchsorted(lut, np.clip(b, 0.0, 1.0)).clip(0, 255).astype(float)
    h, _, _ = colorsys.rgb_to_hsv(*(enc[::-1] / 255.0))
    return 360.0 * h, float(enc.max() - enc.min())


def _ellipse_info(rim: np.ndarray) -> dict[str, Any]:
    """The fitted outline as ``{centre, axes (semi), angle_deg}`` (OpenCV's angle)."""
    (eu, ev), (A, B), ang = cv2.fitEllipse(rim.astype(np.float32))
    return {"centre": [float(eu), float(ev)], "axes": [float(A / 2), float(B / 2)], "angle_deg": float(ang)}


def _ellipse_irls(pts: np.ndarray, init: np.ndarray) -> tuple[np.ndarray, np.ndarray, float, np.ndarray] | None:
    """Robust ellipse through the rim points (no camera): ``(rim, weights, rms, centre)``.

    A sphere's image is an ellipse of modest eccentricity; when the visible
    arc is too short to pin down five parameters (the fit degenerates or
    comes out implausibly elongated) a circle is fitted instead.
    """
    finite = np.all(np.isfinite(pts), axis=1)
    P = np.ascontiguousarray(np.where(finite[:, None], pts, 0.0))
    w = (init & finite).astype(np.float64)
    model = None
    res = np.zeros(len(P))
    for it in range(8):
        if w.sum() < 6:
            return None
        model = _fit_ellipse(P, w)
        if model is None:
            model = _fit_circle(P, w)
            if model is None:
                return None
        res = model["dist"]
        sig = max(1.4826 * float(np.median(np.abs(res[w > 0]))), 0.08)
        u = np.where(finite, res / (4.0 * sig), np.inf)
        w_new = np.where(np.abs(u) < 1, (1 - u * u) ** 2, 0.0)
        change = float(np.max(np.abs(w_new - w)))
        w = w_new
        if it >= 1 and change < 0.02:
            break
    assert model is not None
    if w.sum() < 3:
        return None
    rms = float(np.sqrt(np.sum(w * res**2) / np.sum(w)))
    (cu, cv_), (a, b), ang = model["ellipse"]
    phi = np.linspace(0, 2 * math.pi, 48, endpoint=False)
    ca, sa = math.cos(math.radians(ang)), math.sin(math.radians(ang))
    x, y = a * np.cos(phi), b * np.sin(phi)
    rim = np.column_stack([cu + ca * x - sa * y, cv_ + sa * x + ca * y])
    return rim, w, rms, np.array([cu, cv_])


def _fit_circle(P: np.ndarray, w: np.ndarray) -> dict[str, Any] | None:
    """Least-squares circle of the points with ``w > 0``, in ``_fit_ellipse``'s form."""
    out = np.empty(3)
    if not _kasa_kernel(P, w > 0, out):
        return None
    dist = np.hypot(P[:, 0] - out[0], P[:, 1] - out[1]) - out[2]
    return {"ellipse": ((float(out[0]), float(out[1])), (float(out[2]), float(out[2])), 0.0), "dist": dist}


def _fit_ellipse(P: np.ndarray, w: np.ndarray) -> dict[str, Any] | None:
    """Weighted algebraic ellipse fit (Fitzgibbon's constraint), with distances.

    Points are centred and scaled first; the distance is the Sampson
    approximation of the geometric one, in pixels.
    """
    sel = w > 0
    m = np.average(P[sel], axis=0, weights=w[sel])
    s = math.sqrt(np.average(((P[sel] - m) ** 2).sum(1), weights=w[sel])) or 1.0
    x = (P[:, 0] - m[0]) / s
    y = (P[:, 1] - m[1]) / s
    D = np.column_stack([x * x, x * y, y * y, x, y, np.ones_like(x)])
    sw = np.sqrt(w)
    Dw = D * sw[:, None]
    S = Dw.T @ Dw
    Cm = np.zeros((6, 6))
    Cm[0, 2] = Cm[2, 0] = 2.0
    Cm[1, 1] = -1.0
    try:
        # Generalised eigenproblem S a = l C a; the ellipse is the eigenvector
        # with the only positive eigenvalue (solved via S^-1 C).
        evals, evecs = np.linalg.eig(np.linalg.solve(S, Cm))
    except np.linalg.LinAlgError:
        return None
    evals = np.real(evals)
    evecs = np.real(evecs)
    cond = 4 * evecs[0] * evecs[2] - evecs[1] ** 2
    ok = np.flatnonzero((cond > 0) & np.isfinite(evals) & (evals > 0))
    if len(ok) == 0:
        return None
    a = evecs[:, ok[np.argmax(evals[ok])]]
    A_, B_, C_, D_, E_, F_ = a
    den = B_ * B_ - 4 * A_ * C_
    if den >= 0:
        return None
    xc = (2 * C_ * D_ - B_ * E_) / den
    yc = (2 * A_ * E_ - B_ * D_) / den
    # Axes and angle from the conic.
    M = np.array([[A_, B_ / 2], [B_ / 2, C_]])
    Fc = A_ * xc * xc + B_ * xc * yc + C_ * yc * yc + D_ * xc + E_ * yc + F_
    ev, evec = np.linalg.eigh(M)
    if Fc == 0 or np.any(-Fc / ev <= 0):
        return None
    ax = np.sqrt(-Fc / ev) * s
    if max(ax) > _MAX_AXIS_RATIO * min(ax):
        return None  # not the image of a sphere (or an arc too short to tell)
    # Semi-axis ax[0] lies along the first eigenvector.
    ang = math.degrees(math.atan2(evec[1, 0], evec[0, 0]))
    val = D @ a
    gx = 2 * A_ * x + B_ * y + D_
    gy = B_ * x + 2 * C_ * y + E_
    dist = val / np.maximum(np.hypot(gx, gy), 1e-12) * s
    centre = (float(xc * s + m[0]), float(yc * s + m[1]))
    return {"ellipse": (centre, (float(ax[0]), float(ax[1])), ang), "dist": dist}


# ---------------------------------------------------------------------------
# timing
# ---------------------------------------------------------------------------


def _demo_image(seed: int = 0, width: int = 960, height: int = 540) -> tuple[np.ndarray, dict[str, Marker], Camera]:
    """A textured, noisy frame with four shaded balls of one robot (for timing only).

    The markers' positions are the balls' centres in this camera's frame
    (as if the robot's frame were the camera's), so the rig check applies.
    """
    rng = np.random.default_rng(seed)
    f = 800.0
    K = np.array([[f, 0, (width - 1) / 2], [0, f, (height - 1) / 2], [0, 0, 1]])
    cam = Camera(K, size=(width, height))
    bg = cv2.GaussianBlur(rng.integers(40, 160, (height // 8, width // 8, 3), dtype=np.uint8), (0, 0), 1.0)
    img = cv2.resize(bg, (width, height), interpolation=cv2.INTER_CUBIC)
    colours = {"M1": (255, 0, 0), "M2": (0, 200, 0), "M3": (0, 0, 255), "M4": (255, 255, 0)}
    markers = {}
    for i, (name, rgb) in enumerate(colours.items()):
        cx, cy = (i + 1) * width / 5 + rng.uniform(-20, 20), height / 2 + rng.uniform(-100, 100)
        r = rng.uniform(8, 24)
        for k in range(int(r), 0, -1):  # crude shading: brighter towards the centre
            shade = 0.55 + 0.45 * (1 - (k / r) ** 2) ** 0.5
            col = tuple(int(c * shade) for c in rgb[::-1])
            cv2.circle(img, (int(cx * 16), int(cy * 16)), int(k * 16), col, -1, cv2.LINE_AA, shift=4)
        z = f * DEFAULT_BALL_RADIUS_M / r
        pos = np.array([(cx - K[0, 2]) * z / f, (cy - K[1, 2]) * z / f, z])
        markers[name] = Marker(name=name, robot="q", position=pos, color=rgb)
    img = np.clip(img + rng.normal(0, 2, img.shape), 0, 255).astype(np.uint8)
    return img, markers, cam


def time_detector(
    image: np.ndarray | None = None,
    markers: Mapping[str, Marker] | None = None,
    camera: Camera | None = None,
    *,
    repeats: int = 200,
    threads: int = 1,
    **kwargs: Any,
) -> float:
    """Frames per second of :func:`detect_balls` on one image (default: a demo frame).

    ``threads`` is passed to ``cv2.setNumThreads`` for the measurement (1 =
    one core) and restored afterwards.  The clock is the process's CPU time,
    so with one thread the figure is per core and does not depend on what
    else the machine is running.
    """
    if image is None or markers is None:
        image, markers, cam = _demo_image()
        camera = camera or cam
    old = cv2.getNumThreads()
    cv2.setNumThreads(int(threads))
    try:
        detect_balls(image, markers, camera=camera, **kwargs)  # warm-up (JIT, caches)
        best = math.inf
        # Best of a few batches (CPU time still feels cache and memory
        # contention from other processes).
        n = max(1, repeats // 3)
        for _ in range(3):
            t0 = time.process_time()
            for _ in range(n):
                detect_balls(image, markers, camera=camera, **kwargs)
            best = min(best, (time.process_time() - t0) / n)
    finally:
        cv2.setNumThreads(old)
    return 1.0 / best


if __name__ == "__main__":  # pragma: no cover
    img, mk, cam = _demo_image()
    res = detect_balls(img, mk, camera=cam)
    print(f"found {sorted(res.detections)}, missing {res.missing}")
    print(f"detect_balls: {time_detector(img, mk, cam):.0f} FPS at {img.shape[1]}x{img.shape[0]}, "
          f"{len(mk)} markers, one thread")
