"""One round of the first look's rays around a blob, compiled end to end (a pinhole camera).

:func:`~.detector.refine_blob` casts rays around each blob twice, and each
round is a chain of small steps: the sampling window (:func:`~.rim.window`),
the sub-pixel rim (:func:`~.rim.edges_kernel`), the rays near the expected
rim, the occluder test (:func:`~.occlusion.smooth_rim`), the rim points and
their bearings, the cone fit (:func:`~.fit.cone_fit`), its outline and the
radii seen from its centre (:func:`~.fit.fit_rim`).  Each step is cheap; in
Python, the calls between them cost as much as the steps.  :func:`sweep`
runs the chain as one compiled call, with the very same kernels and the
sums added in NumPy's order, so its figures are those of the step-by-step
code (which still serves other cameras, and the rescue of cut blobs).
:func:`measure` does the same for what the score measures of the ball
(:func:`~.choose.score_candidate`).
"""

from __future__ import annotations

import numba
import numpy as np

from ...core.camera import project_kernel
from .cues import encode_kernel, shading_kernel
from .fit import OUTLINE_POINTS, cone_fit, cone_rim_kernel, pinhole_bearings_kernel
from .numeric import column_medians, np_sum
from .occlusion import smooth_kernel
from .rim import edges_kernel, rim_points_kernel, rim_radii

__all__ = ["FAILED", "NO_RIM", "OK", "measure", "sweep"]

#: :func:`sweep`'s status: a fit, fewer than six rays to start it from, or a fit that failed.
OK, NO_RIM, FAILED = 0, 1, 2


@numba.njit(cache=True, fastmath=False)
def sweep(img, lut, gain, cx, cy, ang, rexp, local_half_window, step, tol0, slope_lim, Kinv, K, dist, f):
    """Rays at ``ang`` from ``(cx, cy)`` expecting the rim at ``rexp``: rim, cone fit and outline.

    ``tol0``: how far from ``rexp`` a ray's rim may be to start the fit;
    ``slope_lim``: :func:`~.occlusion.smooth_rim`'s limit; ``Kinv``, ``K``,
    ``dist`` (all zero) and ``f``: the pinhole camera (:class:`~.fit.CameraModel`).

    Returns ``(status, near, inner, direction, weights, cos_theta, rms,
    outline, centre_u, centre_v, radii, radius_px, radii_finite)``:
    ``near`` counts the rays within ``tol0`` before the occluder test;
    ``inner`` is the :class:`~.rim.Rim`'s (the ball colour per ray); the
    rest is the :class:`~.fit.Fit`'s (meaningful only when ``status`` is
    OK).
    """
    n = ang.shape[0]
    e = np.empty(n)
    valid = np.empty(n, np.bool_)
    inner = np.empty((n, 3))
    contrast = np.empty(n)
    d = np.zeros(3)
    w = np.zeros(n)
    outline = np.zeros((OUTLINE_POINTS, 2))
    radii = np.zeros(n)
    # rim.window
    r = np_sum(rexp, 0, n) / n
    h = min(max(0.25 * r + 2.0, 2.5), 6.0)
    h = min(h, max(rexp.min() - 0.75, 1.5))
    edges_kernel(img, lut, gain, cx, cy, ang, rexp, h, local_half_window, step, e, valid, inner, contrast)
    near = np.empty(n, np.bool_)
    n_near = 0
    for i in range(n):
        near[i] = valid[i] and abs(e[i] - rexp[i]) <= tol0
        n_near += near[i]
    kept = np.empty(n, np.bool_)
    smooth_kernel(e, valid, slope_lim, kept)
    n_init = 0
    for i in range(n):
        near[i] = near[i] and kept[i]
        n_init += near[i]
    if n_init < 6:
        return NO_RIM, n_near, inner, d, w, 0.0, 0.0, outline, 0.0, 0.0, radii, 0.0, False
    pts = np.empty((n, 2))
    rim_points_kernel(cx, cy, ang, e, pts)
    bear = np.empty((n, 3))
    fin = kept.copy()
    pinhole_bearings_kernel(Kinv, pts, fin, bear)
    ok, cos_t, rms = cone_fit(bear, fin, near, f, d, w)
    if not ok or not cone_rim_kernel(K, dist, d, cos_t, outline):
        return FAILED, n_near, inner, d, w, 0.0, 0.0, outline, 0.0, 0.0, radii, 0.0, False
    m = outline.shape[0]
    cu = np_sum(outline[:, 0], 0, m) / m
    cv_ = np_sum(outline[:, 1], 0, m) / m
    radii = rim_radii(outline, cu, cv_, ang)
    finite = True
    for i in range(n):
        finite = finite and np.isfinite(radii[i])
    return (OK, n_near, inner, d, w, cos_t, rms, outline, cu, cv_, radii,
            np_sum(radii, 0, n) / n, finite)


@numba.njit(cache=True, fastmath=False)
def measure(img, lut, gain, w, inner_all, cx, cy, ang, radii, tol_deg, K, dist, d):
    """What :func:`~.choose.score_candidate` measures of a fitted ball (no light correction), compiled.

    ``gain``: the light's colour in the rim's values, ``w``: the fit's weights per ray, ``inner_all``
    the rim's inner colours, ``(cx, cy)`` the fitted centre, ``radii`` the fitted outline's radii
    along the rays at ``ang`` from it, ``tol_deg``: the shading cue's hue tolerance, ``d`` the cone's
    axis.  Returns
    ``(inliers, b, g, r, shading, uv)``: the rays with weight, the ball's
    median colour encoded to 0..255 (:func:`~.cues.hue_chroma`), its
    shading contrast (:func:`~.cues.shading_contrast`) and the projection
    of ``d``.
    """
    n = w.shape[0]
    k = 0
    for i in range(n):
        if w[i] > 0.0:
            k += 1
    inner = np.empty((k, 3))
    mid = np.empty((k, 2))
    j = 0
    for i in range(n):
        if w[i] > 0.0:
            for c in range(3):
                inner[j, c] = inner_all[i, c]
            mid[j, 0] = cx + 0.5 * radii[i] * np.cos(ang[i])
            mid[j, 1] = cy + 0.5 * radii[i] * np.sin(ang[i])
            j += 1
    ball = np.empty(3)
    column_medians(inner, ball)
    # ball / max(1.0, ball.max()): NumPy's max is NaN if any is, and
    # Python's max keeps 1.0 unless the other is larger.
    top = ball[0]
    for c in range(1, 3):
        if ball[c] > top or np.isnan(ball[c]):
            top = ball[c]
    if np.isnan(ball[0]):
        top = ball[0]
    div = top if top > 1.0 else 1.0
    b, g, r = encode_kernel(lut, ball[0] / div, ball[1] / div, ball[2] / div)
    shading = shading_kernel(img, lut, gain, cx, cy, inner, ball, mid, tol_deg)
    uv = np.empty(2)
    project_kernel(K, dist, d, uv)
    return k, b, g, r, shading, uv
