"""Sub-pixel tag corners: each side of a detected tag's black square is
re-measured along its length (integral edge positions on profiles across
it, in linearised grey levels), fitted robustly as a line, and the corners
are the lines' intersections (in undistorted coordinates with a camera).
Also the tag centre from its corners (the diagonals' intersection)."""

from __future__ import annotations

from typing import Any

import cv2
import numpy as np

from ..core.camera import Camera
from ..errors import InputError

__all__ = ["diagonal_centre", "refine_edges"]


def _intersect(l1: np.ndarray, l2: np.ndarray) -> np.ndarray | None:
    """Intersection of two homogeneous 2-D lines, or None if (nearly) parallel."""
    p = np.cross(l1, l2)
    scale = np.linalg.norm(l1[:2]) * np.linalg.norm(l2[:2])
    if abs(p[2]) <= 1e-12 * scale:
        return None
    return p[:2] / p[2]


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
    h = np.c_[pts, np.ones(4)]
    p = _intersect(np.cross(h[0], h[2]), np.cross(h[1], h[3]))
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
# the one-cell black border and the (at least one-cell) white quiet zone.
_PROFILE_CELL_FRACTION = 0.45
_PROFILE_MIN_PX = 1.5
_PROFILE_MAX_PX = 6.0
# A refined corner further than this (pixels, or this fraction of a cell) from
# OpenCV's is not trusted: the edge fit latched onto something else.  Not
# tighter: OpenCV's own corners were measured up to 1.6 px off on 30 px tags.
_MAX_SHIFT_PX = 2.0
_MAX_SHIFT_CELLS = 0.5


