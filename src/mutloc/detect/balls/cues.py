"""Evidence cues shared by the ranking of coarse blobs and the final score."""

from __future__ import annotations

import colorsys
import math

import numba
import numpy as np

from .numeric import column_medians, sort_inplace

__all__ = [
    "GREY_BELOW", "ball_coloured", "encode_kernel", "encoded_hue_chroma", "evidence", "hue_chroma", "hue_kernel", "shading_contrast",
    "shading_kernel", "vivid",
]


def vivid(chroma: float) -> float:
    """How clearly coloured (chroma = max - min of the encoded 0..255 BGR), 0..1.

    Dim, barely tinted patches can have the right hue; a ball of a saturated
    colour has a strong chroma even in dim light.
    """
    return 1.0 - math.exp(-((chroma / 40.0) ** 2))


def evidence(rim_length_px: float) -> float:
    """Confidence from the length of rim that fits the model (0..1).

    A blob of a few pixels is round by default, so, other things equal, the
    bigger of two blobs of the right colour is the ball.
    """
    return 1.0 - math.exp(-rim_length_px / 15.0)


def hue_chroma(bgr: np.ndarray, lut: np.ndarray) -> tuple[float, float]:
    """Hue (deg) and chroma (max - min, 0..255 encoded) of a BGR colour in ``lut``'s values."""
    return encoded_hue_chroma(*encode_kernel(lut, float(bgr[0]), float(bgr[1]), float(bgr[2])))


def encoded_hue_chroma(b: float, g: float, r: float) -> tuple[float, float]:
    """:func:`hue_chroma` of a colour already encoded to 0..255 (``encode_kernel``)."""
    h, _, _ = colorsys.rgb_to_hsv(r / 255.0, g / 255.0, b / 255.0)
    return 360.0 * h, max(b, g, r) - min(b, g, r)


@numba.njit(cache=True, fastmath=False)
def encode_kernel(lut, b, g, r):
    """The 0..255 values whose ``lut`` entries first reach ``b, g, r`` (clipped to 0..1)."""
    out = np.empty(3)
    n = lut.shape[0]
    for c, v in enumerate((b, g, r)):
        v = min(max(v, 0.0), 1.0)
        lo = 0
        if v != v:  # NaN sorts last
            lo = n
        hi = n
        while lo < hi:  # the first index with lut >= v
            mid = (lo + hi) // 2
            if lut[mid] < v:
                lo = mid + 1
            else:
                hi = mid
        out[c] = min(lo, 255)
    return out[0], out[1], out[2]


#: A colour (in the unmixing values) whose chroma is less than this share of its brightest channel has
#: no hue to compare: about the coarse search's lowest saturation floor, 40 of 255 in encoded values
#: (``1 - (215 / 255) ** 1.7``).
GREY_BELOW = 0.25


def shading_contrast(
    img: np.ndarray, lut: np.ndarray, cx: float, cy: float, inner: np.ndarray, ball: np.ndarray | None = None,
    mid_pts: np.ndarray | None = None, gain: np.ndarray | None = None, tol_deg: float = 24.0,
) -> float:
    """Relative brightness range over the ball: its middle and the ring just inside the rim (0..1).

    A lit sphere is shaded (its limb or one side darker than its middle); a
    printed disc of the same colour is flat.  ``inner`` (n, 3) holds the
    ball colours next to the rim, in ``lut``'s values (times ``gain``, the
    light's colour divided out, if any), ``ball`` their median (computed
    when None).  Only colours of the ball's count (:func:`ball_coloured`:
    the hue of ``ball`` within ``tol_deg``), so a ray an occluder's edge
    crossed is left out of the ring; the middle is the 3x3 pixels at
    ``(cx, cy)`` if each has the ball's colour, else (an occluder hides it:
    a cut ball, a printed disc behind a box) the mean of the points
    ``mid_pts`` (k, 2: half way in along the rays of the visible rim) that
    have it.
    """
    inner = np.ascontiguousarray(inner, dtype=np.float64)
    if ball is None:
        ball = np.empty(3)
        column_medians(inner, ball)
    g = np.ones(3) if gain is None else np.ascontiguousarray(gain, dtype=np.float64)
    mid = np.zeros((0, 2)) if mid_pts is None else np.ascontiguousarray(mid_pts, dtype=np.float64)
    return float(shading_kernel(img, lut, g, float(cx), float(cy), inner, np.asarray(ball, np.float64), mid,
                                float(tol_deg)))


