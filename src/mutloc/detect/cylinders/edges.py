"""Stage 3 of the cylinder detector: sub-pixel silhouette edges (across) and
band boundaries (along), and the refined band centres."""

from __future__ import annotations

import math
import statistics
from typing import Any

import cv2
import numpy as np

from ...core.camera import Camera
from .runs import Run, code_runs

__all__ = ["EDGE_LUT", "axis_u", "reads_code", "refine"]

# The values in which edges are located: encoded grey levels raised to 1.7,
# part way to linear light (as the ball detector's, see _MIX_GAMMA there).
# Pixel area and blur mix *light*: in encoded values a dark band's edges
# sit ~0.2 px inside it (the bands read thinner, the code's pitch shorter);
# JPEG's chroma subsampling, on the other hand, mixes encoded values.
EDGE_LUT = ((np.arange(256) / 255.0) ** 1.7 * 255.0).astype(np.float32)


def _edge(profile: np.ndarray, i0: int, i1: int, a: float, b: float) -> float | None:
    """Position of a step from level ``a`` to ``b`` within samples ``i0..i1`` (integral method)."""
    if abs(a - b) < 8:
        return None
    seg = profile[i0:i1 + 1]
    frac = np.clip((seg - b) / (a - b), 0.0, 1.0)
    return i0 - 0.5 + float(frac.sum())


def _across(g: np.ndarray, rows: list[int], cx0: float, cx1: float, R: float, prior: float = 0.0
            ) -> tuple[float, float, float, set[int]] | None:
    """The silhouette's centre line ``x = cx0 + cx1 v`` and half-width from
    both edges on ``rows`` (of dark bands: their shading is too dark to bend
    the edge profile).

    Each edge is located by the integral method between the levels just
    outside and just inside it; the left and right edges are fitted robustly
    as two parallel lines ``R`` either side of the centre line, so dark
    clutter touching a band on one side (or an edge of the background close
    by) costs only that side's rows.  ``(cx0, cx1, R)`` is the starting
    guess, ``R`` from the band height and the cylinder's proportions; the
    line starts where most edges put it.  ``prior``: how many edges' worth
    the guessed ``R`` counts.  Returns the line, the half-width and the rows
    with an edge on the fitted lines; None if too few edges agree.
    """
    H, W = g.shape
    m = 2 + int(round(0.1 * R))
    for it in range(2):
        vs, xs, right = [], [], []
        for v in rows:
            xc = cx0 + cx1 * v
            for sgn in (-1, 1):
                xe = xc + sgn * R
                i0, i1 = int(math.floor(xe - m)), int(math.ceil(xe + m))
                lo, hi = i0 - 4, i1 + 4
                if lo < 0 or hi >= W or v < 0 or v >= H:
                    continue
                row = g[v, lo:hi + 1]
                # The steepest step the right way round (light outside, dark
                # inside) in the window, then the integral method over a few
                # pixels about it, between the levels just beyond: another
                # edge of the background a few pixels out stays out of it.
                d = np.diff(row[i0 - lo:i1 - lo + 2]) * sgn
                k = int(np.argmax(d))
                if d[k] <= 0:
                    continue
                c = i0 - lo + k  # the step is between samples c and c + 1
                a0, a1 = c - 2, c + 3
                before, after = float(row[a0 - 1]), float(row[a1 + 1])
                if (sgn < 0) != (before > after):
                    continue
                e = _edge(row, a0, a1, before, after)
                if e is None:
                    continue
                vs.append(v)
                xs.append(lo + e)
                right.append(sgn > 0)
        if len(vs) < 6 or all(right) or not any(right):
            return None
        rt = np.array(right)
        va = np.array(vs, float)
        y = np.array(xs)
        # Unknowns: centre line (cx0, cx1) and half-width R.
        side = np.where(rt, 1.0, -1.0)
        A = np.column_stack([np.ones_like(va), va, side])
        if it == 0:
            # Start where most edges put the centre line (each edge, moved by
            # the half-width, is a vote).
            cx0 = float(np.median(y - side * R - cx1 * va))
        res = y - A @ np.array([cx0, cx1, R])
        wts = np.ones(len(y))
        R0 = R
        for _ in range(6):
            scale = max(0.1, 1.4826 * float(np.median(np.abs(res[wts > 0]))))
            u = res / (4.685 * scale)
            wts = np.where(np.abs(u) < 1, (1 - u * u) ** 2, 0.0)
            if np.count_nonzero((wts > 0) & rt) < 2 or np.count_nonzero((wts > 0) & ~rt) < 2:
                return None
            sw = np.sqrt(wts)
            Aw, yw = A * sw[:, None], y * sw
            if prior > 0:
                # The half-width the band pitch gives, worth ``prior`` edges.
                k = math.sqrt(prior)
                Aw = np.vstack([Aw, [0.0, 0.0, k]])
                yw = np.append(yw, k * R0)
            sol, *_ = np.linalg.lstsq(Aw, yw, rcond=None)
            res = y - A @ sol
        cx0, cx1, R = float(sol[0]), float(sol[1]), float(sol[2])
        if R <= 1.0:
            return None
    return cx0, cx1, R, set(va[wts > 0].astype(int).tolist())


