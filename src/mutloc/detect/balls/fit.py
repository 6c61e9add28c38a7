"""Fit of the rim: a circular cone of bearings with a camera, an ellipse without.

The image of a sphere is an ellipse whose centre is *not* the projection of
the sphere's centre (0.6 px apart for a 3 cm ball at 1 m near the corner of
a 960x540, f = 800 px frame).  With a camera the rim points become bearings
and a circular cone is fitted robustly (IRLS, Tukey); its axis is the
direction of the sphere centre, which removes that bias and handles lens
distortion.  Without a camera an ellipse is fitted and its centre is the
estimate.  Occluded or out-of-frame parts of the rim are outliers of the
fit, so the visible arc alone determines the ball.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import cv2
import numba
import numpy as np

from ...core.camera import Camera, project_many
from ...errors import InputError
from .numeric import kasa_circle, median_inplace, solve3
from .rim import Rim, rim_radii

__all__ = [
    "OUTLINE_POINTS",
    "CameraModel",
    "Fit",
    "bearings",
    "cone_fit",
    "cone_rim",
    "cone_rim_kernel",
    "ellipse_info",
    "fit_circle",
    "fit_ellipse",
    "fit_ellipse_irls",
    "fit_rim",
    "pinhole_bearings_kernel",
]

# Points on a fitted outline.
OUTLINE_POINTS = 48


class CameraModel:
    """A camera and what the fit needs of it, computed once per image."""

    def __init__(self, camera: Camera) -> None:
        self.camera = camera
        self.f = 0.5 * float(camera.K[0, 0] + camera.K[1, 1])
        self.pinhole = not np.any(camera.dist)
        self.Kinv = np.linalg.inv(camera.K)


@dataclass
class Fit:
    """A fitted outline of a ball's image.

    ``outline`` (48, 2) pixels, its mean ``centre_px`` and its ``radii``
    seen from there along the rim's rays (where the next round of rays
    expects the rim); ``weights`` per rim ray (0: outlier) and the ``rms``
    residual (pixels).  With a camera: the unit ``direction`` of the
    sphere's centre and ``cos_theta`` of the cone's half-angle; without:
    ``ellipse_centre``.
    """

    outline: np.ndarray
    centre_px: np.ndarray
    radii: np.ndarray
    radius_px: float  # the mean of radii
    weights: np.ndarray
    rms: float
    direction: np.ndarray | None = None
    cos_theta: float = 0.0
    ellipse_centre: np.ndarray | None = None


#: A centre known worse than this many times a whole ball's is reported at this scale (an arc so short
#: that it hardly fixes a centre is rejected by ``min_visible_fraction`` long before).
MAX_SIGMA_SCALE = 20.0


def centre_sigma_scale(ang: np.ndarray, used: np.ndarray) -> float:
    """How much worse a circle's centre is known from the rim rays ``used`` (a mask over the evenly spread
    rays at angles ``ang``) than from all of them: the square root of the ratio of the centre's worst
    variance, the radius free, to a whole rim's (``2 / n``), for the same noise on each ray.

    A ray at angle a measures ``-cos(a) dx - sin(a) dy - dr``; a rim seen all round fixes the centre
    from opposite sides, an arc only along its middle: with half the rim hidden the centre is about 3
    times worse along the hidden side (the radius with it), with 60 % hidden about 6 times.
    """
    return float(_centre_sigma_scale(np.ascontiguousarray(ang, dtype=np.float64),
                                     np.ascontiguousarray(used, dtype=np.bool_), MAX_SIGMA_SCALE))


@numba.njit(cache=True, fastmath=False)
def _centre_sigma_scale(ang, used, cap):
    n = ang.shape[0]
    m = 0
    cc = cs = ss = c1 = s1 = 0.0
    for i in range(n):
        if used[i]:
            c = math.cos(ang[i])
            s = math.sin(ang[i])
            cc += c * c
            cs += c * s
            ss += s * s
            c1 += c
            s1 += s
            m += 1
    if m < 3 or n == 0:
        return cap
    # The centre block of the inverse of [[cc, cs, c1], [cs, ss, s1], [c1, s1, m]]: the Schur
    # complement of m, inverted.
    a = cc - c1 * c1 / m
    b = cs - c1 * s1 / m
    d = ss - s1 * s1 / m
    det = a * d - b * b
    if not det > 1e-12 * (a + d) ** 2:
        return cap
    # the largest eigenvalue of the 2x2 inverse is 1 / the smallest of [[a, b], [b, d]]
    tr = a + d
    small = 0.5 * (tr - math.sqrt(max((a - d) ** 2 + 4.0 * b * b, 0.0)))
    if not small > 0.0:
        return cap
    return min(max(math.sqrt(n / (2.0 * small)), 1.0), cap)


def fit_rim(rim: Rim, init: np.ndarray, cam: CameraModel | None, max_axis_ratio: float) -> Fit | None:
    """Robust outline through the valid points of ``rim`` (IRLS starts from the rays in ``init``).

    A cone with ``cam``, else an ellipse no more elongated than
    ``max_axis_ratio``; None if the fit fails.
    """
    pts = rim.pts
    direction = centre = None
    cos_t = 0.0
    if cam is not None:
        bear, fin = bearings(cam, pts, rim.valid)
        d = np.empty(3)
        w = np.empty(len(pts))
        ok, cos_t, rms = cone_fit(bear, fin, init, cam.f, d, w)
        outline = cone_rim(cam.camera, d, cos_t) if ok else None
        if outline is None:
            return None
        direction = d
    else:
        fit = fit_ellipse_irls(pts, init, max_axis_ratio)
        if fit is None:
            return None
        outline, w, rms, centre = fit
    # sum / n is what ndarray.mean computes, without its overhead.
    n = len(outline)
    cx, cy = float(outline[:, 0].sum() / n), float(outline[:, 1].sum() / n)
    radii = rim_radii(outline, cx, cy, rim.ang)
    return Fit(outline, np.array([cx, cy]), radii, float(radii.sum() / len(radii)), w, rms, direction, cos_t, centre)


# ---------------------------------------------------------------------------
# with a camera: a cone of bearings
# ---------------------------------------------------------------------------


@numba.njit(cache=True, fastmath=False)
def cone_fit(bear, fin, init, f, d, w):
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
        if not solve3(M, rhs, m):
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
        sig = max(1.4826 * median_inplace(absr, k), 0.08)
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


def cone_rim(camera: Camera, d: np.ndarray, cos_t: float, n: int = OUTLINE_POINTS) -> np.ndarray | None:
    """Pixels (n, 2) of the cone's rim: the outline of the sphere's image; None if it does not project."""
    uv = np.empty((n, 2))
    return uv if cone_rim_kernel(camera.K, camera.dist, d, cos_t, uv) else None


@numba.njit(cache=True, fastmath=False)
def cone_rim_kernel(K, dist, d, cos_t, uv) -> bool:
    """Writes the rim's pixels into ``uv``; False if some do not project (not finite)."""
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
    for i in range(n):
        if not (math.isfinite(uv[i, 0]) and math.isfinite(uv[i, 1])):
            return False
    return True


