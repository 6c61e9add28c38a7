"""Coarse search: what to look for, hue masks, blobs and a RANSAC circle per blob.

The hue mask and contours are the frame-sized part of the work, so they run
on a downscaled image (see :func:`pick_downscale`); everything that needs
accuracy is done at full resolution by the later stages.
"""

from __future__ import annotations

import colorsys
import math
from dataclasses import dataclass

import cv2
import numba
import numpy as np

from ...core.rig import Marker
from ...errors import InputError
from .cues import evidence, vivid
from .light import correct
from .numeric import circle3, kasa_circle
from .params import DEFAULT_BALL_RADIUS_M, BallParams

__all__ = [
    "BallSearch",
    "Blob",
    "coarse_blobs",
    "fill_fraction",
    "find_blobs",
    "hue_masks",
    "pick_downscale",
    "ransac_circle",
    "same_circle",
    "value_floor",
]

# sRGB-encoded uint8 -> linear light (for nominal colours).
_SRGB_LUT = np.array(
    [c / 12.92 if c <= 0.04045 else ((c + 0.055) / 1.055) ** 2.4 for c in np.arange(256) / 255.0],
    dtype=np.float32,
)

# Fixed random triplets: detections are repeatable.
_TRIPLETS = np.random.default_rng(12345).random((48, 3))


@dataclass(frozen=True)
class BallSearch:
    """What the detector looks for for one marker (derived from its colour)."""

    name: str
    rgb: tuple[int, int, int]
    hue_deg: float
    saturation: float
    value: float
    radius_m: float = DEFAULT_BALL_RADIUS_M
    # The robot carrying the ball and the ball's position on it: balls of one
    # robot must be seen at mutually consistent places.
    robot: str | None = None
    position: np.ndarray | None = None

    @classmethod
    def from_marker(cls, name: str, marker: Marker, params: BallParams | None = None) -> BallSearch:
        """Validate the marker's colour; raise InputError for achromatic ones.

        The rig gives nominal sRGB colours; for linear images
        (``params.srgb=False``) hue and saturation are those of the
        linearised colour, since e.g. orange (255, 128, 0) has a hue of
        30 deg in sRGB but 13 deg in linear values.
        """
        p = params or BallParams()
        rgb = marker.color
        try:
            r, g, b = (int(c) for c in rgb)  # type: ignore[union-attr]
        except (TypeError, ValueError):
            raise InputError(f"marker {name!r}: color must be 3 integers [r, g, b] in 0..255, got {rgb!r}") from None
        if not all(0 <= c <= 255 for c in (r, g, b)):
            raise InputError(f"marker {name!r}: color must be 3 integers [r, g, b] in 0..255, got {rgb!r}")
        h, s, v = colorsys.rgb_to_hsv(r / 255.0, g / 255.0, b / 255.0)
        # Achromatic or not is judged on the nominal (sRGB) colour.
        if s < p.min_nominal_saturation or v < p.min_nominal_value:
            kind = "black" if v < p.min_nominal_value else ("white" if v > 0.85 else "grey")
            raise InputError(
                f"marker {name!r}: color [{r}, {g}, {b}] is {kind} (saturation {s:.2f}); the ball detector "
                f"matches hue and needs a saturated colour (saturation >= {p.min_nominal_saturation})"
            )
        radius = DEFAULT_BALL_RADIUS_M
        extra = getattr(marker, "extra", None) or {}
        if "radius" in extra:
            try:
                radius = float(extra["radius"])
            except (TypeError, ValueError):
                raise InputError(f"marker {name!r}: radius must be a number, got {extra['radius']!r}") from None
            if not (radius > 0 and math.isfinite(radius)):
                raise InputError(f"marker {name!r}: radius must be positive, got {extra['radius']!r}")
        if not p.srgb:
            h, s, v = colorsys.rgb_to_hsv(*(float(_SRGB_LUT[c]) for c in (r, g, b)))
        robot = getattr(marker, "robot", None)
        pos = getattr(marker, "position", None)
        pos = np.asarray(pos, float) if pos is not None and np.shape(pos) == (3,) else None
        return cls(name, (r, g, b), 360.0 * h, s, v, radius, robot, pos)


@dataclass(frozen=True)
class Blob:
    """A coarse circle in full-resolution pixels.

    ``quality`` is the contour's support of the circle times ``fill``, the
    share of the disc set in the mask; ``chroma`` is the blob's colour
    strength (see :func:`~mutloc.detect.balls.cues.vivid`), 0 until
    :func:`find_blobs` measures it.
    """

    u: float
    v: float
    radius: float
    quality: float
    fill: float
    chroma: float = 0.0


