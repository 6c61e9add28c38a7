"""The image of a sphere, and where its centre projects.

A sphere of angular radius ``alpha`` seen along the unit direction ``d`` is
bounded by the circular cone of bearings ``b . d = cos(alpha)``; under a
pinhole camera its image is a conic (an ellipse), elongated radially, and
its centre lies *outward* of the projection of the sphere's centre: by
``f * (sin 2t / (cos 2a + cos 2t) - tan t)``, about ``f a^2 tan t / cos^2 t``
for a small sphere ``t`` off the optical axis.  A detector that measures the
centre of a lit disc (a centroid, or the centre of its glow's contours, both
centrally symmetric about the ellipse's centre) therefore reports a point
that is not the projection the pose solver needs; :func:`sphere_centre_pixel`
maps one to the other through the camera model (lens distortion included;
any lens: :class:`~mutloc.core.camera.Camera`, ``FisheyeCamera``,
``OmniCamera``, out to their ``max_angle`` -- through a fisheye the image of
a small sphere is nearly centred on its centre's projection even at the rim,
since the lens maps angles, not tangents).
"""

from __future__ import annotations

import math

import numpy as np

from ..errors import InputError
from .camera import Camera

__all__ = ["sphere_image", "sphere_centre_pixel"]

_RIM = 48  # rim points: the inscribed polygon's area is 0.3 % short, its centroid exact to ~1e-4 of the offset


def _rim_bearings(d: np.ndarray, alpha: float, n: int) -> np.ndarray:
    """``n`` unit bearings on the cone of half-angle ``alpha`` around unit ``d``."""
    a = np.array([1.0, 0.0, 0.0]) if abs(d[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    e1 = np.cross(d, a)
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(d, e1)
    phi = np.linspace(0.0, 2.0 * math.pi, n, endpoint=False)
    return (math.cos(alpha) * d[None, :]
            + math.sin(alpha) * (np.cos(phi)[:, None] * e1[None, :] + np.sin(phi)[:, None] * e2[None, :]))


def sphere_image(camera: Camera, direction: np.ndarray, alpha: float, n: int = _RIM) -> tuple[np.ndarray, float]:
    """Area centroid (pixel) and area (px^2) of the image of a sphere of
    angular radius ``alpha`` (rad) whose centre lies along ``direction``
    (camera frame), through ``camera`` (distortion included).

    The outline is the projected rim cone, as a polygon of ``n`` points.
    NaN centroid and area when part of the rim does not project (behind the
    camera or outside the lens model's domain).
    """
    d = np.asarray(direction, float)
    d = d / np.linalg.norm(d)
    uv = camera.project(_rim_bearings(d, alpha, n))
    x, y = uv[:, 0], uv[:, 1]
    xn, yn = np.roll(x, -1), np.roll(y, -1)
    cross = x * yn - xn * y
    a2 = float(cross.sum())  # twice the signed area
    if not math.isfinite(a2) or abs(a2) < 1e-12:
        return np.full(2, np.nan), math.nan
    c = np.array([float(((x + xn) * cross).sum()), float(((y + yn) * cross).sum())]) / (3.0 * a2)
    return c, 0.5 * abs(a2)


def sphere_centre_pixel(camera: Camera, centre: np.ndarray, area: float, iterations: int = 3) -> np.ndarray:
    """Projection of a sphere's centre from the centre and area of its image.

    ``centre`` is the area centroid of the sphere's image (pixels), ``area``
    the image's area (px^2): the apparent size gives the angular radius (and
    with the sphere's true radius ``R`` the range, ``R / sin(alpha)``, which
    is not needed).  Fixed-point iteration: the sphere is imaged along the
    bearing of the current estimate ``p`` of its centre's projection;
    ``alpha`` is rescaled so that image has the measured area, and ``p`` is
    put where the (rescaled) offset of that image's centroid lands it on the
    measured centroid.  Returns ``centre`` itself when the spot
    is too small to matter or the geometry does not project.
    """
    m = np.asarray(centre, float)
    if not (math.isfinite(area) and area > 0.0) or not np.all(np.isfinite(m)):
        return m.copy()
    f = float(math.sqrt(camera.K[0, 0] * camera.K[1, 1]))
    alpha = math.sqrt(area / math.pi) / f  # first guess: a disc on the axis
    p = m.copy()
    for _ in range(iterations):
        try:
            d = camera.pixels_to_bearings(p)
        except InputError:  # outside the lens model's domain: leave it uncorrected
            return m.copy()
        if not np.all(np.isfinite(d)) or alpha >= camera.max_angle - math.acos(max(-1.0, min(1.0, d[2]))):
            return m.copy()  # the rim would reach past what the lens images (pinhole: behind the camera)
        c, a = sphere_image(camera, d, alpha)
        if not (math.isfinite(a) and a > 0.0) or not np.all(np.isfinite(c)):
            return m.copy()
        # Image area and the centre's offset both grow as alpha^2: rescale
        # to the measured area (one projection per iteration).
        scale = area / a
        alpha *= math.sqrt(scale)
        p = m - (c - p) * scale
    return p
