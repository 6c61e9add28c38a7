"""Sub-pixel tag corners: each side of a detected tag's black square is
re-measured along its length (integral edge positions on profiles across
it, in linearised grey levels), fitted robustly as a line, and the corners
are the lines' intersections (in undistorted coordinates with a camera).
Also the tag centre from its corners (the diagonals' intersection)."""

from __future__ import annotations

import functools
import math
from typing import Any

import numba
import numpy as np

from ..core.camera import Camera
from ..errors import InputError

__all__ = ["diagonal_centre", "linearize", "refine_edges"]


@functools.lru_cache(maxsize=8)
def _lut(gamma: float | str) -> np.ndarray:
    x = np.arange(256) / 255.0
    if gamma == "srgb":  # IEC 61966-2-1
        y = np.where(x <= 0.04045, x / 12.92, ((x + 0.055) / 1.055) ** 2.4)
    elif gamma == "linear":
        y = x
    else:
        y = x ** float(gamma)
    return (255.0 * y).astype(np.float32)


def linearize(gray: np.ndarray, gamma: float | str = "srgb") -> np.ndarray:
    """uint8 grey levels -> float32 levels proportional to light (0..255).

    ``gamma``: ``"srgb"`` (the sRGB transfer curve), ``"linear"`` (already
    proportional: only converted to float) or a power-law exponent.
    """
    return _lut(gamma)[gray]


def _cross(a: Any, b: Any) -> tuple[float, float, float]:
    # Scalar arithmetic: np.cross costs ~50 us per call, more than the whole edge fit.
    a0, a1, a2 = float(a[0]), float(a[1]), float(a[2])
    b0, b1, b2 = float(b[0]), float(b[1]), float(b[2])
    return a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0


def _intersect(l1: Any, l2: Any) -> np.ndarray | None:
    """Intersection of two homogeneous 2-D lines, or None if (nearly) parallel."""
    x, y, w = _cross(l1, l2)
    scale = math.hypot(float(l1[0]), float(l1[1])) * math.hypot(float(l2[0]), float(l2[1]))
    if abs(w) <= 1e-12 * scale:
        return None
    return np.array([x / w, y / w])


def _normalized(camera: Camera | None, uv: np.ndarray) -> np.ndarray:
    """Undistorted normalized image coordinates (n, 2) of pixels ``uv`` (InputError where not invertible)."""
    if camera is None:
        raise InputError("no camera to undistort with")
    b = camera.pixels_to_bearings(uv)
    return b[:, :2] / b[:, 2:3]


def _to_pixels(camera: Camera, xy: np.ndarray) -> np.ndarray:
    return camera.project(np.c_[xy, np.ones(len(xy))])


def _distorted(camera: Camera | None) -> bool:
    return camera is not None and bool(np.any(camera.dist != 0.0))


def diagonal_centre(corners: Any, camera: Camera | None = None) -> np.ndarray:
    """Image of the tag centre: the intersection of the diagonals 0-2 and 1-3.

    Under a pinhole projection the diagonals of the imaged square meet at the
    image of its centre (projective invariance of incidence), which the mean
    of the corners is not.  With a distorting ``camera`` the diagonals are
    intersected in undistorted coordinates and the point distorted back.
    """
    c = np.asarray(corners, dtype=float).reshape(4, 2)
    undistort = _distorted(camera)
    pts = c
    if undistort:
        try:
            pts = _normalized(camera, c)
        except InputError:  # a corner where the lens model is not invertible: stay in pixels
            undistort = False
    h = [(float(x), float(y), 1.0) for x, y in pts]
    p = _intersect(_cross(h[0], h[2]), _cross(h[1], h[3]))
    if p is None:  # degenerate quadrilateral: no better answer than the mean
        p = pts.mean(axis=0)
    if undistort:
        p = _to_pixels(camera, p[None])[0]  # type: ignore[arg-type]
    return np.asarray(p, dtype=float)


