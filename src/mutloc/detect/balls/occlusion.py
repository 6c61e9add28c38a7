"""Partly hidden balls: find the circle of the visible rim, leave the occluder's edge out.

A pole, a cable or the edge of a box in front of a ball cuts straight edges
into its blob, or splits it in two.  The coarse circle of such a blob (or of
one half of it) is off, and a fit that took every edge point would be
pulled towards the occluder.  Two tests tell the ball's rim from an
occluder's edge:

* the **normal** of a rim point is radial: :func:`recentre` runs a RANSAC
  circle over the blob's outline at full resolution in which a point
  counts only if it lies on the circle *and* its outline's normal points to
  the centre (a straight occluding edge crosses the circle at an angle, so
  its points do not count); the pieces of a split blob vote for one circle;
* along the sub-pixel rim of the rays, :func:`smooth_rim` drops points
  where the outline turns steeply against the ray, the same test on the
  measured edge.

What is left of the rim is fitted (:mod:`.fit`); its share of all rays is
the ball's visible fraction.
"""

from __future__ import annotations

import math

import cv2
import numba
import numpy as np

from .light import correct
from .numeric import circle3, kasa_circle
from .params import BallParams
from .search import BallSearch, Blob

__all__ = ["hue_mask", "outline_points", "recentre", "smooth_kernel", "smooth_rim"]

# Fixed random draws: detections are repeatable.
_DRAWS = np.random.default_rng(2718).random((48, 3))