def _along(jj: np.ndarray, sq: np.ndarray, ww: np.ndarray, y: np.ndarray, n: int
           ) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """Robust fit of the band boundaries' edges ``y`` (boundary index ``jj``,
    ``sq = sqrt(1 - (w / R)^2)`` and ``ww = w / R`` at the profile's offset
    ``w``): ``v = al j + be + b_j sq + t_j ww``, see :func:`refine`.

    Starts from the line through the boundaries' median edges that most of
    them agree with; a boundary with little support (its edges are mostly
    someone else's: a poster's edge beside the cylinder's end) is dropped
    and the rest fitted again.  Returns (solution, inliers, residuals).
    """
    use = np.ones(len(y), bool)
    jn = (jj - 0.5 * n) / n
    for _ in range(3):
        js = sorted(set(jj[use].tolist()))
        if len(js) < 2:
            return None
        if len(js) >= 3:
            A = np.column_stack([jj, np.ones_like(jj), sq, sq * jn, ww, ww * jn])
        else:
            A = np.column_stack([jj, np.ones_like(jj), sq, ww])
        # Start: of the lines through two boundaries' median edges, the one
        # the most boundaries are close to.
        med = {j: float(np.median(y[use & (jj == j)])) for j in js}
        best = None
        for a in range(len(js)):
            for b in range(a + 1, len(js)):
                al = (med[js[b]] - med[js[a]]) / (js[b] - js[a])
                be = med[js[a]] - al * js[a]
                cost = float(np.median([abs(med[j] - al * j - be) for j in js]))
                if best is None or cost < best[0]:
                    best = (cost, al, be)
        res = y - (best[1] * jj + best[2])
        wts = use.astype(float)
        for _ in range(8):
            act = wts > 0
            scale = max(0.05, 1.4826 * float(np.median(np.abs(res[act] - np.median(res[act])))))
            u = (res - np.median(res[act])) / (4.685 * scale)
            wts = np.where(use & (np.abs(u) < 1), (1 - u * u) ** 2, 0.0)
            if np.count_nonzero(wts) < 6:
                return None
            sw = np.sqrt(wts)
            sol, *_ = np.linalg.lstsq(A * sw[:, None], y * sw, rcond=None)
            res = y - A @ sol
        keep = wts > 0
        weak = [j for j in js
                if np.count_nonzero(keep & (jj == j)) < max(3, 0.4 * np.count_nonzero(use & (jj == j)))]
        if not weak:
            return sol, keep, res
        use &= ~np.isin(jj, weak)
    return None


