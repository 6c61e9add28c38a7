"""Detection through any lens: locally rectified pinhole views.

The image detectors (balls, tags, cylinders) assume a pinhole camera: straight
lines stay straight, a ball's outline is a conic.  Through a fisheye or
omnidirectional lens, far off the axis (80-95 degrees and beyond), a tag is
strongly curved and compressed and the detectors miss it or measure it pixels
off.  So for a wide-angle camera the image is seen through a small set of
virtual pinhole views (:class:`View`): perspective cameras sharing the lens's
optical centre, rotated to cover the lens's whole field, each resampled from
the raw image with ``cv2.remap``.  The detector runs on every view with the
view's own pinhole :class:`~mutloc.core.camera.Camera`; each detection (its
centre, a tag's corners, a cylinder's bands) goes back to the raw image
through its ray (view pixel -> bearing in the camera frame ->
``camera.bearings_to_pixels``), so results are the raw image's pixels, as the
SPEC wants.  A marker found in several overlapping views is kept from the
view where it lies nearest the centre (least stretched, farthest from the
view's border).

Layout (:func:`views_for`): one view along the optical axis and rings of six
views tilted 70 degrees (and 120 degrees, then one looking backwards, when the
field reaches that far), each ``2 * half_fov_deg`` = 100 degrees square: every
direction of a 95-degree field is then at least 11 degrees inside some view's
border (at least 11 degrees up to 150 degrees with the second ring), so
a marker up to ~20 degrees across is whole in one view.  A view is cropped to
where it shows the raw image.  Its focal length gives it the raw image's pixel
density along its axis (the larger of the lens's radial and tangential
pixels per radian there, times ``density``), so nothing is lost near the centre
of a view; away from it the view is finer still (pinhole stretch).

The views and their remap tables are per camera, computed once and cached
(:func:`views_for`): not per frame.  What a view shows beyond the raw image
(past the lens's field: a fisheye's black surround) is filled with the
view's mean level, not left black: a large dark shape with a ragged edge
is clutter to the detectors (cylinders chased it for seconds a frame).

Noise: a view oversamples the raw image where it is finer, and a detection's
error in raw pixels is then what the raw pixels allow, not smaller; where a
view is coarser than the raw image (its pixel spans more than one raw pixel,
as happens across the compressed rim of some lenses at ``density < 1``),
resampling has thrown information away and the detection's ``sigma_scale``
is multiplied by that span (the largest singular value of d(raw px)/d(view px)
at the detection), ``info["view"]["raw_px_per_view_px"]``.

A pinhole camera (``model == "pinhole"``) is never seen through views: the
detectors get the raw image and the camera, exactly as before.
"""

from __future__ import annotations

import math
from collections import OrderedDict
from dataclasses import dataclass, field
from typing import Any, Callable, Mapping

import cv2
import numpy as np

from ..core.camera import Camera
from ..errors import InputError
from .base import Detection, DetectionResult, as_bgr

__all__ = ["View", "ViewSet", "linearized", "needs_views", "views_for", "view_towards", "detection_to_raw",
           "detect_in_views", "HALF_FOV_DEG"]

#: Half the field of view of a virtual view (degrees; the views are square).
HALF_FOV_DEG = 50.0
#: Rings of views: (tilt off the optical axis in degrees, number of views, azimuth of the first), used while
#: the lens's field reaches beyond the previous ring's coverage (the first number of :data:`_RING_REACH`).
_RINGS = ((70.0, 6, 0.0), (120.0, 6, 30.0))
#: Field (degrees off the axis) up to which the views so far keep every direction >= 8 degrees inside one
#: view (measured on a dense sample of directions): the axis view alone, then with each ring.
_REACH = (35.0, 104.0, 150.0)
#: Views cached per camera (the remap tables are the big part: ~6 bytes per view pixel).
_CACHE_SIZE = 8
#: Raw pixels kept around the part of a view that shows the image (view pixels).
_CROP_MARGIN = 2
#: View pixels along the edge of what a view shows that are filled too (View.rectify).
_FILL_EDGE = 2


