"""Evidence cues shared by the ranking of coarse blobs and the final score."""

from __future__ import annotations

import colorsys
import math

import numpy as np

__all__ = ["evidence", "hue_chroma", "shading_contrast", "vivid"]


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
    enc = np.searchsorted(lut, np.clip(bgr, 0.0, 1.0)).clip(0, 255).astype(float)
    h, _, _ = colorsys.rgb_to_hsv(*(enc[::-1] / 255.0))
    return 360.0 * h, float(enc.max() - enc.min())


def shading_contrast(img: np.ndarray, lut: np.ndarray, cx: float, cy: float, inner: np.ndarray) -> float:
    """Relative brightness range over the ball: its middle and the ring just inside the rim (0..1).

    A lit sphere is shaded (its limb or one side darker than its middle); a
    printed disc of the same colour is flat.  ``inner`` (n, 3) holds the
    ball colours next to the rim, in ``lut``'s values.
    """
    Himg, Wimg = img.shape[:2]
    ring = np.sort(inner.sum(axis=1))
    if len(ring) < 4:
        return 0.0
    # 10th and 90th percentiles (robust to a stray ray).
    vals = [float(ring[len(ring) // 10]), float(ring[(9 * len(ring)) // 10])]
    i, j = int(round(cy)), int(round(cx))
    if 1 <= i < Himg - 1 and 1 <= j < Wimg - 1:
        vals.append(float(lut[img[i - 1 : i + 2, j - 1 : j + 2]].sum(axis=2).mean()))
    hi = max(vals)
    return (hi - min(vals)) / hi if hi > 0 else 0.0