def _start_line(runs: list[Run], R: float, unit: float) -> tuple[float, float]:
    """Starting centre line ``x = cx0 + cx1 v``: each side of each dark run
    seen, moved in by the half-width ``R``, votes for a centre; a side
    touching clutter votes wide of the others."""
    votes = np.array([r.left - 0.5 + R for r in runs] + [r.right + 0.5 - R for r in runs])
    vv = np.array([0.5 * (r.top + r.bot) for r in runs] * 2)
    support = [np.count_nonzero(np.abs(votes - x) <= 1.5) for x in votes]
    near = np.abs(votes - votes[int(np.argmax(support))]) <= 1.5
    if np.ptp(vv[near]) > 2 * unit and np.count_nonzero(near) >= 3:
        cx1, cx0 = np.polyfit(vv[near], votes[near], 1)
        return float(cx0), float(cx1)
    return float(np.median(votes[near])), 0.0


def _boundary_edges(g: np.ndarray, bounds: list[tuple[int, float, bool]], cx0: float, cx1: float, R: float,
                    unit: float, n: int) -> tuple[list[float], ...]:
    """Sub-pixel edges of the band boundaries ``(index j, coarse v, dark
    above?)`` on vertical profiles across the cylinder, at offsets ``w`` from
    its centre line: lists of v, sqrt(1 - (w / R)^2), w / R, j and the
    step's contrast."""
    H, W = g.shape
    hw = int(np.clip(math.floor(0.45 * unit), 1, 4))
    offs = np.linspace(-1.0, 1.0, 9) * max(0.5 * R, min(0.85 * R, R - 2.0))
    rows_v, rows_sq, rows_w, rows_j, rows_c = [], [], [], [], []
    for j, v0, dark_above in bounds:
        for w in offs:
            # Vertical profile along the centre line shifted by w.
            vv = np.arange(int(math.floor(v0 - hw - 3 * unit)), int(math.ceil(v0 + hw + 3 * unit)) + 1)
            if vv[0] < 0 or vv[-1] >= H:
                continue
            xx = cx0 + cx1 * vv + w
            if xx.min() < 0 or xx.max() > W - 1:
                continue
            prof = cv2.remap(g, xx.astype(np.float32)[None, :], vv.astype(np.float32)[None, :],
                             cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)[0]
            c = int(round(v0 + 0.5)) - vv[0]  # first sample below the boundary
            i0, i1 = c - hw - 1, c + hw
            # Levels from the middle of the band (or background) on each side: a band can be
            # as short as ~4 px, so the windows must not reach the next boundary.
            lq = max(0, int(round(0.15 * unit)))
            ca = int(round(v0 - 0.5 * unit - vv[0] + 0.5))
            cb = int(round(v0 + 0.5 * unit - vv[0] + 0.5))
            above = prof[max(0, ca - lq - 1):max(0, ca + lq)]
            below = prof[cb - lq:cb + lq + 1]
            if above.size == 0 or below.size == 0:
                continue
            a, b = statistics.median(above.tolist()), statistics.median(below.tolist())
            if j in (0, n):
                # An end of the cylinder, against the background: the
                # steepest step the right way round, integrated over a few
                # pixels about it, with the background level just beyond (an
                # edge of the background a few pixels off stays out of it).
                d = np.diff(prof[i0:i1 + 2]) * (1.0 if dark_above else -1.0)
                k = int(np.argmax(d))
                cs = i0 + k  # the step is between samples cs and cs + 1
                lo_, hi_ = cs - 2, cs + 3
                if d[k] <= 0 or lo_ < 1 or hi_ + 1 >= len(prof):
                    continue
                if j == 0:
                    a = float(prof[lo_ - 1])
                else:
                    b = float(prof[hi_ + 1])
                i0, i1 = lo_, hi_
            if dark_above != (a < b):
                continue
            e = _edge(prof, i0, i1, a, b)
            if e is None:
                continue
            rows_v.append(vv[0] + e)
            rows_sq.append(math.sqrt(max(0.0, 1 - (w / R) ** 2)))
            rows_w.append(w / R)
            rows_j.append(j)
            rows_c.append(abs(a - b))
    return rows_v, rows_sq, rows_w, rows_j, rows_c


