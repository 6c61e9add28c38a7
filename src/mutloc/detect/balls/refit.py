"""A ball measured again where, and as large as, a pose says it must appear.

The first look (:func:`~.detector.detect_balls`) fits a ball's rim with its
size free: three parameters (direction and angular radius) from whatever
arc is visible.  For a partly hidden ball that arc is short, and the centre
slides along it with the radius.  Once a pose is known (from the other
balls and the other robot's view), the ball's distance is known, hence its
angular radius ``asin(R / distance)``: the rim is then fitted with that
radius fixed and only the direction free, which a short arc pins down
well.  The rays are cast from the predicted centre, so the rim found is the
one of the ball the pose expects, not of a look-alike elsewhere; rim points
on an occluder's edge fail the normal test (:func:`~.occlusion.smooth_rim`)
and the robust fit.

:func:`refit_ball` works on one ball given its centre in the camera frame;
:class:`RefitContext` holds what is computed once per image.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ...core.camera import Camera
from ...core.rig import Marker
from ..base import Detection, as_bgr
from .choose import score_candidate
from .cues import hue_chroma
from .fit import CameraModel, Fit, bearings, cone_rim
from .light import light_gains, lut_gains
from .occlusion import smooth_rim
from .params import BallParams, value_lut
from .rim import Rim, edges_kernel, rim_radii, sample_rim
from .search import BallSearch, find_blobs, value_floor

__all__ = ["RefitContext", "apparent_radius_px", "balls_near", "fixed_cone_fit", "refit_ball"]


@dataclass
class RefitContext:
    """One image and what every refit in it shares (unmixing values, light colour, camera)."""

    img: np.ndarray
    cam: CameraModel
    params: BallParams
    lut: np.ndarray
    gains: np.ndarray | None
    rim_gains: np.ndarray

    @classmethod
    def of(cls, image: np.ndarray, camera: Camera, params: BallParams | None = None) -> "RefitContext":
        params = params or BallParams()
        img = as_bgr(image)
        gains = light_gains(img, params)
        return cls(img, CameraModel(camera), params, value_lut(bool(params.srgb), float(params.mix_gamma)),
                   gains, lut_gains(gains, params))


def fixed_cone_fit(bear: np.ndarray, ok: np.ndarray, init: np.ndarray, d0: np.ndarray, cos_a: float,
                   f: float, iterations: int = 10) -> tuple[np.ndarray, np.ndarray, float] | None:
    """Robust axis ``d`` of the cone ``b . d = cos_a`` (half-angle fixed) through bearings ``bear``.

    Gauss-Newton on the two tangent directions of ``d`` (started at ``d0``),
    residuals in pixels (angular distance to the cone times ``f``), Tukey
    weights at 4 robust sigmas (floored at 0.08 px) re-estimated each step,
    starting from the rows in ``init``.  Returns ``(d, weights, rms_px)``, or
    None with fewer than 4 rows of weight.
    """
    sin_a = math.sqrt(max(1.0 - cos_a * cos_a, 1e-18))
    d = np.asarray(d0, float) / np.linalg.norm(d0)
    w = (ok & init).astype(float)
    B = np.where(ok[:, None], bear, 0.0)
    res = np.zeros(len(B))
    for it in range(iterations):
        if np.count_nonzero(w) < 4:
            return None
        a = np.array([1.0, 0.0, 0.0]) if abs(d[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
        e1 = np.cross(d, a)
        e1 /= np.linalg.norm(e1)
        e2 = np.cross(d, e1)
        res = (B @ d - cos_a) / sin_a * f
        J = np.column_stack([B @ e1, B @ e2]) / sin_a * f
        JW = J * w[:, None]
        A = JW.T @ J
        if np.linalg.cond(A) > 1e10:
            return None
        step = np.linalg.solve(A, -JW.T @ res)
        d = d + step[0] * e1 + step[1] * e2
        d /= np.linalg.norm(d)
        res = (B @ d - cos_a) / sin_a * f
        sig = max(1.4826 * float(np.median(np.abs(res[w > 0]))), 0.08)
        u = np.where(ok, res / (4.0 * sig), np.inf)
        w_new = np.where(np.abs(u) < 1.0, (1.0 - u * u) ** 2, 0.0)
        change = float(np.max(np.abs(w_new - w)))
        w = w_new
        if it >= 1 and change < 0.02 and float(np.hypot(*step)) < 1e-7:
            break
    if w.sum() < 3.0:
        return None
    return d, w, float(np.sqrt(np.sum(w * res**2) / w.sum()))


def _fit(ctx: RefitContext, rim: Rim, init: np.ndarray, d0: np.ndarray, cos_a: float) -> Fit | None:
    bear, fin = bearings(ctx.cam, rim.pts, rim.valid)
    out = fixed_cone_fit(bear, fin, init, d0, cos_a, ctx.cam.f)
    if out is None:
        return None
    d, w, rms = out
    outline = cone_rim(ctx.cam.camera, d, cos_a)
    if outline is None:
        return None
    n = len(outline)
    cx, cy = float(outline[:, 0].sum() / n), float(outline[:, 1].sum() / n)
    radii = rim_radii(outline, cx, cy, rim.ang)
    return Fit(outline, np.array([cx, cy]), radii, float(radii.sum() / len(radii)), w, rms, d, cos_a)


def _predicted(ctx: RefitContext, radius_m: float, centre: np.ndarray
               ) -> tuple[np.ndarray, float, np.ndarray, float] | None:
    """(unit direction, cos of the angular radius, projected outline, mean outline radius px) of a ball."""
    X = np.asarray(centre, float)
    dist = float(np.linalg.norm(X))
    if not (X[2] > 0.0 and dist > radius_m):
        return None
    d = X / dist
    cos_a = math.sqrt(1.0 - (radius_m / dist) ** 2)
    outline = cone_rim(ctx.cam.camera, d, cos_a)
    if outline is None:
        return None
    c = outline.mean(axis=0)
    return d, cos_a, outline, float(np.hypot(outline[:, 0] - c[0], outline[:, 1] - c[1]).mean())


def _near(rim: Rim, rexp: np.ndarray, tol: float) -> np.ndarray:
    """Rays whose edge lies within ``tol`` pixels of the expected radius."""
    return rim.valid & (np.abs(np.where(rim.valid, rim.radius, 1e9) - rexp) <= tol)


def _narrow_resample(ctx: RefitContext, rim: Rim, near: np.ndarray, rexp: np.ndarray, tol: float,
                     half_px: float, max_colour_deg: float = 8.0) -> np.ndarray:
    """Rays whose edge missed the expected outline measured again in a window of ``+-half_px`` around it.

    Against a background of a hue near the ball's (a light stripe next to
    it, a poster), the wide window's far end is not the colour that mixes in
    the rim's pixels, and the edge lands pixels off.  The pose places the
    outline to a fraction of a pixel, so the colours just either side of it
    are the ones to unmix.  Replaces those rays in ``rim`` in place; returns
    the new ``near``.
    """
    params = ctx.params
    n = len(rim.ang)
    e = np.empty(n)
    valid = np.empty(n, np.bool_)
    inner = np.empty((n, 3))
    contrast = np.empty(n)
    h = min(half_px, max(float(rexp.min()) - 0.75, 1.5))
    edges_kernel(ctx.img, ctx.lut, ctx.rim_gains, rim.cx, rim.cy, rim.ang, rexp, h, 2.0 * h, params.step_px,
                 e, valid, inner, contrast)
    take = ~near & valid & (np.abs(np.where(valid, e, 1e9) - rexp) <= tol)
    # Only where the inside is the ball's colour (that of the rays that did
    # find the outline): an occluder's edge near the outline must not count.
    if np.count_nonzero(near) < 4:
        return near
    ref = np.median(rim.inner[near] / np.linalg.norm(rim.inner[near], axis=1, keepdims=True), axis=0)
    ref /= np.linalg.norm(ref)
    cosang = (inner @ ref) / np.maximum(np.linalg.norm(inner, axis=1), 1e-12)
    take &= np.where(take, cosang, 0.0) > math.cos(math.radians(max_colour_deg))
    rim.radius = np.where(take, e, rim.radius)
    rim.valid = rim.valid | take
    rim.inner = np.where(take[:, None], inner, rim.inner)
    rim.contrast = np.where(take, contrast, rim.contrast)
    return near | take


def _ball_coloured(ctx: RefitContext, rim: Rim, hue_deg: float, min_chroma: float = 8.0) -> np.ndarray:
    """Rays whose inner colour (the ball's side of their edge) has the marker's hue: within twice
    ``hue_tol_deg`` and with a chroma (0..255) of at least ``min_chroma``.

    A ray from a partly hidden ball's centre that runs over the occluder finds the occluder's far edge,
    which can lie near the ball's outline (an occluder about as wide as the ball): its edge is a step
    from the occluder's colour, not from the ball's, and must not count as rim.
    """
    ok = rim.valid.copy()
    for i in np.flatnonzero(ok):
        # As the score measures the ball's colour (choose.score_candidate), one ray at a time.
        c = rim.inner[i]
        hue, chroma = hue_chroma(c / max(1.0, float(c.max())), ctx.lut)
        ok[i] = chroma >= min_chroma and abs((hue - hue_deg + 180.0) % 360.0 - 180.0) <= 2.0 * ctx.params.hue_tol_deg
    return ok


def apparent_radius_px(ctx: RefitContext, name: str, marker: Marker, centre: np.ndarray) -> float | None:
    """Mean radius (pixels) of the outline a ball at camera-frame ``centre`` projects to (None: it does not)."""
    p = _predicted(ctx, BallSearch.from_marker(name, marker, ctx.params).radius_m, centre)
    return None if p is None else p[3]


def refit_ball(ctx: RefitContext, name: str, marker: Marker, centre: np.ndarray, *,
               radius_offset_px: float = 0.0, max_shift_px: float | None = None,
               narrow_px: float | None = 1.5, narrow_below: float = 0.3) -> Detection | None:
    """``marker``'s ball measured with the size its camera-frame ``centre`` (metres) gives it.

    ``radius_offset_px`` is added to that size: the rim measurement's own
    bias (the first look sees whole balls' rims a few hundredths of a pixel
    inside their true outline), which a fixed size would otherwise turn into
    a shift of a short arc's centre.

    The rim is sampled along rays from where ``centre`` projects, expected
    on its projected outline; points near that outline start a robust fit of
    the ball's direction with its angular radius fixed, and a second round
    of rays from the fitted centre polishes it.  None when the ball cannot
    be measured there: too little rim (below ``params.min_visible_fraction``),
    not of the marker's colour, or a centre more than ``max_shift_px``
    (default: a third of the radius plus a pixel) from the prediction.

    When that finds the ball missing or under ``narrow_below`` of its rim,
    the rays whose edge missed the outline are measured again within
    ``+-narrow_px`` of it (see :func:`_narrow_resample`) and the ball with
    more rim is kept.  Only then: those rays' edges run a little inside the
    outline (~0.1-0.3 px) and would shift a ball measured well without them.
    """
    det = _refit(ctx, name, marker, centre, radius_offset_px, max_shift_px, None)
    if narrow_px is None or (det is not None and float(det.visible_fraction or 0.0) >= narrow_below):
        return det
    again = _refit(ctx, name, marker, centre, radius_offset_px, max_shift_px, narrow_px)
    if again is None or (det is not None and float(again.visible_fraction or 0.0) <= float(det.visible_fraction or 0.0)):
        return det
    return again


def _refit(ctx: RefitContext, name: str, marker: Marker, centre: np.ndarray, radius_offset_px: float,
           max_shift_px: float | None, narrow_px: float | None) -> Detection | None:
    params = ctx.params
    s = BallSearch.from_marker(name, marker, params)
    pred = _predicted(ctx, s.radius_m, centre)
    if pred is None:
        return None
    d0, cos_a, outline, r0 = pred
    if radius_offset_px:
        # The angular radius scaled as the outline's: tan(a) ~ radius in pixels.
        tan_a = math.sqrt(1.0 - cos_a * cos_a) / cos_a * max(r0 + radius_offset_px, 0.5) / r0
        cos_a = 1.0 / math.sqrt(1.0 + tan_a * tan_a)
        outline = cone_rim(ctx.cam.camera, d0, cos_a)
        if outline is None:
            return None
    H, W = ctx.img.shape[:2]
    cx, cy = float(outline[:, 0].mean()), float(outline[:, 1].mean())
    if not (0.0 <= cx < W and 0.0 <= cy < H):
        return None
    n_rays = min(max(round(2.0 * math.pi * float(np.mean(np.hypot(outline[:, 0] - cx, outline[:, 1] - cy)))), 24), 96)
    ang = np.arange(n_rays) * (2.0 * math.pi / n_rays)
    rexp = rim_radii(outline, cx, cy, ang)
    r = float(rexp.mean())
    uv0 = ctx.cam.camera.project(d0)
    limit = (1.0 + r / 3.0) if max_shift_px is None else float(max_shift_px)
    d = d0
    fit = rim = None
    for it in range(2):
        rim = sample_rim(ctx.img, ctx.lut, cx, cy, ang, rexp, params.local_half_window_px, params.step_px,
                         ctx.rim_gains)
        tol = max(1.0, 0.1 * r) if it == 0 else max(0.75, 0.05 * r)
        near = _near(rim, rexp, tol)
        if narrow_px is not None and not near.all():
            near = _narrow_resample(ctx, rim, near, rexp, tol, narrow_px)
        rim.valid = smooth_rim(rim.radius, rim.valid, rim.ang, params.max_rim_slope_deg)
        rim.valid = _ball_coloured(ctx, rim, s.hue_deg)
        fit = _fit(ctx, rim, near & rim.valid, d, cos_a)
        if fit is None:
            return None
        d = fit.direction
        cx, cy = float(fit.centre_px[0]), float(fit.centre_px[1])
        rexp = fit.radii
    assert fit is not None and rim is not None
    cand = score_candidate(ctx.img, ctx.lut, s, 1.0, rim, fit, ctx.cam, params, rim_gains=ctx.rim_gains)
    if cand is None:
        return None
    vis = float(cand.info["rim_fraction"])
    dh = abs((float(cand.info["hue_deg"]) - s.hue_deg + 180.0) % 360.0 - 180.0)
    if vis < params.min_visible_fraction or dh > 1.5 * params.hue_tol_deg:
        return None
    if float(np.hypot(*(cand.uv - uv0))) > limit:
        return None
    cand.info["refit"] = True
    return Detection(marker=name, uv=cand.uv, score=cand.score, info=cand.info, visible_fraction=vis,
                     residual_px=float(cand.info["rms_px"]), sigma_scale=float(cand.info["sigma_scale"]))


def balls_near(ctx: RefitContext, name: str, marker: Marker, distance_m: float,
               reach: list[tuple[np.ndarray, float]]) -> list[Detection]:
    """``marker``'s ball measured as :func:`refit_ball` does, at ``distance_m``, on each blob of its colour
    whose circle comes within ``reach`` (``(pixel, radius px)`` pairs) -- whatever the blob scores.

    For a ball the first look turned down: a partly hidden one scores low for
    being hidden and its free size is off; the blob's circle is found again
    from its visible outline (as the detector's rescue does) and the ball
    measured from there with the size ``distance_m`` gives it.
    """
    from .detector import refine_blob

    params = ctx.params
    s = BallSearch.from_marker(name, marker, params)
    H, W = ctx.img.shape[:2]
    rmax = float(params.max_radius_px) if params.max_radius_px is not None else min(H, W) / 3.0
    k = 2 if min(H, W) // 2 >= 120 else 1
    vf = value_floor(ctx.img)
    out = []
    blobs = [b for b in find_blobs(ctx.img, [s], k, rmax, vf, params, gains=ctx.gains)[0]
             if any(math.hypot(b.u - float(uv[0]), b.v - float(uv[1])) <= r + b.radius for uv, r in reach)]
    for b in blobs[: 2 * int(params.max_candidates)]:
        c = refine_blob(ctx.img, ctx.lut, s, b, ctx.cam, rmax, params, v_floor=vf, gains=ctx.gains, recentre_it=True)
        uv = c.uv if c is not None else np.array([b.u, b.v])
        d = refit_ball(ctx, name, marker, ctx.cam.camera.pixels_to_bearings(uv) * distance_m)
        if d is not None and not any(float(np.hypot(*(d.uv - o.uv))) < 1.0 for o in out):
            out.append(d)
    return out