@numba.njit(cache=True, fastmath=False)
def pinhole_bearings_kernel(Ki, pts, ok, bear) -> None:
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


def bearings(cam: CameraModel, pts: np.ndarray, ok: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Unit bearings (n, 3) of pixels ``pts`` where ``ok``; also the rows that have one."""
    if cam.pinhole:
        bear = np.empty((len(pts), 3))
        ok = ok.copy()
        pinhole_bearings_kernel(cam.Kinv, pts, ok, bear)
        return bear, ok
    bear = np.zeros((len(pts), 3))
    ok = ok & np.isfinite(pts[:, 0]) & np.isfinite(pts[:, 1])
    if not np.any(ok):
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


# ---------------------------------------------------------------------------
# without a camera: an ellipse
# ---------------------------------------------------------------------------


def fit_ellipse_irls(
    pts: np.ndarray, init: np.ndarray, max_axis_ratio: float
) -> tuple[np.ndarray, np.ndarray, float, np.ndarray] | None:
    """Robust ellipse through the rim points: ``(outline, weights, rms, centre)``.

    A sphere's image is an ellipse of modest eccentricity; when the visible
    arc is too short to pin down five parameters (the fit degenerates or
    comes out more elongated than ``max_axis_ratio``) a circle is fitted
    instead.
    """
    finite = np.all(np.isfinite(pts), axis=1)
    P = np.ascontiguousarray(np.where(finite[:, None], pts, 0.0))
    w = (init & finite).astype(np.float64)
    model = None
    res = np.zeros(len(P))
    for it in range(8):
        if w.sum() < 6:
            return None
        model = fit_ellipse(P, w, max_axis_ratio)
        if model is None:
            model = fit_circle(P, w)
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
    phi = np.linspace(0, 2 * math.pi, OUTLINE_POINTS, endpoint=False)
    ca, sa = math.cos(math.radians(ang)), math.sin(math.radians(ang))
    x, y = a * np.cos(phi), b * np.sin(phi)
    outline = np.column_stack([cu + ca * x - sa * y, cv_ + sa * x + ca * y])
    return outline, w, rms, np.array([cu, cv_])


def fit_circle(P: np.ndarray, w: np.ndarray) -> dict[str, Any] | None:
    """Least-squares circle of the points with ``w > 0``, in :func:`fit_ellipse`'s form."""
    out = np.empty(3)
    if not kasa_circle(P, w > 0, out):
        return None
    dist = np.hypot(P[:, 0] - out[0], P[:, 1] - out[1]) - out[2]
    return {"ellipse": ((float(out[0]), float(out[1])), (float(out[2]), float(out[2])), 0.0), "dist": dist}


def fit_ellipse(P: np.ndarray, w: np.ndarray, max_axis_ratio: float = math.inf) -> dict[str, Any] | None:
    """Weighted algebraic ellipse fit (Fitzgibbon's constraint), with distances.

    Returns ``{"ellipse": ((u, v), (semi-axis 0, semi-axis 1), angle_deg of
    axis 0), "dist": signed distance of every point (pixels)}``, or None if
    degenerate or more elongated than ``max_axis_ratio``.  Points are
    centred and scaled first; the distance is the Sampson approximation of
    the geometric one.
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
    if max(ax) > max_axis_ratio * min(ax):
        return None  # not the image of a sphere (or an arc too short to tell)
    # Semi-axis ax[0] lies along the first eigenvector.
    ang = math.degrees(math.atan2(evec[1, 0], evec[0, 0]))
    val = D @ a
    gx = 2 * A_ * x + B_ * y + D_
    gy = B_ * x + 2 * C_ * y + E_
    dist = val / np.maximum(np.hypot(gx, gy), 1e-12) * s
    centre = (float(xc * s + m[0]), float(yc * s + m[1]))
    return {"ellipse": (centre, (float(ax[0]), float(ax[1])), ang), "dist": dist}


def ellipse_info(outline: np.ndarray) -> dict[str, Any]:
    """A fitted outline as ``{centre, axes (semi), angle_deg}`` (OpenCV's angle), for reports."""
    (eu, ev), (A, B), ang = cv2.fitEllipse(outline.astype(np.float32))
    return {"centre": [float(eu), float(ev)], "axes": [float(A / 2), float(B / 2)], "angle_deg": float(ang)}