def reads_code(gray: np.ndarray, part: list[Run], code: np.ndarray) -> bool:
    """Whether the middles of the bands where ``part`` (one run per dark run of ``code``) puts them read
    as the code at all: every dark band darker than every light one (the median grey level of each
    band's middle 40 % of rows and 60 % of the narrowest run's columns).  A quick test before
    :func:`refine`, which ends with the same test, stricter, at the refined band centres: most wrong
    candidates in clutter fail it here for a few hundredths of a refinement's time."""
    first, last, druns = code_runs(code)  # type: ignore[misc]
    unit = (part[-1].bot + 1 - part[0].top) / (last - first)
    o = part[0].top - first * unit
    seen = [r for r in part if not r.synthetic]
    xc = statistics.median(r.xc for r in seen)
    hw = 0.3 * min(r.width for r in seen)
    H, W = gray.shape
    c0, c1 = int(round(xc - hw)), int(round(xc + hw))
    if c0 < 0 or c1 >= W:
        return False
    levels = []
    for k in range(len(code)):
        v = o + (k + 0.5) * unit
        r0, r1 = int(round(v - 0.2 * unit)), int(round(v + 0.2 * unit))
        if r0 < 0 or r1 >= H:
            return False
        levels.append(float(np.median(gray[r0:r1 + 1, c0:c1 + 1])))
    lv = np.array(levels)
    dk, lt = lv[code == 1], lv[code == 0]
    return not (dk.size and lt.size) or float(lt.min()) > float(dk.max())