@numba.njit(cache=True, fastmath=False)
def hue_kernel(b, g, r):
    """Hue (deg) of a colour, as :func:`colorsys.rgb_to_hsv` (0 for a grey)."""
    mx = max(b, g, r)
    mn = min(b, g, r)
    if mx == mn:
        return 0.0
    d = mx - mn
    if r == mx:
        h = (g - b) / d
    elif g == mx:
        h = 2.0 + (b - r) / d
    else:
        h = 4.0 + (r - g) / d
    return 360.0 * ((h / 6.0) % 1.0)


@numba.njit(cache=True, fastmath=False)
def ball_coloured(b, g, r, hue_deg, tol_deg):
    """Whether a colour (unmixing values, any scale: shading scales them alike) has a hue
    (chroma at least :data:`GREY_BELOW` of its brightest channel) within ``tol_deg`` of ``hue_deg``."""
    mx = max(b, g, r)
    if not mx > 0.0 or mx - min(b, g, r) < GREY_BELOW * mx:
        return False
    return abs((hue_kernel(b, g, r) - hue_deg + 180.0) % 360.0 - 180.0) <= tol_deg


@numba.njit(cache=True, fastmath=False)
def shading_kernel(img, lut, gain, cx, cy, inner, ball, mid_pts, tol_deg):
    # Sums in NumPy's order (three values in turn, nine pairwise), so the
    # figures match the array code they replace.
    n = inner.shape[0]
    if n < 4:
        return 0.0
    hue = hue_kernel(ball[0], ball[1], ball[2])
    ring = np.empty(n)
    m = 0
    for k in range(n):
        if ball_coloured(inner[k, 0], inner[k, 1], inner[k, 2], hue, tol_deg):
            ring[m] = inner[k, 0] + inner[k, 1] + inner[k, 2]
            m += 1
    if m < 4:
        return 0.0
    sort_inplace(ring, m)
    # 10th and 90th percentiles (robust to a stray ray).
    lo = ring[m // 10]
    hi = ring[(9 * m) // 10]
    mn = min(lo, hi)
    mx = max(lo, hi)
    i = round(cy)
    j = round(cx)
    H = img.shape[0]
    W = img.shape[1]
    seen = False
    if 1 <= i < H - 1 and 1 <= j < W - 1:
        s = np.empty(9, np.float32)
        seen = True
        for a in range(3):
            for b in range(3):
                p = img[i - 1 + a, j - 1 + b]
                s[3 * a + b] = lut[p[0]] + lut[p[1]] + lut[p[2]]
                seen = seen and ball_coloured(gain[0] * lut[p[0]], gain[1] * lut[p[1]], gain[2] * lut[p[2]],
                                              hue, tol_deg)
        if seen:
            tot = (((s[0] + s[1]) + (s[2] + s[3])) + ((s[4] + s[5]) + (s[6] + s[7]))) + s[8]
            mid = float(tot / np.float32(9.0))
            mn = min(mn, mid)
            mx = max(mx, mid)
    if not seen:
        # The middle is hidden: the ball half way in along its visible rays instead.
        acc = 0.0
        k = 0
        for q in range(mid_pts.shape[0]):
            y = round(mid_pts[q, 1])
            x = round(mid_pts[q, 0])
            if 0 <= y < H and 0 <= x < W:
                p = img[y, x]
                b_, g_, r_ = gain[0] * lut[p[0]], gain[1] * lut[p[1]], gain[2] * lut[p[2]]
                if ball_coloured(b_, g_, r_, hue, tol_deg):
                    acc += b_ + g_ + r_
                    k += 1
        if k > 0:
            mn = min(mn, acc / k)
            mx = max(mx, acc / k)
    return (mx - mn) / mx if mx > 0 else 0.0