def outline_points(mask: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Outer outline pixels (n, 2) of every blob of ``mask`` and their unit normals (n, 2).

    The normal is perpendicular to the outline's chord over +-2 pixels
    (its sign is not used).  Holes (a highlight, a logo) are not outlines.
    """
    contours, _ = cv2.findContours(mask, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
    contours = [c for c in contours if len(c) >= 8]
    if not contours:
        return np.zeros((0, 2)), np.zeros((0, 2))
    lens = np.array([len(c) for c in contours], np.int64)
    pts = np.concatenate([c.reshape(-1, 2) for c in contours]).astype(np.float64)
    nrm = np.empty_like(pts)
    _normals(pts, lens, nrm)
    return pts, nrm


@numba.njit(cache=True, fastmath=False)
def _normals(pts, lens, nrm) -> None:
    start = 0
    for L in lens:
        for k in range(L):
            a = start + (k + 2) % L
            b = start + (k - 2) % L
            tx = pts[a, 0] - pts[b, 0]
            ty = pts[a, 1] - pts[b, 1]
            ln = math.hypot(tx, ty)
            i = start + k
            if ln > 0.0:
                nrm[i, 0] = -ty / ln
                nrm[i, 1] = tx / ln
            else:  # a one-pixel spike: no direction, never an inlier
                nrm[i, 0] = 0.0
                nrm[i, 1] = 0.0
        start += L


def recentre(
    img: np.ndarray, s: BallSearch, blob: Blob, v_floor: int, gains: np.ndarray | None, params: BallParams
) -> tuple[float, float, float] | None:
    """The circle ``(u, v, r)`` (full-resolution pixels) of the ball near ``blob``, from its visible outline.

    Looks in a window of about twice the blob's radius around it, at full
    resolution, so the pieces of a ball split by a pole are seen together.
    None when no circle has enough support.
    """
    H, W = img.shape[:2]
    r0 = float(blob.radius)
    half = int(math.ceil(2.2 * r0 + 3.0))
    x0, x1 = max(0, int(blob.u) - half), min(W, int(blob.u) + half + 1)
    y0, y1 = max(0, int(blob.v) - half), min(H, int(blob.v) + half + 1)
    if x1 - x0 < 8 or y1 - y0 < 8:
        return None
    roi = correct(np.ascontiguousarray(img[y0:y1, x0:x1]), gains)
    hsv = cv2.cvtColor(roi, cv2.COLOR_BGR2HSV_FULL)
    mask = hue_mask(hsv, s, params.hue_tol_deg, v_floor)
    pts, nrm = outline_points(mask)
    if len(pts) < 12:
        return None
    rmin = max(0.6 * params.min_radius_px, 0.6 * r0)
    rmax = 2.0 * r0 + 2.0
    tol = max(0.9, 0.05 * r0)
    cos_max = math.cos(math.radians(params.max_rim_slope_deg))
    ok, u, v, r, k = _ransac_normals(np.ascontiguousarray(pts), np.ascontiguousarray(nrm), tol, cos_max,
                                     rmin, rmax, _DRAWS)
    # The outline runs through the outermost mask pixel centres: half a
    # pixel inside the rim.  Support: share of the circle's own outline.
    if not ok or k < max(10.0, 0.25 * 0.87 * 2.0 * math.pi * r):
        return None
    return u + x0, v + y0, r + 0.5


def hue_mask(hsv: np.ndarray, s: BallSearch, tol_deg: float, v_floor: int) -> np.ndarray:
    """The coarse search's mask (:func:`~.search.hue_masks`) for one marker, by ranges (red wraps around)."""
    s_floor = int(np.clip(0.4 * 255 * s.saturation, 40, 110))
    lo = (s.hue_deg - tol_deg - 0.71) * 256.0 / 360.0
    hi = (s.hue_deg + tol_deg + 0.71) * 256.0 / 360.0
    a, b = int(math.ceil(lo)), int(math.floor(hi))
    if a < 0 or b > 255:
        a, b = a % 256, b % 256
        m1 = cv2.inRange(hsv, (a, s_floor, v_floor), (255, 255, 255))
        m2 = cv2.inRange(hsv, (0, s_floor, v_floor), (b, 255, 255))
        return cv2.bitwise_or(m1, m2)
    return cv2.inRange(hsv, (a, s_floor, v_floor), (b, 255, 255))


@numba.njit(cache=True, fastmath=False)
def _ransac_normals(pts, nrm, tol, cos_max, rmin, rmax, draws):
    """Circle with the most outline points on it whose normals are radial: ``(ok, u, v, r, count)``."""
    n = pts.shape[0]
    best = -1
    bu = bv = br = 0.0
    for h in range(draws.shape[0]):
        i0 = int(draws[h, 0] * n) % n
        i1 = int(draws[h, 1] * n) % n
        i2 = int(draws[h, 2] * n) % n
        ax, ay = pts[i0, 0], pts[i0, 1]
        bx, by = pts[i1, 0], pts[i1, 1]
        cx, cy = pts[i2, 0], pts[i2, 1]
        # Points too close together give ill-conditioned circles.
        if min(math.hypot(ax - bx, ay - by), math.hypot(bx - cx, by - cy), math.hypot(ax - cx, ay - cy)) < rmin:
            continue
        ok, ux, uy, r = circle3(ax, ay, bx, by, cx, cy)
        if not ok:
            continue
        if r < rmin or r > rmax:
            continue
        cnt = _count(pts, nrm, ux, uy, r, tol, cos_max)
        if cnt > best:
            best = cnt
            bu, bv, br = ux, uy, r
    if best < 6:
        return False, 0.0, 0.0, 0.0, 0
    out = np.array([bu, bv, br])
    mask = np.empty(n, np.bool_)
    for _ in range(2):
        k = 0
        for i in range(n):
            mask[i] = _inlier(pts, nrm, i, out[0], out[1], out[2], tol, cos_max)
            if mask[i]:
                k += 1
        if k < 6 or not kasa_circle(pts, mask, out):
            return False, 0.0, 0.0, 0.0, 0
    return True, out[0], out[1], out[2], _count(pts, nrm, out[0], out[1], out[2], tol, cos_max)


@numba.njit(cache=True, fastmath=False, inline="always")
def _inlier(pts, nrm, i, ux, uy, r, tol, cos_max):
    dx = pts[i, 0] - ux
    dy = pts[i, 1] - uy
    dd = math.hypot(dx, dy)
    if abs(dd - r) > tol or dd <= 0.0:
        return False
    return abs(dx * nrm[i, 0] + dy * nrm[i, 1]) >= cos_max * dd


@numba.njit(cache=True, fastmath=False)
def _count(pts, nrm, ux, uy, r, tol, cos_max):
    k = 0
    for i in range(pts.shape[0]):
        if _inlier(pts, nrm, i, ux, uy, r, tol, cos_max):
            k += 1
    return k


def smooth_rim(radius: np.ndarray, valid: np.ndarray, ang: np.ndarray, max_slope_deg: float) -> np.ndarray:
    """Rays whose rim point's outline is nearly perpendicular to the ray (the normal test on the sub-pixel rim).

    The outline's angle against the ray is ``atan(dr / (r dphi))`` between
    neighbouring rays (``ang`` evenly spaced around the circle); a point
    passes if on at least one side it is below ``max_slope_deg`` (the last
    point of an arc before an occluder has a steep step on one side only).
    Points without a valid neighbour pass.
    """
    out = np.empty(len(radius), np.bool_)
    smooth_kernel(radius, valid, math.tan(math.radians(max_slope_deg)) * 2.0 * math.pi / max(len(radius), 1), out)
    return out


@numba.njit(cache=True, fastmath=False)
def smooth_kernel(radius, valid, lim_dphi, out):
    n = radius.shape[0]
    for i in range(n):
        out[i] = valid[i]
        if not valid[i] or n < 3:
            continue
        r = max(radius[i], 1e-9)
        seen = False
        ok = False
        for j in ((i + 1) % n, (i - 1) % n):
            if valid[j]:
                seen = True
                if abs(radius[j] - radius[i]) <= lim_dphi * r:
                    ok = True
        out[i] = ok or not seen