# ---------------------------------------------------------------------------
# edge refinement
# ---------------------------------------------------------------------------

# Profile sample spacing across an edge, in pixels.
_PROFILE_STEP = 0.25
# Profile half-length: a fraction of a tag cell, so the profile stays inside
# the one-cell black border and the (at least one-cell) white quiet zone --
# at least a pixel: a tag seen 55-62 degrees off its normal at 30 px has cells
# under 2 px across its foreshortened sides, and a 1.5 px floor reached past
# them (its worst corner's p90 0.36-0.38 px on sharp renders, 0.11-0.19 px
# with the 1 px floor; blurred ones and face-on tags unchanged).
_PROFILE_CELL_FRACTION = 0.6
_PROFILE_MIN_PX = 1.0
_PROFILE_MAX_PX = 6.0
# A refined corner further than this (pixels, or this fraction of a cell) from
# OpenCV's is not trusted: the edge fit latched onto something else.  Not
# tighter: OpenCV's own corners were measured up to 1.6 px off on 30 px tags.
_MAX_SHIFT_PX = 2.0
# Profiles per side at most (one per pixel up to this): a long side's line is
# pinned down well by fewer, and the fit's cost grows with their number.
_MAX_PROFILES = 40
# Passes of the edge fit, each re-centring the profiles on the previous sides
# (a short profile is biased towards its own centre, so the fit is iterated to
# its fixed point: measured on 27 px tags with 0.8 px blur, 2 passes left a
# 2.5 cm range bias at 3.5 m, 4 passes 0.4 cm, more passes no change), and the
# corner shift below which it has converged.
_PASSES = 4
_CONVERGED_PX = 0.002
_MAX_SHIFT_CELLS = 0.5


@numba.njit(cache=True, fastmath=False)
def _bilinear(img: np.ndarray, x: float, y: float) -> float:
    h, w = img.shape
    x0 = min(int(math.floor(x)), w - 2)
    y0 = min(int(math.floor(y)), h - 2)
    fx, fy = x - x0, y - y0
    return ((1.0 - fy) * ((1.0 - fx) * img[y0, x0] + fx * img[y0, x0 + 1])
            + fy * ((1.0 - fx) * img[y0 + 1, x0] + fx * img[y0 + 1, x0 + 1]))