def refine(gray: np.ndarray, part: list[Run], code: np.ndarray, aspect: float) -> dict[str, Any] | None:
    """Sub-pixel band centres of a cylinder whose dark runs (top to bottom,
    one per dark run of ``code``) are ``part``; ``aspect`` is its diameter
    over a band's height.  None if the image does not bear the code out.

    Two rounds of: the centre line from the silhouette's edges
    (:func:`_across`), then the band boundaries along it (:func:`_along`);
    the second round starts from the first's band pitch and boundaries
    (the runs' ends may be off where clutter touches a band's end).
    """
    first, last, druns = code_runs(code)  # type: ignore[misc]
    n = len(code)
    H, W = gray.shape
    unit = (part[-1].bot + 1 - part[0].top) / (last - first)
    o = part[0].top - first * unit  # v of the code's top
    g = EDGE_LUT[gray]
    seen = [r for r in part if not r.synthetic]
    # Boundaries (index j, coarse v, dark above?) of each dark run.
    bounds = []
    for (s, e), run in zip(druns, part):
        bounds.append((s, run.top - 0.5, False))  # light/background above, dark below
        bounds.append((e, run.bot + 0.5, True))
    for rnd in range(2):
        R = 0.5 * aspect * unit
        cx0, cx1 = _start_line(seen, R, unit)
        # Across: the silhouette's edges on the dark bands' rows (away from their ends).
        rows = []
        for k in np.nonzero(code)[0]:
            a, b = o + k * unit, o + (k + 1) * unit
            rows.extend(range(int(math.ceil(a + 0.25 * unit)), int(math.floor(b - 0.25 * unit)) + 1))
        # The second round knows the half-width from the band pitch.
        got = _across(g, rows, cx0, cx1, R, prior=10.0 if rnd else 0.0)
        edge_rows: set[int] = set()
        if got is not None:
            cx0, cx1, R, edge_rows = got
        rows_v, rows_sq, rows_w, rows_j, rows_c = _boundary_edges(g, bounds, cx0, cx1, R, unit, n)
        if len(rows_v) < 2 * len(bounds):
            return None
        # A boundary with the background (the code's ends) is only as good as
        # the background: where that is dark too, the step found is some other
        # edge (a dark poster's), so it must show about the contrast of the
        # cylinder's own dark/light boundaries.
        jj = np.array(rows_j, float)
        con = np.array(rows_c)
        use = np.ones(len(jj), bool)
        inner = (jj > 0) & (jj < n)
        if inner.any():
            use = inner | (con >= 0.5 * float(np.median(con[inner])))
        # Every boundary is a circle about the axis, seen as the front arc of an
        # ellipse: v = v0_j + b_j sqrt(1 - (w / R)^2) + t_j w, with v0_j (the
        # circle's centre), b_j (how much of the circle's top or underside shows)
        # and t_j (the ellipse's tilt, off the image centre) all linear in the
        # boundary index j -- the axis is straight and, across the cylinder's
        # length, so is the view of it.  All edges are fitted at once, robustly:
        # over the offsets used, sqrt(1 - (w / R)^2) varies too little for one
        # boundary alone to tell its v0 from its b.
        fit = _along(jj[use], np.array(rows_sq)[use], np.array(rows_w)[use], np.array(rows_v)[use], n)
        if fit is None:
            return None
        sol, keep, res = fit
        al, be = float(sol[0]), float(sol[1])
        # The cylinder's own dark/light boundaries (not its ends, which may
        # be against dark background) can only be hidden by something in
        # front of it: each must be there.
        found_j = set(jj[use][keep].tolist())
        if any(0 < j < n and j not in found_j for j, _, _ in bounds):
            return None
        # The band pitch must agree with the silhouette's width and the
        # cylinder's proportions (perspective scales both alike).
        if not 0.85 < al * aspect / (2.0 * R) < 1.2:
            return None
        # Second round: boundaries where the fit puts them.
        unit, o = al, be
        bounds = [(j, be + al * j, above) for j, _, above in bounds]
    # A dark run placed from the code (never seen as a run: it touches dark
    # clutter) must show the silhouette's edge, on one side at least, on a
    # good part of its rows: a false chain (a dark poster over a dark
    # skirting board) has no such edges where the code wants a dark band.
    for (s0, e0), run in zip(druns, part):
        band_rows = [v for v in rows if o + s0 * unit <= v <= o + e0 * unit]
        if run.synthetic and sum(v in edge_rows for v in band_rows) < max(1.0, 0.3 * len(band_rows)):
            return None
    ga = 0.0

    def v_at(j: float) -> float:
        return float((al * j + be) / (ga * j + 1.0))

    band_uv = []
    for k in range(n):
        v = v_at(k + 0.5)
        band_uv.append((cx0 + cx1 * v, v))
    # Verify the code: every band's middle must read as its bit (dark bands all darker than light ones).
    unit_v = abs(al)
    hu, hr = max(0.5, 0.25 * unit_v), max(1.0, 0.4 * R)
    levels = []
    for u, v in band_uv:
        r0, r1 = int(round(v - hu)), int(round(v + hu))
        c0, c1 = int(round(u - hr)), int(round(u + hr))
        if r0 < 0 or c0 < 0 or r1 >= H or c1 >= W:
            return None
        levels.append(float(np.median(gray[r0:r1 + 1, c0:c1 + 1])))
    levels = np.array(levels)
    dk, lt = levels[code == 1], levels[code == 0]
    if lt.size and dk.size and not lt.min() - dk.max() > max(20.0, 0.3 * (np.median(lt) - np.median(dk))):
        return None
    vc = v_at(0.5 * n)
    return {"bands": band_uv, "centre": (cx0 + cx1 * vc, vc), "unit_px": al, "radius_px": R,
            "edge_rms_px": float(np.sqrt(np.mean(res[keep] ** 2)))}


def axis_u(u: float, R: float, camera: Camera) -> float:
    """Column of an upright axis whose silhouette is centred at column ``u``
    with half-width ``R`` (px): the mean of the edges' angles, not of their
    columns."""
    fx, cx = float(camera.K[0, 0]), float(camera.K[0, 2])
    m = u - cx
    return cx + fx * math.tan(0.5 * (math.atan((m + R) / fx) + math.atan((m - R) / fx)))