def pick_downscale(downscale: int | None, min_radius_px: float, w: int, h: int) -> int:
    """Coarse-search factor: the largest of 1, 2, 4 keeping ``min_radius_px / k >= 1.5``.

    Area-averaging mixes a small ball with its background, and below ~1.5
    coarse pixels of radius its hue no longer survives reliably (balls of
    2 px were missed about one time in ten at half resolution).
    """
    if downscale is not None:
        k = int(downscale)
    else:
        k = 1
        for cand in (2, 4):
            if min_radius_px / cand >= 1.5 and min(w, h) // cand >= 120:
                k = cand
    # Never shrink below a usable search image.
    while k > 1 and (w // k < 16 or h // k < 16):
        k //= 2
    return k


def value_floor(img: np.ndarray) -> int:
    """Value threshold adapted to the image's exposure.

    Hue is meaningless in near-black pixels (noise dominates), but a dim image
    must still find its dim balls: the floor is a fraction of the 99th
    percentile of V, kept within [12, 40].  Every 4th row and column is
    plenty for a percentile.
    """
    return int(np.clip(0.12 * _value_p99(img, 4), 12, 40))


@numba.njit(cache=True, fastmath=False)
def _value_p99(img, step):
    """99th percentile of HSV's V (the largest of B, G, R) over every ``step``-th row and column."""
    hist = np.zeros(256, np.int64)
    for y in range(0, img.shape[0], step):
        for x in range(0, img.shape[1], step):
            hist[max(img[y, x, 0], img[y, x, 1], img[y, x, 2])] += 1
    target = 0.99 * hist.sum()
    acc = 0
    for v in range(256):
        acc += hist[v]
        if acc >= target:
            return v
    return 256


def hue_masks(hsv: np.ndarray, searches: list[BallSearch], tol_deg: float, v_floor: int) -> list[np.ndarray]:
    """One mask per marker: hue within ``tol_deg`` of its own, saturated and bright enough.

    Shading scales RGB, which leaves saturation unchanged; haze, highlights
    and JPEG chroma blur lower it, so the saturation floor is a fraction of
    the nominal saturation (the lowest over the markers: one pass for all).
    The hue test is a lookup table on the hue channel, which handles red's
    wrap-around for free and serves eight markers per pass, one bit each.
    """
    s_floor = min(int(np.clip(0.4 * 255 * s.saturation, 40, 110)) for s in searches)
    # Degrees of each 8-bit HSV_FULL hue bin; half a bin (0.7 deg) of slack.
    deg = np.arange(256) * (360.0 / 256.0)
    masks: list[np.ndarray] = []
    for start in range(0, len(searches), 8):
        chunk = searches[start : start + 8]
        table = np.zeros(256, np.uint8)
        for bit, s in enumerate(chunk):
            dh = np.abs((deg - s.hue_deg + 180.0) % 360.0 - 180.0)
            table[dh <= tol_deg + 0.71] |= np.uint8(1 << bit)
        label = np.empty(hsv.shape[:2], np.uint8)
        _label_kernel(hsv, table, s_floor, int(v_floor), label)
        masks.extend(np.bitwise_and(label, np.uint8(1 << bit)) for bit in range(len(chunk)))
    return masks


@numba.njit(cache=True, fastmath=False)
def _label_kernel(hsv, table, s_floor, v_floor, out) -> None:
    """``table[hue]`` where saturation and value reach their floors, else 0 (one pass over the HSV image)."""
    for y in range(out.shape[0]):
        for x in range(out.shape[1]):
            ok = (hsv[y, x, 1] >= s_floor) & (hsv[y, x, 2] >= v_floor)
            out[y, x] = table[hsv[y, x, 0]] * ok


def coarse_blobs(mask: np.ndarray, sx: float, sy: float, min_r: float, max_r: float) -> list[Blob]:
    """Candidate blobs of ``mask`` (a search image ``sx, sy`` times smaller), in full-resolution pixels.

    Each external contour may hold several circles: a ball touching another
    blob of a similar hue (a printed disc behind it, a second ball) merges
    with it in the mask, so after the best circle of a contour the points it
    does not explain are searched again (:func:`_contour_circles`).
    """
    return [Blob(*row) for row in _coarse_rows(mask, sx, sy, min_r, max_r).tolist()]


def _coarse_rows(mask: np.ndarray, sx: float, sy: float, min_r: float, max_r: float) -> np.ndarray:
    """:func:`coarse_blobs` as rows ``(u, v, radius, quality, fill)`` (n, 5)."""
    contours, _ = cv2.findContours(mask, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
    scale = 0.5 * (sx + sy)
    # A contour through pixel centres of a disc of radius r has ~0.87 * 2 pi r
    # points (8-connected); a partly hidden ball still shows over half of it.
    min_len = max(4, int(0.5 * 0.87 * 2 * math.pi * (0.7 * min_r / scale)))
    keep = [c for c in contours if len(c) >= min_len]
    rows = np.empty((3 * len(keep), 5))
    if not keep:
        return rows
    lens = np.array([len(c) for c in keep], np.int64)
    pts = np.concatenate(keep).reshape(-1, 2).astype(np.float64)  # coarse pixel centres
    n = _contour_circles(pts, lens, mask, float(sx), float(sy), float(scale), float(min_r), float(max_r), min_len,
                         _TRIPLETS, rows)
    return rows[:n]


@numba.njit(cache=True, fastmath=False)
def _contour_circles(pts, lens, mask, sx, sy, scale, min_r, max_r, min_len, triplets, out):
    """Up to three circles per contour (``pts`` holds the contours of lengths ``lens`` one after the other).

    Writes rows ``(u, v, radius, quality, fill)`` in full-resolution pixels
    into ``out``; returns how many.  One compiled pass: the per-contour
    work is small, and in Python its overhead was most of the coarse search.
    """
    nb = 0
    start = 0
    for c in range(lens.shape[0]):
        L = lens[c]
        cp = pts[start : start + L]
        start += L
        # Pixel count of the filled blob: the outline's area (shoelace, as
        # cv2.contourArea; exact for integer points) plus half its length.
        a = 0.0
        px = cp[L - 1, 0]
        py = cp[L - 1, 1]
        for i in range(L):
            a += px * cp[i, 1] - py * cp[i, 0]
            px = cp[i, 0]
            py = cp[i, 1]
        area = abs(a * 0.5) + 0.5 * L + 1.0
        r_eq = math.sqrt(area / math.pi) * scale
        if r_eq < 0.6 * min_r:
            continue
        if L < 6:
            mx = 0.0
            my = 0.0
            for i in range(L):
                mx += cp[i, 0]
                my += cp[i, 1]
            out[nb, 0] = (mx / L + 0.5) * sx - 0.5
            out[nb, 1] = (my / L + 0.5) * sy - 0.5
            out[nb, 2] = r_eq
            out[nb, 3] = 0.3
            out[nb, 4] = 1.0
            nb += 1
            continue
        # No circle is much bigger than the contour holding it.
        x0 = x1 = cp[0, 0]
        y0 = y1 = cp[0, 1]
        for i in range(1, L):
            x0 = min(x0, cp[i, 0])
            x1 = max(x1, cp[i, 0])
            y0 = min(y0, cp[i, 1])
            y1 = max(y1, cp[i, 1])
        span = 0.5 * math.hypot(x1 - x0, y1 - y0)
        rmin_c = 0.5 * min_r / scale
        rmax_c = min(1.2 * span + 1.0, 1.5 * max_r / scale)
        rest = cp.copy()
        for _ in range(3):
            ok, cu, cv_, r, frac = _ransac_circle_kernel(rest, max(1.0, 0.08 * r_eq / scale), triplets, rmin_c, rmax_c)
            if not ok:
                break
            # Support: how much of the circle's own circumference the contour
            # covers (a clean disc ~1, a rectangle's inscribed circle little).
            support = min(1.0, frac * rest.shape[0] / (0.87 * 2 * math.pi * max(r, 0.5)))
            if support >= 0.25:
                fill = _fill_kernel(mask, cu, cv_, r + 0.5)
                # The contour runs through the outermost pixel centres: half
                # a (coarse) pixel inside the true rim.
                R = (r + 0.5) * scale
                if 0.6 * min_r <= R <= 1.5 * max_r:
                    # Quality: support times how well the blob fills its
                    # circle (a ring or a crescent does not).
                    out[nb, 0] = (cu + 0.5) * sx - 0.5
                    out[nb, 1] = (cv_ + 0.5) * sy - 0.5
                    out[nb, 2] = R
                    out[nb, 3] = support * fill
                    out[nb, 4] = fill
                    nb += 1
            # Whatever this circle explains is set aside; the rest may hold
            # another one.
            lo2, hi2 = _ring(r, 2.0 * max(1.0, 0.08 * r))
            k = 0
            for i in range(rest.shape[0]):
                dx = rest[i, 0] - cu
                dy = rest[i, 1] - cv_
                if not (lo2 <= dx * dx + dy * dy <= hi2):
                    rest[k, 0] = rest[i, 0]
                    rest[k, 1] = rest[i, 1]
                    k += 1
            rest = rest[:k]
            if k < max(12, min_len):
                break
    return nb


def _blob_chroma(coarse: np.ndarray, rows: np.ndarray, sx: float, sy: float) -> np.ndarray:
    """Chroma of each blob (rows of :func:`_coarse_rows`): the best of its centre and four points halfway to its rim.

    Several points, because an occluder may cover the centre.
    """
    out = np.zeros(len(rows))
    _chroma_kernel(coarse, np.ascontiguousarray(rows), float(sx), float(sy), out)
    return out


@numba.njit(cache=True, fastmath=False)
def _chroma_kernel(coarse, rows, sx, sy, out) -> None:
    h = coarse.shape[0]
    w = coarse.shape[1]
    for b in range(rows.shape[0]):
        cu = (rows[b, 0] + 0.5) / sx - 0.5
        cv_ = (rows[b, 1] + 0.5) / sy - 0.5
        r = 0.5 * rows[b, 2] / sx
        best = 0.0
        for k in range(5):
            du = r if k == 1 else (-r if k == 2 else 0.0)
            dv = r if k == 3 else (-r if k == 4 else 0.0)
            i = round(cv_ + dv)
            j = round(cu + du)
            if 0 <= i < h and 0 <= j < w:
                hi = max(coarse[i, j, 0], coarse[i, j, 1], coarse[i, j, 2])
                lo = min(coarse[i, j, 0], coarse[i, j, 1], coarse[i, j, 2])
                best = max(best, float(hi) - float(lo))
        out[b] = best


#: Blobs of at least this quality look like whole discs; the others (down
#: to 0.15) are looked at only when no whole one of a marker is its ball.
WHOLE = 0.25


def find_blobs(
    img: np.ndarray, searches: list[BallSearch], k: int, max_r: float, v_floor: int, params: BallParams,
    gains: np.ndarray | None = None, masks: dict[str, list[tuple[np.ndarray, float, float]]] | None = None,
) -> list[list[Blob]]:
    """Per search, its blobs in the image shrunk ``k`` times, best first.

    Best: round, solid, vivid and (other things equal) big, as in the final
    score; blobs that are clearly not discs are dropped.  ``gains`` (linear,
    per channel) divide out the light's colour first (:mod:`.light`).
    ``masks``: where to add each search's hue mask, by name, with the
    factors ``(sx, sy)`` from its pixels to the image's.
    """
    H, W = img.shape[:2]
    coarse = img if k == 1 else cv2.resize(img, (W // k, H // k), interpolation=cv2.INTER_AREA)
    if gains is not None:
        coarse = correct(coarse, gains)
    hsv = cv2.cvtColor(coarse, cv2.COLOR_BGR2HSV_FULL)
    sx = W / coarse.shape[1]
    sy = H / coarse.shape[0]
    out = []
    for s, mask in zip(searches, hue_masks(hsv, searches, params.hue_tol_deg, v_floor)):
        if masks is not None:
            masks.setdefault(s.name, []).append((mask, sx, sy))
        rows = _coarse_rows(mask, sx, sy, params.min_radius_px, max_r)
        # A ball split by a pole leaves half-discs: support ~0.5 of their
        # circle, filling ~0.4 of it (:data:`WHOLE` for the rest).
        rows = rows[rows[:, 3] >= 0.15]
        blobs = [Blob(*row, chroma) for row, chroma in zip(rows.tolist(), _blob_chroma(coarse, rows, sx, sy).tolist())]
        blobs.sort(key=lambda b: -b.quality * evidence(2.0 * math.pi * b.radius) * vivid(b.chroma))
        out.append(blobs)
    return out


def same_circle(a: Blob, b: Blob) -> bool:
    """Whether two coarse circles are one blob's (centres and radii within a third of the larger radius,
    plus a pixel: coarse circles of one blob at two resolutions differ by that much)."""
    tol = 1.0 + max(a.radius, b.radius) / 3.0
    return math.hypot(a.u - b.u, a.v - b.v) <= tol and abs(a.radius - b.radius) <= tol


def fill_fraction(mask: np.ndarray, cu: float, cv_: float, r: float) -> float:
    """Share of the disc ``(cu, cv_, r)`` (mask pixels) that is set in ``mask``."""
    return float(_fill_kernel(mask, float(cu), float(cv_), float(r)))


@numba.njit(cache=True, fastmath=False)
def _fill_kernel(mask, cu, cv_, r):
    h, w = mask.shape
    x0, x1 = max(0, int(math.floor(cu - r))), min(w, int(math.ceil(cu + r)) + 1)
    y0, y1 = max(0, int(math.floor(cv_ - r))), min(h, int(math.ceil(cv_ + r)) + 1)
    n = 0
    k = 0
    r2 = r * r
    for y in range(y0, y1):
        dy2 = (y - cv_) ** 2
        for x in range(x0, x1):
            if (x - cu) ** 2 + dy2 <= r2:
                n += 1
                if mask[y, x] != 0:
                    k += 1
    return k / n if n > 0 else 0.0


def ransac_circle(pts: np.ndarray, tol: float, rmin: float, rmax: float) -> tuple[float, float, float, float] | None:
    """Circle (radius in [rmin, rmax]) through most of the contour ``pts``: ``(u, v, r, inlier fraction)``.

    A straight occluding edge or a ragged side of the blob does not pull it,
    unlike a least-squares circle or the blob's moments.
    """
    if len(pts) < 6:
        return None
    ok, cu, cv_, r, frac = _ransac_circle_kernel(np.ascontiguousarray(pts), float(tol), _TRIPLETS, rmin, rmax)
    return (cu, cv_, r, frac) if ok else None


@numba.njit(cache=True, fastmath=False)
def _ransac_circle_kernel(pts, tol, triplets, rmin, rmax):
    n = pts.shape[0]
    best = -1
    bu = bv = br = 0.0
    for h in range(triplets.shape[0]):
        # Three points spaced along the contour by a third of it (a lone
        # ball: well-conditioned circles), a sixth or a tenth (a ball whose
        # outline is only a part of a contour it shares with another blob).
        div = 3 if h % 3 == 0 else (6 if h % 3 == 1 else 10)
        sp = max(1, n // div)
        i0 = int(triplets[h, 0] * n) % n
        i1 = (i0 + sp + int(triplets[h, 1] * 0.5 * sp)) % n
        i2 = (i1 + sp + int(triplets[h, 2] * 0.5 * sp)) % n
        ax, ay = pts[i0, 0], pts[i0, 1]
        bx, by = pts[i1, 0], pts[i1, 1]
        cx, cy = pts[i2, 0], pts[i2, 1]
        ok, ux, uy, r = circle3(ax, ay, bx, by, cx, cy)
        if not ok:
            continue
        # Nearly collinear points give huge circles that hug straight edges.
        if r < rmin or r > rmax:
            continue
        cnt = _count_on(pts, ux, uy, r, tol)
        if cnt > best:
            best = cnt
            bu, bv, br = ux, uy, r
    if best < 5:
        return False, 0.0, 0.0, 0.0, 0.0
    # Polish: least squares on the inliers, twice (the inlier set of the
    # refined circle is a little larger).
    out = np.array([bu, bv, br])
    mask = np.empty(n, np.bool_)
    k = 0
    for _ in range(2):
        k = 0
        lo2, hi2 = _ring(out[2], tol)
        for i in range(n):
            dx = pts[i, 0] - out[0]
            dy = pts[i, 1] - out[1]
            mask[i] = lo2 <= dx * dx + dy * dy <= hi2
            if mask[i]:
                k += 1
        if k < 5 or not kasa_circle(pts, mask, out):
            return False, 0.0, 0.0, 0.0, 0.0
    return True, out[0], out[1], out[2], _count_on(pts, out[0], out[1], out[2], tol) / n


@numba.njit(cache=True, fastmath=False, inline="always")
def _ring(r, tol):
    """Squared distances bounding the ring ``|d - r| <= tol``: a point is tested without a square root."""
    lo = r - tol
    return (lo * lo if lo > 0.0 else -1.0), (r + tol) * (r + tol)


@numba.njit(cache=True, fastmath=False)
def _count_on(pts, ux, uy, r, tol):
    """How many of ``pts`` lie within ``tol`` of the circle ``(ux, uy, r)``."""
    lo2, hi2 = _ring(r, tol)
    k = 0
    for i in range(pts.shape[0]):
        dx = pts[i, 0] - ux
        dy = pts[i, 1] - uy
        if lo2 <= dx * dx + dy * dy <= hi2:
            k += 1
    return k