def _edge_points(gray: np.ndarray, a: np.ndarray, b: np.ndarray, inside: np.ndarray,
                 r: float) -> tuple[np.ndarray, np.ndarray]:
    """Sub-pixel points on the tag's outer edge near segment a-b.

    Samples intensity profiles along the normal of a-b at about one-pixel
    spacing, away from the corners where the neighbouring side blurs into
    the profile.  For each profile, with ``I0``/``I1`` the inner/outer
    plateau levels, the edge sits at ``s* = s_max - integral(I - I0) ds / (I1 - I0)``:
    exact for a step blurred by any symmetric kernel, and it uses every
    sample rather than one threshold crossing.  Returns the points (n, 2) and
    their contrast ``|I1 - I0|`` (used as weights).
    """
    d = b - a
    length = float(np.hypot(*d))
    d = d / length
    n = np.array([d[1], -d[0]])
    if n @ (0.5 * (a + b) - inside) < 0:  # make n point out of the tag
        n = -n
    margin = r + 1.0
    if length - 2 * margin < 4.0:
        return np.empty((0, 2)), np.empty(0)
    t = np.linspace(margin, length - margin, max(4, int(length - 2 * margin) + 1))
    s = np.arange(-r, r + 0.5 * _PROFILE_STEP, _PROFILE_STEP)
    base = a + t[:, None] * d
    grid = base[:, None, :] + s[None, :, None] * n
    h, w = gray.shape
    ok = np.all((grid[..., 0] >= 0) & (grid[..., 0] <= w - 1) & (grid[..., 1] >= 0) & (grid[..., 1] <= h - 1),
                axis=1)
    if not np.any(ok):
        return np.empty((0, 2)), np.empty(0)
    grid = grid[ok]
    base = base[ok]
    prof = cv2.remap(gray, grid[..., 0].astype(np.float32), grid[..., 1].astype(np.float32),
                     interpolation=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE).astype(float)
    k = max(2, len(s) // 6)  # plateau: the outer sixth of each end
    i0 = prof[:, :k].mean(axis=1)
    i1 = prof[:, -k:].mean(axis=1)
    contrast = i1 - i0
    rel = prof - i0[:, None]
    area = _PROFILE_STEP * (rel.sum(axis=1) - 0.5 * (rel[:, 0] + rel[:, -1]))  # trapezoid rule
    with np.errstate(divide="ignore", invalid="ignore"):
        off = s[-1] - area / contrast
    # The formula holds for either polarity (inverted tags are light inside);
    # profiles against the side's majority polarity did not cross this edge.
    polarity = np.sign(np.median(contrast))
    good = (np.sign(contrast) == polarity) & (polarity != 0) & np.isfinite(off) & (np.abs(off) < r)
    return base[good] + off[good, None] * n, np.abs(contrast[good])


def _fit_line(pts: np.ndarray, wts: np.ndarray) -> np.ndarray | None:
    """Weighted total-least-squares line ``(a, b, c)``, ``a x + b y + c = 0``, |(a, b)| = 1."""
    if len(pts) < 3 or not np.sum(wts) > 0:
        return None
    mu = (wts[:, None] * pts).sum(axis=0) / wts.sum()
    X = (pts - mu) * np.sqrt(wts)[:, None]
    _, _, vt = np.linalg.svd(X, full_matrices=False)
    nrm = vt[-1]
    return np.array([nrm[0], nrm[1], -nrm @ mu])


def _robust_line(pts: np.ndarray, wts: np.ndarray, px: float) -> tuple[np.ndarray, float] | None:
    """:func:`_fit_line` after discarding low-contrast and outlying edge points.

    Low contrast means the profile did not cross the tag's edge (occlusion,
    a specular patch, the image border); outliers are dropped at 3.5 robust
    sigmas (floor 0.05 px; ``px`` is one pixel in the units of ``pts``) so
    one bad stretch of edge cannot tilt the line.  Returns the line and the
    RMS distance (pixels) of the kept points from it.
    """
    if len(pts) < 3:
        return None
    keep = wts >= 0.5 * np.median(wts)
    pts, wts = pts[keep], wts[keep]
    line = _fit_line(pts, wts)
    for _ in range(2):
        if line is None:
            return None
        res = np.abs(pts @ line[:2] + line[2])
        sigma = max(1.4826 * float(np.median(res)), 0.05 * px)
        keep = res <= 3.5 * sigma
        if keep.sum() < 3:
            return None
        line = _fit_line(pts[keep], wts[keep])
    if line is None:
        return None
    rms = float(np.sqrt(np.mean((pts[keep] @ line[:2] + line[2]) ** 2))) / px
    return line, rms


def refine_edges(gray: np.ndarray, corners: np.ndarray, cells: int,
                  camera: Camera | None) -> tuple[np.ndarray, float] | None:
    """Corners from straight-line fits to the four sides of the black square.

    ``corners`` (4, 2) are OpenCV's (sub-pixel) corners, the starting point.
    Two passes: the second re-centres the profiles on the first pass's sides,
    so its plateaus are symmetric about the edge.  With a distorting
    ``camera`` the edge points are undistorted before the line fit (sides are
    straight only there).  Returns the corners and the RMS distance (px) of
    the edge points from their sides -- a quality figure: noise, blur and
    curvature the model lacks all raise it.  None when a side cannot be
    fitted or a corner moves implausibly far; the caller keeps OpenCV's
    corners then.
    """
    c0 = np.asarray(corners, dtype=float)
    side = float(np.mean(np.linalg.norm(c0 - np.roll(c0, -1, axis=0), axis=1)))
    cell = side / cells
    r = float(np.clip(_PROFILE_CELL_FRACTION * cell, _PROFILE_MIN_PX, _PROFILE_MAX_PX))
    undistort = _distorted(camera)
    # One pixel in the line-fit coordinates (normalized ones when undistorting).
    px = 1.0 / float(camera.K[0, 0]) if undistort else 1.0  # type: ignore[union-attr]
    c = c0.copy()
    for _ in range(2):
        centre = c.mean(axis=0)
        lines = []
        rms = []
        for k in range(4):
            pts, wts = _edge_points(gray, c[k], c[(k + 1) % 4], centre, r)
            if undistort and len(pts):
                try:
                    pts = _normalized(camera, pts)
                except InputError:  # outside the invertible region of the lens model
                    return None
            fit = _robust_line(pts, wts, px)
            if fit is None:
                return None
            lines.append(fit[0])
            rms.append(fit[1])
        new = []
        for k in range(4):
            p = _intersect(lines[(k - 1) % 4], lines[k])
            if p is None:
                return None
            new.append(p)
        c = np.array(new)
        if undistort:
            c = _to_pixels(camera, c)  # type: ignore[arg-type]
        if not np.all(np.isfinite(c)):
            return None
    if np.max(np.linalg.norm(c - c0, axis=1)) > max(_MAX_SHIFT_PX, _MAX_SHIFT_CELLS * cell):
        return None
    return c, float(np.sqrt(np.mean(np.square(rms))))


# ---------------------------------------------------------------------------
# detection
# ---------------------------------------------------------------------------
