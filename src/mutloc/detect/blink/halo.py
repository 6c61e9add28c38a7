"""Constants of the light measurement and the compiled halo-contour kernel of a clipped light."""

from __future__ import annotations

import math

import numba
import numpy as np

from ...core.refine import solve_spd

__all__ = ["FORBIDDEN", "SRGB_LUT", "CLIP_LEVEL", "HALO_LEVELS", "HALO_MIN_LEVEL", "MAX_PLATES", "halo_kernel"]

# Cost of forbidden pairs in the Hungarian problem (far above any real cost).
FORBIDDEN = 1e6

# sRGB-encoded uint8 -> linear light.
SRGB_LUT = np.array(
    [c / 12.92 if c <= 0.04045 else ((c + 0.055) / 1.055) ** 2.4 for c in np.arange(256) / 255.0],
    dtype=np.float32,
)
# A pixel at or above this (uint8) is taken as clipped.
CLIP_LEVEL = 250
# Levels of the halo contours, as fractions of the headroom above the
# background (see LightTracker._halo_centre), and the lowest level in linear
# light (well above the noise of a difference of two frames).
HALO_LEVELS = (0.1, 0.2, 0.35, 0.5, 0.7)
HALO_MIN_LEVEL = 0.04
# Background plates kept per light.
MAX_PLATES = 4


@numba.njit(cache=True)
def halo_kernel(h, cx, cy, levels, nray, step, rmax, iters, out):
    """Centre of the circular contours of a radially symmetric halo.

    ``h`` (float32, NaN where unknown: clipped, masked or outside) is the
    light's own contribution in linear light, decreasing away from its centre.
    Rays from ``(cx, cy)`` (array coordinates) are sampled bilinearly every
    ``step`` px out to ``rmax``; past the first unknown stretch (the clipped
    core) each ray's crossing of each level is interpolated.  Crossings are
    fitted robustly (Tukey IRLS) with ``r = rho_level + dx cos a + dy sin a
    + second harmonics`` (an ellipse's contours have those), and the centre
    is moved by ``(dx, dy)``; ``iters`` rounds of rays.

    ``out``: centre x, y, inlier crossings, quadrants (of 4) holding inliers,
    robust residual scale (px).  Returns False when there is too little to fit.
    """
    hh, ww = h.shape
    nl = levels.shape[0]
    ns = int(rmax / step) + 1
    buf = np.empty(ns)
    npar = nl + 4
    maxc = nray * nl
    rows_l = np.empty(maxc, np.int64)
    rows_a = np.empty(maxc)
    rr = np.empty(maxc)
    wts = np.empty(maxc)
    res = np.empty(maxc)
    ata = np.empty((npar, npar))
    atb = np.empty(npar)
    sol = np.zeros(npar)
    row = np.empty(npar)
    x = cx
    y = cy
    n = 0
    scale = 0.0
    for it in range(iters):
        # --- crossings ---
        n = 0
        for i in range(nray):
            a = 2.0 * math.pi * i / nray
            ca = math.cos(a)
            sa = math.sin(a)
            for j in range(ns):
                px = x + ca * j * step
                py = y + sa * j * step
                if px < 0.0 or py < 0.0 or px > ww - 1.0 or py > hh - 1.0:
                    buf[j] = np.nan
                    continue
                x0 = min(int(px), ww - 2)
                y0 = min(int(py), hh - 2)
                fx = px - x0
                fy = py - y0
                buf[j] = ((1.0 - fx) * (1.0 - fy) * h[y0, x0] + fx * (1.0 - fy) * h[y0, x0 + 1]
                          + (1.0 - fx) * fy * h[y0 + 1, x0] + fx * fy * h[y0 + 1, x0 + 1])
            j0 = 0
            while j0 < ns and not math.isfinite(buf[j0]):
                j0 += 1
            if j0 >= ns:
                continue
            for lv in range(nl):
                t = levels[lv]
                if not buf[j0] > t:
                    continue  # the crossing is hidden in the clipped core
                for j in range(j0 + 1, ns):
                    v = buf[j]
                    if not math.isfinite(v):
                        break  # unknown before crossing: no measurement
                    if v <= t:
                        u = buf[j - 1]
                        rr[n] = step * (j - 1 + (u - t) / (u - v))
                        rows_l[n] = lv
                        rows_a[n] = a
                        n += 1
                        break
        if n < 12:
            return False
        # --- robust fit ---
        for k in range(n):
            wts[k] = 1.0
        for rnd in range(8):
            for p in range(npar):
                atb[p] = 0.0
                for q in range(npar):
                    ata[p, q] = 0.0
            for k in range(n):
                wk = wts[k]
                if wk <= 0.0:
                    continue
                for p in range(npar):
                    row[p] = 0.0
                row[rows_l[k]] = 1.0
                a = rows_a[k]
                row[nl] = math.cos(a)
                row[nl + 1] = math.sin(a)
                row[nl + 2] = math.cos(2.0 * a)
                row[nl + 3] = math.sin(2.0 * a)
                for p in range(npar):
                    if row[p] == 0.0:
                        continue
                    atb[p] += wk * row[p] * rr[k]
                    for q in range(npar):
                        ata[p, q] += wk * row[p] * row[q]
            for p in range(npar):
                ata[p, p] += 1e-9
            if not solve_spd(ata, atb, sol):  # normal equations: SPD
                return False
            for k in range(n):
                a = rows_a[k]
                res[k] = abs(rr[k] - sol[rows_l[k]] - sol[nl] * math.cos(a) - sol[nl + 1] * math.sin(a)
                             - sol[nl + 2] * math.cos(2.0 * a) - sol[nl + 3] * math.sin(2.0 * a))
            scale = max(0.1, 1.4826 * np.median(res[:n]))
            c = 4.685 * scale
            for k in range(n):
                u = res[k] / c
                wts[k] = (1.0 - u * u) ** 2 if u < 1.0 else 0.0
        x += sol[nl]
        y += sol[nl + 1]
        if abs(sol[nl]) < 0.01 and abs(sol[nl + 1]) < 0.01:
            break
    inl = 0
    quad = np.zeros(4, np.int64)
    for k in range(n):
        if wts[k] > 0.0:
            inl += 1
            quad[int(rows_a[k] / (0.5 * math.pi)) % 4] = 1
    out[0] = x
    out[1] = y
    out[2] = inl
    out[3] = quad.sum()
    out[4] = scale
    return True