def _lut_tables() -> tuple[np.ndarray, np.ndarray]:
    x = np.arange(256) / 255.0
    lin = np.where(x <= 0.04045, x / 12.92, ((x + 0.055) / 1.055) ** 2.4)
    y = np.arange(65536) / 65535.0
    enc = np.where(y <= 0.0031308, 12.92 * y, 1.055 * y ** (1.0 / 2.4) - 0.055)
    return (np.round(lin * 65535.0).astype(np.uint16), np.clip(np.round(enc * 255.0), 0, 255).astype(np.uint8))


#: sRGB level -> linear light (16 bits), and back (IEC 61966-2-1).
_TO_LINEAR16, _TO_SRGB8 = _lut_tables()


def linearized(image: np.ndarray) -> np.ndarray:
    """An sRGB uint8 image in linear light, 16 bits (what :meth:`View.rectify` resamples)."""
    return _TO_LINEAR16[image]


def needs_views(camera: Any) -> bool:
    """Whether ``camera`` is seen through rectified views: any lens but the pinhole one."""
    return camera is not None and getattr(camera, "model", "pinhole") != "pinhole"


def _look(axis: np.ndarray) -> np.ndarray:
    """Rotation whose columns are a view's x, y, z axes in the camera frame: z along ``axis``, y ("down")
    as near the camera's own y as can be (so an upright thing stays upright), else towards -z."""
    a = axis / np.linalg.norm(axis)
    for down in (np.array([0.0, 1.0, 0.0]), np.array([0.0, 0.0, -1.0])):
        y = down - (down @ a) * a
        if np.linalg.norm(y) > 1e-6:
            break
    y = y / np.linalg.norm(y)
    return np.stack([np.cross(y, a), y, a], axis=1)


