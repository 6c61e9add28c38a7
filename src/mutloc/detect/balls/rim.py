"""Sub-pixel rim: along rays from a centre, unmix ball and background colours.

Each ray's rim radius is the integral of the ball fraction across a short
window around the edge (see :func:`edges_kernel`).  That integral is the
edge position for any symmetric blur (optics, pixel area), and the unmixing
makes it independent of the ball's shading and of the background's
brightness.  (Values are partly linearised first: see
:attr:`~mutloc.detect.balls.params.BallParams.mix_gamma` for why not fully.)
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numba
import numpy as np

__all__ = ["Rim", "edges_kernel", "rim_points_kernel", "rim_radii", "sample_rim", "unmix_edge", "window"]


@dataclass
class Rim:
    """Rim measurements along ``n`` rays from ``(cx, cy)`` at angles ``ang``.

    ``radius`` is the edge distance along each ray (NaN where not
    ``valid``), ``pts`` the edge pixels (n, 2), ``inner`` the ball colour
    next to the edge (n, 3, in the unmixing values) and ``contrast`` the
    ball/background colour difference.
    """

    cx: float
    cy: float
    ang: np.ndarray
    radius: np.ndarray
    valid: np.ndarray
    inner: np.ndarray
    contrast: np.ndarray

    @property
    def pts(self) -> np.ndarray:
        """Edge pixels (n, 2); NaN where not valid."""
        out = np.empty((len(self.ang), 2))
        rim_points_kernel(float(self.cx), float(self.cy), self.ang, self.radius, out)
        return out


@numba.njit(cache=True, fastmath=False)
def rim_points_kernel(cx, cy, ang, radius, out) -> None:
    for i in range(ang.shape[0]):
        out[i, 0] = cx + math.cos(ang[i]) * radius[i]
        out[i, 1] = cy + math.sin(ang[i]) * radius[i]


def window(rexp: np.ndarray) -> float:
    """Half-width of the sampling window around the expected rim ``rexp`` (pixels).

    Wide enough for the blur of a small ball and the error of the coarse
    circle, never reaching the centre.
    """
    r = float(rexp.sum() / len(rexp))
    h = min(max(0.25 * r + 2.0, 2.5), 6.0)
    return min(h, max(float(rexp.min()) - 0.75, 1.5))


def sample_rim(
    img: np.ndarray, lut: np.ndarray, cx: float, cy: float, ang: np.ndarray, rexp: np.ndarray,
    local_half_window: float, step: float, gains: np.ndarray | None = None,
) -> Rim:
    """Measure the rim along rays at angles ``ang`` from ``(cx, cy)``, expected at radii ``rexp``.

    ``lut`` maps uint8 values to the values colours are unmixed in; the
    window is :func:`window` wide, refined to ``+- local_half_window``
    around the first edge, sampled every ``step`` pixels.  ``gains``
    (per channel B, G, R, in ``lut``'s values) divide out the light's
    colour first: the unmixing itself does not care, but whether ball and
    background differ enough in colour to unmix does.
    """
    g = np.ones(3) if gains is None else np.ascontiguousarray(gains, dtype=np.float64)
    n = len(ang)
    e = np.empty(n)
    valid = np.empty(n, np.bool_)
    inner = np.empty((n, 3))
    contrast = np.empty(n)
    edges_kernel(img, lut, g, cx, cy, ang, rexp, window(rexp), local_half_window, step, e, valid, inner, contrast)
    return Rim(cx, cy, ang, e, valid, inner, contrast)


@numba.njit(cache=True, fastmath=False)
def _sample(img, lut, gain, x, y, out) -> None:
    """Bilinear sample of the image in ``lut``'s values at ``(x, y)`` in [0, W-1] x [0, H-1]."""
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
        out[c] = gain[c] * (
            w00 * lut[img[y0, x0, c]]
            + w01 * lut[img[y0, x0 + 1, c]]
            + w10 * lut[img[y0 + 1, x0, c]]
            + w11 * lut[img[y0 + 1, x0 + 1, c]]
        )


@numba.njit(cache=True, fastmath=False)
def edges_kernel(img, lut, gain, cx, cy, ang, rexp, h, w2, step, e, valid, inner, contrast) -> None:
    """Sub-pixel rim radius along each ray ``(cx, cy) + t (cos a, sin a)``.

    The window ``t in rexp[i] +- h`` is sampled every ``step`` pixels, and
    the edge is found in it, then again in a window of ``+- w2`` around that
    first estimate (see :func:`unmix_edge`).  In a window, the first two
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
    G = np.empty(3)
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
            _sample(img, lut, gain, cx + cs * t, cy + sn * t, P[j])
        # First over the whole window, then over a window of +-w2 around
        # that first edge: the colours next to the rim are the ones that
        # mix in its pixels (a background that changes a few pixels out, a
        # poster's border, must not count).
        ok, ei, con = _unmix_edge(P, np.int64(0), K - 1, step, alpha, B, G)
        if not ok:
            continue
        j0 = int(round((ei - w2) / step))
        j1 = int(round((ei + w2) / step))
        if j0 > 0 or j1 < K - 1:
            j0 = max(j0, 0)
            j1 = min(j1, K - 1)
            if j1 - j0 < 6:
                continue
            ok, e2, con = _unmix_edge(P, j0, j1, step, alpha, B, G)
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
def unmix_edge(P, j0, j1, step, alpha, B):
    """Edge position (relative to sample ``j0``) of the colour profile ``P[j0..j1]`` sampled every ``step``.

    Writes the ball colour B (first two samples) and the ball fractions into
    ``alpha``; returns ``(ok, edge, contrast)``, not ok when the profile is
    not one clean ball-to-background step.
    """
    return _unmix_edge(P, j0, j1, step, alpha, B, np.empty(3))


@numba.njit(cache=True, fastmath=False)
def _unmix_edge(P, j0, j1, step, alpha, B, G):
    """:func:`unmix_edge` with the background colour's buffer ``G`` given (no allocation per ray)."""
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
    # Brightness trends of the ball and of the background towards the edge
    # (a sphere darkens or brightens steeply at its limb under a hard
    # light): the ball's share in each sample is unmixed against the
    # shading extrapolated to it, not against the window's ends.
    sb = 0.0
    sg = 0.0
    if wch > 0.0 and j1 - j0 >= 8:
        b0, _ = _unmix2(P, j0, B, G, bb, gg, bg, det)
        b2, _ = _unmix2(P, j0 + 2, B, G, bb, gg, bg, det)
        _, g0 = _unmix2(P, j1, B, G, bb, gg, bg, det)
        _, g2 = _unmix2(P, j1 - 2, B, G, bb, gg, bg, det)
        sb = 0.5 * (b2 - b0)
        sg = 0.5 * (g0 - g2)
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
            # Shading at this sample, extrapolated from each side, kept
            # within a factor of two of the ends'.
            s_b = min(max(1.0 + sb * (j - j0 - 0.5), 0.5), 2.0)
            s_g = min(max(1.0 + sg * (j1 - 0.5 - j), 0.5), 2.0)
            bet /= s_b
            gam /= s_g
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


@numba.njit(cache=True, fastmath=False, inline="always")
def _unmix2(P, j, B, G, bb, gg, bg, det):
    """(beta, gamma) of sample ``j``: ``P[j] ~ beta B + gamma G``."""
    pb = 0.0
    pg = 0.0
    for c in range(3):
        pb += P[j, c] * B[c]
        pg += P[j, c] * G[c]
    return (gg * pb - bg * pg) / det, (bb * pg - bg * pb) / det


@numba.njit(cache=True, fastmath=False)
def rim_radii(rim: np.ndarray, cx: float, cy: float, ang: np.ndarray) -> np.ndarray:
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
