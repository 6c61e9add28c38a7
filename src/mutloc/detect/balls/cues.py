"""Evidence cues shared by the ranking of coarse blobs and the final score."""

from __future__ import annotations

import colorsys
import math

import numba
import numpy as np

from .numeric import sort_inplace

__all__ = [
    "encode_kernel", "encoded_hue_chroma", "evidence", "hue_chroma", "shading_contrast", "shading_kernel", "vivid",
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


def shading_contrast(img: np.ndarray, lut: np.ndarray, cx: float, cy: float, inner: np.ndarray) -> float:
    """Relative brightness range over the ball: its middle and the ring just inside the rim (0..1).

    A lit sphere is shaded (its limb or one side darker than its middle); a
    printed disc of the same colour is flat.  ``inner`` (n, 3) holds the
    ball colours next to the rim, in ``lut``'s values.
    """
    return float(shading_kernel(img, lut, float(cx), float(cy), inner))


@numba.njit(cache=True, fastmath=False)
def shading_kernel(img, lut, cx, cy, inner):
    # Sums in NumPy's order (three values in turn, nine pairwise), so the
    # figures match the array code they replace.
    n = inner.shape[0]
    if n < 4:
        return 0.0
    ring = np.empty(n)
    for k in range(n):
        ring[k] = inner[k, 0] + inner[k, 1] + inner[k, 2]
    sort_inplace(ring, n)
    # 10th and 90th percentiles (robust to a stray ray).
    lo = ring[n // 10]
    hi = ring[(9 * n) // 10]
    mn = min(lo, hi)
    mx = max(lo, hi)
    i = round(cy)
    j = round(cx)
    if 1 <= i < img.shape[0] - 1 and 1 <= j < img.shape[1] - 1:
        s = np.empty(9, np.float32)
        for a in range(3):
            for b in range(3):
                p = img[i - 1 + a, j - 1 + b]
                s[3 * a + b] = lut[p[0]] + lut[p[1]] + lut[p[2]]
        tot = (((s[0] + s[1]) + (s[2] + s[3])) + ((s[4] + s[5]) + (s[6] + s[7]))) + s[8]
        mid = float(tot / np.float32(9.0))
        mn = min(mn, mid)
        mx = max(mx, mid)
    return (mx - mn) / mx if mx > 0 else 0.0