@numba.njit(cache=True, fastmath=False)
def _side_points(gray: np.ndarray, c: np.ndarray, rs: np.ndarray, ox: float, oy: float,
                 pts: np.ndarray, wts: np.ndarray, counts: np.ndarray) -> None:
    """Sub-pixel points on the tag's outer edge along each side k (c[k] -> c[k+1]).

    Samples intensity profiles along the side's normal at about one-pixel
    spacing, away from the corners where the neighbouring side blurs into
    the profile.  For each profile, with ``I0``/``I1`` the inner/outer
    plateau levels, the edge sits at ``s* = s_max - integral(I - I0) ds / (I1 - I0)``:
    exact for a step blurred by any symmetric kernel, and it uses every
    sample rather than one threshold crossing.  Points go to ``pts[k, :counts[k]]``
    (image pixels), their contrast ``|I1 - I0|`` to ``wts`` (used as weights);
    ``rs[k]`` is side k's profile half-length.
    """
    h, w = gray.shape
    cx = 0.25 * (c[0, 0] + c[1, 0] + c[2, 0] + c[3, 0])
    cy = 0.25 * (c[0, 1] + c[1, 1] + c[2, 1] + c[3, 1])
    prof = np.empty(int(2.0 * rs.max() / _PROFILE_STEP) + 3)
    maxn = pts.shape[1]
    off = np.empty(maxn)
    con = np.empty(maxn)
    bx = np.empty(maxn)
    by = np.empty(maxn)
    for k in range(4):
        counts[k] = 0
        r = rs[k]
        ns = int(math.floor(2.0 * r / _PROFILE_STEP + 0.5)) + 1
        kk = max(2, ns // 6)  # plateau: the outer sixth of each end
        ax, ay = c[k, 0], c[k, 1]
        dx, dy = c[(k + 1) % 4, 0] - ax, c[(k + 1) % 4, 1] - ay
        length = math.hypot(dx, dy)
        margin = r + 1.0
        if length - 2.0 * margin < 4.0:
            continue
        dx /= length
        dy /= length
        nx, ny = dy, -dx
        if nx * (ax + 0.5 * length * dx - cx) + ny * (ay + 0.5 * length * dy - cy) < 0:  # n points out
            nx, ny = -nx, -ny
        nt = min(maxn, _MAX_PROFILES, max(4, int(length - 2.0 * margin) + 1))
        m = 0
        for i in range(nt):
            t = margin + (length - 2.0 * margin) * i / (nt - 1)
            px, py = ax + t * dx, ay + t * dy
            x_a, y_a = px - r * nx - ox, py - r * ny - oy
            x_b, y_b = px + r * nx - ox, py + r * ny - oy
            if min(x_a, x_b) < 0 or min(y_a, y_b) < 0 or max(x_a, x_b) > w - 1 or max(y_a, y_b) > h - 1:
                continue
            for j in range(ns):
                sj = -r + j * _PROFILE_STEP
                prof[j] = _bilinear(gray, px + sj * nx - ox, py + sj * ny - oy)
            i0 = 0.0
            i1 = 0.0
            for j in range(kk):
                i0 += prof[j]
                i1 += prof[ns - 1 - j]
            i0 /= kk
            i1 /= kk
            area = 0.0
            for j in range(ns):
                area += prof[j] - i0
            area = _PROFILE_STEP * (area - 0.5 * ((prof[0] - i0) + (prof[ns - 1] - i0)))
            contrast = i1 - i0
            if contrast == 0.0:
                continue
            off[m] = (-r + (ns - 1) * _PROFILE_STEP) - area / contrast
            con[m] = contrast
            bx[m] = px
            by[m] = py
            m += 1
        if m == 0:
            continue
        # The formula holds for either polarity (reversed-border tags are light
        # inside); profiles against the side's majority polarity did not cross this edge.
        pol = np.sign(np.median(con[:m]))
        n = 0
        for i in range(m):
            if pol != 0 and np.sign(con[i]) == pol and abs(off[i]) < r:
                pts[k, n, 0] = bx[i] + off[i] * nx
                pts[k, n, 1] = by[i] + off[i] * ny
                wts[k, n] = abs(con[i])
                n += 1
        counts[k] = n


@numba.njit(cache=True, fastmath=False)
def _fit_line(pts: np.ndarray, wts: np.ndarray, keep: np.ndarray, line: np.ndarray) -> bool:
    """Weighted total-least-squares line ``a x + b y + c = 0`` (|(a, b)| = 1) through the kept points."""
    sw = 0.0
    mx = 0.0
    my = 0.0
    for i in range(len(wts)):
        if keep[i]:
            sw += wts[i]
            mx += wts[i] * pts[i, 0]
            my += wts[i] * pts[i, 1]
    if not sw > 0:
        return False
    mx /= sw
    my /= sw
    sxx = 0.0
    sxy = 0.0
    syy = 0.0
    for i in range(len(wts)):
        if keep[i]:
            ex, ey = pts[i, 0] - mx, pts[i, 1] - my
            sxx += wts[i] * ex * ex
            sxy += wts[i] * ex * ey
            syy += wts[i] * ey * ey
    # Normal = eigenvector of the scatter matrix's smaller eigenvalue.
    lam = 0.5 * (sxx + syy) - math.sqrt(0.25 * (sxx - syy) ** 2 + sxy * sxy)
    ax, ay = sxy, lam - sxx
    bx, by = lam - syy, sxy
    if ax * ax + ay * ay < bx * bx + by * by:
        ax, ay = bx, by
    nrm = math.hypot(ax, ay)
    if not nrm > 0:
        return False
    line[0] = ax / nrm
    line[1] = ay / nrm
    line[2] = -(line[0] * mx + line[1] * my)
    return True


@numba.njit(cache=True, fastmath=False)
def _robust_line(pts: np.ndarray, wts: np.ndarray, px: float, line: np.ndarray) -> float:
    """:func:`_fit_line` after discarding low-contrast and outlying edge points.

    Low contrast means the profile did not cross the tag's edge (occlusion,
    a specular patch, the image border); outliers are dropped at 3.5 robust
    sigmas (floor 0.05 px; ``px`` is one pixel in the units of ``pts``) so
    one bad stretch of edge cannot tilt the line.  Returns the RMS distance
    (pixels) of the kept points from the line, -1 when no line fits.
    """
    n = len(wts)
    if n < 3:
        return -1.0
    keep = wts >= 0.5 * np.median(wts)
    if not _fit_line(pts, wts, keep, line):
        return -1.0
    res = np.empty(n)
    for _ in range(2):
        for i in range(n):
            res[i] = abs(pts[i, 0] * line[0] + pts[i, 1] * line[1] + line[2])
        sigma = max(1.4826 * np.median(res[keep]), 0.05 * px)
        keep = keep & (res <= 3.5 * sigma)
        if keep.sum() < 3 or not _fit_line(pts, wts, keep, line):
            return -1.0
    ss = 0.0
    for i in range(n):
        if keep[i]:
            ss += (pts[i, 0] * line[0] + pts[i, 1] * line[1] + line[2]) ** 2
    return math.sqrt(ss / keep.sum()) / px


@numba.njit(cache=True, fastmath=False)
def _refine_pinhole(gray: np.ndarray, c: np.ndarray, rs: np.ndarray, ox: float, oy: float, passes: int,
                    converged: float) -> float:
    """The whole edge fit without lens distortion, in place on ``c``: RMS (px), or -1 on failure."""
    maxn = int(max(math.hypot(c[1, 0] - c[0, 0], c[1, 1] - c[0, 1]),
                             math.hypot(c[2, 0] - c[1, 0], c[2, 1] - c[1, 1]),
                             math.hypot(c[3, 0] - c[2, 0], c[3, 1] - c[2, 1]),
                             math.hypot(c[0, 0] - c[3, 0], c[0, 1] - c[3, 1]))) + 8
    pts = np.empty((4, maxn, 2))
    wts = np.empty((4, maxn))
    counts = np.zeros(4, np.int64)
    lines = np.empty((4, 3))
    rms = np.empty(4)
    new = np.empty((4, 2))
    for _ in range(passes):
        _side_points(gray, c, rs, ox, oy, pts, wts, counts)
        for k in range(4):
            n = counts[k]
            rms[k] = _robust_line(pts[k, :n], wts[k, :n], 1.0, lines[k])
            if rms[k] < 0:
                return -1.0
        shift = 0.0
        for k in range(4):
            l1 = lines[(k + 3) % 4]
            l2 = lines[k]
            x = l1[1] * l2[2] - l1[2] * l2[1]
            y = l1[2] * l2[0] - l1[0] * l2[2]
            w = l1[0] * l2[1] - l1[1] * l2[0]
            if abs(w) <= 1e-12:
                return -1.0
            new[k, 0] = x / w
            new[k, 1] = y / w
            shift = max(shift, abs(new[k, 0] - c[k, 0]), abs(new[k, 1] - c[k, 1]))
        c[:, :] = new
        if not np.all(np.isfinite(c)):
            return -1.0
        if shift < converged:
            break
    ss = 0.0
    for k in range(4):
        ss += rms[k] * rms[k]
    return math.sqrt(ss / 4.0)


def refine_edges(gray: np.ndarray, corners: np.ndarray, cells: int, camera: Camera | None,
                 origin: tuple[int, int] = (0, 0)) -> tuple[np.ndarray, float] | None:
    """Corners from straight-line fits to the four sides of the black square.

    ``corners`` (4, 2) are OpenCV's (sub-pixel) corners, the starting point.
    Each pass re-centres the profiles on the previous pass's sides, so their
    plateaus end up symmetric about the edge (up to :data:`_PASSES`, until
    the corners move less than :data:`_CONVERGED_PX`).  With a distorting
    ``camera`` the edge points are undistorted before the line fit (sides are
    straight only there).  Returns the corners and the RMS distance (px) of
    the edge points from their sides -- a quality figure: noise, blur and
    curvature the model lacks all raise it.  ``gray`` may be a crop of the
    image whose top-left pixel is ``origin`` (corners stay in image pixels).
    None when a side cannot be
    fitted or a corner moves implausibly far; the caller keeps OpenCV's
    corners then.
    """
    c0 = np.asarray(corners, dtype=float)
    side = float(np.mean(np.linalg.norm(c0 - np.roll(c0, -1, axis=0), axis=1)))
    cell = side / cells
    # Profile half-length per side, from the cell size across that side (the
    # shorter adjacent side over the cells): under strong perspective a
    # mean-cell profile would reach past the border into the data cells.
    lens = np.linalg.norm(c0 - np.roll(c0, -1, axis=0), axis=1)
    across = np.minimum(np.roll(lens, 1), np.roll(lens, -1)) / cells
    rs = np.clip(_PROFILE_CELL_FRACTION * across, _PROFILE_MIN_PX, _PROFILE_MAX_PX)
    undistort = _distorted(camera)
    # One pixel in the line-fit coordinates (normalized ones when undistorting).
    px = 1.0 / float(camera.K[0, 0]) if undistort else 1.0  # type: ignore[union-attr]
    c = c0.copy()
    gray = np.ascontiguousarray(gray, dtype=np.float32)
    if not undistort:
        total = _refine_pinhole(gray, c, rs, float(origin[0]), float(origin[1]), _PASSES, _CONVERGED_PX)
        if total < 0 or np.max(np.linalg.norm(c - c0, axis=1)) > max(_MAX_SHIFT_PX, _MAX_SHIFT_CELLS * cell):
            return None
        return c, float(total)
    maxn = int(side) + 8
    pts = np.empty((4, maxn, 2))
    wts = np.empty((4, maxn))
    counts = np.zeros(4, np.int64)
    lines = np.empty((4, 3))
    rms = np.empty(4)
    for _ in range(_PASSES):
        _side_points(gray, c, rs, float(origin[0]), float(origin[1]), pts, wts, counts)
        for k in range(4):
            p = pts[k, :counts[k]]
            if undistort and len(p):
                try:
                    p = _normalized(camera, p)
                except InputError:  # outside the invertible region of the lens model
                    return None
            rms[k] = _robust_line(np.ascontiguousarray(p), wts[k, :counts[k]], px, lines[k])
            if rms[k] < 0:
                return None
        new = []
        for k in range(4):
            q = _intersect(lines[(k - 1) % 4], lines[k])
            if q is None:
                return None
            new.append(q)
        prev, c = c, np.array(new)
        if undistort:
            c = _to_pixels(camera, c)  # type: ignore[arg-type]
        if not np.all(np.isfinite(c)):
            return None
        if np.max(np.abs(c - prev)) < _CONVERGED_PX:
            break
    if np.max(np.linalg.norm(c - c0, axis=1)) > max(_MAX_SHIFT_PX, _MAX_SHIFT_CELLS * cell):
        return None
    return c, float(np.sqrt(np.mean(np.square(rms))))


# ---------------------------------------------------------------------------
# detection
# ---------------------------------------------------------------------------