@dataclass(frozen=True, eq=False)
class View:
    """One virtual pinhole view of a wide-angle camera: a rotation ``R`` (its axes as columns, in the
    camera frame: ``bearing_camera = R @ bearing_view``), its distortion-free pinhole ``camera`` (the
    view's pixels) and the remap tables that resample the raw image into it."""

    index: int
    R: np.ndarray
    camera: Camera
    maps: tuple[np.ndarray, np.ndarray] = field(repr=False)
    #: The lens, whose raw pixels the view is resampled from.
    lens: Any = field(repr=False)
    #: Flat indices of the view pixels that show nothing of the raw image (beyond the lens's field or the
    #: image's border), None if there are none; and a fixed sample of those that do.
    blank: np.ndarray | None = field(default=None, repr=False)
    shown: np.ndarray | None = field(default=None, repr=False)

    @property
    def axis(self) -> np.ndarray:
        return self.R[:, 2]

    def rectify(self, image: np.ndarray, srgb: bool = True, *, linear: np.ndarray | None = None) -> np.ndarray:
        """The view's image, resampled (bilinear) from the raw ``image`` (uint8).  With ``srgb`` (what
        cameras and image files deliver) the interpolation mixes light, not its encoded levels: the image
        is linearized (16 bits), resampled, encoded again.  (Mixing sRGB levels moves every edge towards
        its bright side after the detectors linearize: a tag 0.2-0.3 px too large on each side.)
        ``linear``: :func:`linearized` ``(image)``, when the caller resamples one image into several
        views (linearized once, not once per view)."""
        if not srgb:
            out = cv2.remap(image, self.maps[0], self.maps[1], cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
        else:
            lin = linearized(image) if linear is None else linear
            out = _TO_SRGB8[cv2.remap(lin, self.maps[0], self.maps[1], cv2.INTER_LINEAR,
                                      borderMode=cv2.BORDER_REPLICATE)]
        if self.blank is not None and self.shown is not None:
            # What the view shows beyond the image is the image's mean level, not black: a black surround
            # is a huge dark shape with a ragged edge, which dark-band detectors (cylinders) chase at length.
            flat = out.reshape(-1, out.shape[2]) if out.ndim == 3 else out.reshape(-1)
            flat[self.blank] = flat[self.shown].mean(axis=0).round().astype(out.dtype)
        return out

    def bearings(self, uv: Any) -> np.ndarray:
        """Unit bearings (n, 3) in the *camera* frame of view pixels ``uv`` (n, 2)."""
        uv = np.asarray(uv, float).reshape(-1, 2)
        K = self.camera.K
        y = (uv[:, 1] - K[1, 2]) / K[1, 1]
        x = (uv[:, 0] - K[0, 2] - K[0, 1] * y) / K[0, 0]
        b = np.c_[x, y, np.ones(len(uv))] @ self.R.T
        return b / np.linalg.norm(b, axis=1, keepdims=True)

    def to_raw(self, uv: Any) -> np.ndarray:
        """Raw pixels (n, 2) of view pixels ``uv`` (n, 2) (a (2,) pixel gives (2,)); NaN where the lens
        does not image that direction."""
        a = np.asarray(uv, float)
        out = self.lens.bearings_to_pixels(self.bearings(a))
        return out[0] if a.ndim == 1 else out

    def off_centre(self, uv: Any) -> float:
        """How far view pixel ``uv`` is from the view's border, as the larger of its horizontal and
        vertical angles off the view's axis (radians; the views are square, so a smaller value is farther
        inside, and less stretched)."""
        K = self.camera.K
        u, v = float(uv[0]), float(uv[1])
        y = (v - K[1, 2]) / K[1, 1]
        x = (u - K[0, 2] - K[0, 1] * y) / K[0, 0]
        return max(abs(math.atan(x)), abs(math.atan(y)))

    def raw_per_view_px(self, uv: Any) -> float:
        """The largest singular value of d(raw px)/d(view px) at view pixel ``uv``: how many raw pixels one
        view pixel spans there, at most (central differences)."""
        u, v = float(uv[0]), float(uv[1])
        h = 0.5
        p = self.to_raw(np.array([[u + h, v], [u - h, v], [u, v + h], [u, v - h]]))
        J = np.c_[(p[0] - p[1]) / (2 * h), (p[2] - p[3]) / (2 * h)]
        if not np.all(np.isfinite(J)):
            return 1.0
        return float(np.linalg.svd(J, compute_uv=False)[0])


@dataclass(frozen=True, eq=False)
class ViewSet:
    """The views of one camera (:func:`views_for`) and the field they cover (degrees off the axis)."""

    camera: Any
    views: tuple[View, ...]
    field_deg: float

    def __iter__(self):
        return iter(self.views)

    def __len__(self) -> int:
        return len(self.views)

    @property
    def pixels(self) -> int:
        """View pixels per frame, all views together."""
        return int(sum(v.camera.size[0] * v.camera.size[1] for v in self.views))


def _camera_key(camera: Any) -> tuple:
    size = camera.size
    return (camera.model, camera.K.tobytes(), np.asarray(camera.dist).tobytes(), size,
            float(getattr(camera, "xi", 0.0) or 0.0))


_cache: "OrderedDict[tuple, ViewSet]" = OrderedDict()


def _field_deg(camera: Any, size: tuple[int, int]) -> float:
    """Largest angle off the axis (degrees) at which the raw image shows anything: the image's border
    (sampled every few pixels) and, where it reaches past the lens's ``max_angle``, that."""
    w, h = size
    us = np.linspace(-0.5, w - 0.5, max(2, w // 4))
    vs = np.linspace(-0.5, h - 0.5, max(2, h // 4))
    border = np.r_[np.c_[us, np.full_like(us, -0.5)], np.c_[us, np.full_like(us, h - 0.5)],
                   np.c_[np.full_like(vs, -0.5), vs], np.c_[np.full_like(vs, w - 0.5), vs]]
    b = camera.pixels_to_bearings(border)
    ok = np.all(np.isfinite(b), axis=1)
    top = math.degrees(camera.max_angle)
    if not np.all(ok):
        return top
    return min(top, float(np.degrees(np.arccos(np.clip(b[:, 2], -1.0, 1.0))).max()))


def _axes(field_deg: float) -> list[np.ndarray]:
    axes = [np.array([0.0, 0.0, 1.0])]
    for (tilt, n, first), reach in zip(_RINGS, _REACH):
        if field_deg <= reach:
            return axes
        t = math.radians(tilt)
        for k in range(n):
            ph = math.radians(first + 360.0 * k / n)
            axes.append(np.array([math.sin(t) * math.cos(ph), math.sin(t) * math.sin(ph), math.cos(t)]))
    if field_deg > _REACH[-1]:
        axes.append(np.array([0.0, 0.0, -1.0]))
    return axes


def _density(camera: Any, R: np.ndarray, field_deg: float) -> float:
    """Raw pixels per radian along a view's axis: the geometric mean of the singular values of the lens's
    Jacobian restricted to the directions across the axis (the view then has as many pixels per unit of
    solid angle there as the raw image).  An axis beyond the field is taken where the field ends on its
    way (what the view shows is there), and the density is capped at twice the density on the optical
    axis (a lens whose rim is stretched, as Mei's with a large ``xi``, would else make views of
    millions of pixels)."""
    a = R[:, 2]
    tilt = math.acos(max(-1.0, min(1.0, float(a[2]))))
    edge = math.radians(field_deg) - math.radians(2.0)
    if tilt > edge:
        across = np.array([a[0], a[1], 0.0])
        n = np.linalg.norm(across)
        across = across / n if n > 1e-9 else np.array([1.0, 0.0, 0.0])
        a = np.array([*(math.sin(edge) * across[:2]), math.cos(edge)])
        R = _look(a)

    def at(R: np.ndarray) -> float:
        _, J = camera.project_jacobian(R[:, 2])
        return float(math.sqrt(abs(np.linalg.det(J @ R[:, :2])))) if np.all(np.isfinite(J)) else math.nan

    centre = at(np.eye(3))
    d = at(R)
    if not math.isfinite(d):
        d = centre
    return min(d, 2.0 * centre) if math.isfinite(centre) else d


def _build_view(camera: Any, index: int, R: np.ndarray, field_deg: float, half_fov: float,
                density: float) -> View | None:
    w, h = camera.size
    f = density * _density(camera, R, field_deg)
    half = int(math.ceil(f * math.tan(half_fov)))
    n = 2 * half + 1
    c = float(half)
    g = np.arange(n, dtype=np.float64)
    x = (g - c) / f
    X, Y = np.meshgrid(x, x)
    rays = np.stack([X, Y, np.ones_like(X)], axis=-1).reshape(-1, 3) @ R.T
    rays /= np.linalg.norm(rays, axis=1, keepdims=True)
    raw = camera.bearings_to_pixels(rays)
    ok = np.all(np.isfinite(raw), axis=1) & (rays[:, 2] > math.cos(math.radians(field_deg)) - 1e-12)
    ok &= (raw[:, 0] >= -0.5) & (raw[:, 0] <= w - 0.5) & (raw[:, 1] >= -0.5) & (raw[:, 1] <= h - 0.5)
    ok = ok.reshape(n, n)
    if ok.sum() < 64:
        return None
    rows, cols = np.flatnonzero(ok.any(axis=1)), np.flatnonzero(ok.any(axis=0))
    r0, r1 = max(0, rows[0] - _CROP_MARGIN), min(n, rows[-1] + _CROP_MARGIN + 1)
    c0, c1 = max(0, cols[0] - _CROP_MARGIN), min(n, cols[-1] + _CROP_MARGIN + 1)
    raw = raw.reshape(n, n, 2)[r0:r1, c0:c1]
    bad = ~ok[r0:r1, c0:c1]
    mx = np.where(bad, -1e4, raw[..., 0]).astype(np.float32)
    my = np.where(bad, -1e4, raw[..., 1]).astype(np.float32)
    maps = cv2.convertMaps(mx, my, cv2.CV_16SC2)
    K = np.array([[f, 0.0, c - c0], [0.0, f, c - r0], [0.0, 0.0, 1.0]])
    # Filled with the mean level (View.rectify): what shows nothing, and the edge pixels whose bilinear
    # samples reach past the image's edge (a dotted dark line there looks like a column of bands).
    edge = cv2.erode((~bad).astype(np.uint8), np.ones((2 * _FILL_EDGE + 1,) * 2, np.uint8),
                     borderType=cv2.BORDER_REPLICATE) == 0
    blank = np.flatnonzero(edge)
    shown = np.flatnonzero(~edge)
    shown = shown[np.linspace(0, len(shown) - 1, min(len(shown), 4096)).astype(np.int64)]
    return View(index, R, Camera(K, size=(c1 - c0, r1 - r0)), maps, camera,
                blank if len(blank) else None, shown)


def views_for(camera: Any, *, field_deg: float | None = None, half_fov_deg: float = HALF_FOV_DEG,
              density: float = 1.0) -> ViewSet:
    """The rectified views of a wide-angle ``camera`` (cached per camera and arguments).

    ``field_deg``: the largest angle off the axis that matters (default: as far as the raw image reaches,
    capped by the lens's ``max_angle``; give a lens's own field, e.g. 95 for a 190-degree lens, to spare
    views of its black surround).  ``density`` scales the views' focal lengths (1: the raw image's pixel
    density along each view's axis).  The camera needs its ``size``.
    """
    if not needs_views(camera):
        raise InputError("views are for wide-angle lenses (fisheye, omni); a pinhole camera is used as it is")
    if camera.size is None:
        raise InputError(f"a {camera.model} camera needs its image size to be seen through rectified views")
    if not (0.0 < half_fov_deg < 80.0) or not (density > 0.0):
        raise InputError("half_fov_deg must be in (0, 80) and density > 0")
    key = (_camera_key(camera), field_deg, float(half_fov_deg), float(density))
    hit = _cache.get(key)
    if hit is not None:
        _cache.move_to_end(key)
        return hit
    reach = _field_deg(camera, camera.size)
    fld = reach if field_deg is None else min(float(field_deg), reach)
    views = []
    for axis in _axes(fld):
        v = _build_view(camera, len(views), _look(axis), fld, math.radians(half_fov_deg), density)
        if v is not None:
            views.append(v)
    vs = ViewSet(camera, tuple(views), fld)
    _cache[key] = vs
    while len(_cache) > _CACHE_SIZE:
        _cache.popitem(last=False)
    return vs


def view_towards(camera: Any, direction: Any, *, half_fov_deg: float = 20.0, density: float = 1.0) -> View | None:
    """One rectified view of the wide-angle ``camera`` centred on ``direction`` (camera frame), ``2 *
    half_fov_deg`` square (not cached): for a second look around a predicted marker, where a pose says it
    is.  None when the lens does not image that part of the sky (fewer than 64 view pixels show the image).
    Detections in it go back to the raw image with :func:`detection_to_raw`."""
    if not needs_views(camera):
        raise InputError("views are for wide-angle lenses (fisheye, omni); a pinhole camera is used as it is")
    if camera.size is None:
        raise InputError(f"a {camera.model} camera needs its image size to be seen through rectified views")
    d = np.asarray(direction, float).reshape(3)
    if not (np.all(np.isfinite(d)) and np.linalg.norm(d) > 0.0) or not (0.0 < half_fov_deg < 80.0):
        raise InputError("view_towards needs a finite non-zero direction and half_fov_deg in (0, 80)")
    return _build_view(camera, -1, _look(d), _field_deg(camera, camera.size), math.radians(half_fov_deg), density)


def detection_to_raw(det: Detection, view: View) -> Detection | None:
    """``det`` found in ``view``'s pixels, in the raw image's (its corners too; ``sigma_scale`` widened where
    the view is coarser than the raw image; ``info["view"]`` says where); None if it is not imaged."""
    return _to_raw(det, view)


def _to_raw(det: Detection, view: View) -> Detection | None:
    """``det`` (in ``view``'s pixels) in the raw image's pixels; None if its centre is not imaged."""
    uv = view.to_raw(det.uv)
    if not np.all(np.isfinite(uv)):
        return None
    corners = None
    if det.corners is not None:
        corners = view.to_raw(np.asarray(det.corners, float).reshape(-1, 2))
        if not np.all(np.isfinite(corners)):
            return None
    span = view.raw_per_view_px(det.uv)
    info = dict(det.info)
    info["view"] = {"index": view.index, "axis": [float(a) for a in view.axis],
                    "off_centre_deg": math.degrees(view.off_centre(det.uv)), "raw_px_per_view_px": span,
                    "uv": [float(det.uv[0]), float(det.uv[1])]}
    return Detection(det.marker, uv, det.score, corners, info, det.predicted, det.visible_fraction,
                     det.residual_px, det.sigma_scale * max(1.0, span))


def _group(det: Detection) -> str:
    """The detections that must come from one view: a cylinder's centre and its bands."""
    return str(det.info.get("cylinder", det.marker)) if det.info else det.marker


def detect_in_views(detector: Callable[..., DetectionResult], image: Any, markers: Mapping[str, Any],
                    camera: Any, *, views: ViewSet | None = None, **options: Any) -> DetectionResult:
    """Run an image ``detector`` (``detect_tags``, ``detect_balls``, ``detect_cylinders``: ``(image,
    markers, camera=, **options)``) on every rectified view of the wide-angle ``camera``
    (:func:`views_for`, or ``views``) and report what it found in the raw image's pixels.

    A marker found in several views is taken from the one where it lies farthest inside (least
    off-centre, :meth:`View.off_centre`); its alternatives come from that view too.  Each detection's
    ``info["view"]`` says which view and where in it (``uv``: view pixels; other pixel figures the
    detector put in ``info`` -- ``radius_px``, ``side_px``, ``ellipse`` -- are in the view's pixels).
    A marker no view found is missing, with the most telling reason any view gave (a quality
    rejection before ``"not_found"``).  A detector with an ``in_views`` attribute (``detect_cylinders``)
    searches the views itself: ``detector.in_views(image, markers, camera, views, **options)``.
    """
    img = as_bgr(image, "image")
    if views is None:
        views = views_for(camera)
    size = camera.size
    if size is not None and (img.shape[1], img.shape[0]) != tuple(size):
        raise InputError(f"image is {img.shape[1]}x{img.shape[0]} but the camera's calibration is "
                         f"{size[0]}x{size[1]}")
    in_views = getattr(detector, "in_views", None)
    if in_views is not None:
        # A detector that searches all the views at once (cylinders: one ranking of candidates per frame).
        return in_views(img, markers, camera, views, **options)
    best: dict[str, tuple[float, View, DetectionResult]] = {}
    reasons: dict[str, str] = {}
    missing: list[str] = []
    # Resample in linear light unless the detector is told the levels are linear already.
    srgb = options.get("gamma", "srgb") == "srgb" and getattr(options.get("params"), "srgb", True) is not False
    lin = linearized(img) if srgb else None
    for view in views:
        res = detector(view.rectify(img, srgb, linear=lin), markers, camera=view.camera, **options)
        for name, det in res.detections.items():
            g = _group(det)
            if g != name and g in res.detections:
                continue  # judged with its group's main detection
            off = view.off_centre(det.uv)
            if g not in best or off < best[g][0]:
                best[g] = (off, view, res)
        missing.extend(n for n in res.missing if n not in missing)
        for name, why in res.missing_reasons.items():
            if name not in reasons or (reasons[name].startswith("not_found") and not why.startswith("not_found")):
                reasons[name] = why
    result = DetectionResult()
    taken: dict[str, Detection] = {}
    for g, (_, view, res) in best.items():
        for name, det in res.detections.items():
            if _group(det) != g:
                continue
            raw = _to_raw(det, view)
            if raw is not None:
                taken[name] = raw
                alts = [a for a in (_to_raw(x, view) for x in res.alternatives.get(name, [])) if a is not None]
                if alts:
                    result.alternatives[name] = alts
    # In the markers' order (the detectors' own), then the rest (a cylinder's bands).
    order = list(markers)
    result.detections = {n: taken[n] for n in order if n in taken}
    result.detections.update({n: d for n, d in taken.items() if n not in result.detections})
    result.missing = [n for n in order if n in missing and n not in taken]
    result.missing += [n for n in missing if n not in taken and n not in result.missing]
    result.missing_reasons = {n: reasons[n] for n in result.missing if n in reasons}
    return result
