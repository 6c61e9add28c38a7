"""Colour of the light: estimate it and take it out before hues are compared.

A ball's hue is the product of its albedo and the light's colour: under
warm (tungsten) light a yellow ball turns orange and a blue one nearly
black-grey, far outside any hue window around the nominal colour.  The
light's colour is estimated by the grey-world rule (the mean linear colour
of the image), and hues are compared after dividing it out -- only when the
image's cast is strong, since coloured posters and walls already give
white-lit scenes a mild cast that is not the light's
(:attr:`~mutloc.detect.balls.params.BallParams.auto_white_balance_below`).
Shading and highlights are handled elsewhere: hue ignores brightness, the
saturation floor is relative, and the rim is found by unmixing colours.
"""

from __future__ import annotations

import cv2
import numba
import numpy as np

from .params import BallParams

__all__ = ["correct", "light_gains", "lut_gains"]

# Display gamma for the linear approximation of sRGB values (cheap and
# close enough for a colour correction).
_GAMMA = 2.2
_LIN = np.arange(256) / 255.0
_LIN_SRGB = _LIN**_GAMMA


def light_gains(img: np.ndarray, params: BallParams) -> np.ndarray | None:
    """Per-channel gains (B, G, R) on the *pixel values* that make the light white; None for none.

    Linear light is scaled by ``gains ** gamma`` (2.2 for sRGB images, 1 for
    linear ones).
    """
    gamma = _GAMMA if params.srgb else 1.0
    wb = params.white_balance
    if wb == "off":
        return None
    if wb == "auto":
        # Every 8th row and column is plenty for a mean (and cheap: this
        # runs on every image).
        mean = np.empty(3)
        _mean_colour(img, _LIN_SRGB if params.srgb else _LIN, 8, mean)
        top = float(mean.max())
        if top <= 1e-6 or float(mean.min()) >= params.auto_white_balance_below * top:
            return None
        light = mean / top
    else:
        # The nominal light colour is sRGB, whatever the image's encoding.
        lin = (np.asarray(wb, float)[::-1] / 255.0) ** _GAMMA
        light = lin / float(lin.max())
    # A channel the light hardly has cannot be recovered beyond noise.
    return (1.0 / np.maximum(light, 1.0 / 16.0)) ** (1.0 / gamma)


@numba.njit(cache=True, fastmath=False)
def _mean_colour(img, table, step, out) -> None:
    """Mean of ``table[img]`` per channel over every ``step``-th row and column (summed row by row)."""
    out[:] = 0.0
    n = 0
    for y in range(0, img.shape[0], step):
        for x in range(0, img.shape[1], step):
            for c in range(3):
                out[c] += table[img[y, x, c]]
            n += 1
    for c in range(3):
        out[c] /= max(n, 1)


def _tables(gains: np.ndarray) -> np.ndarray:
    """(256, 1, 3) uint8 LUT scaling the pixel values by ``gains``."""
    x = np.arange(256.0)
    cols = [np.clip(x * float(g) + 0.5, 0, 255) for g in gains]
    return np.stack(cols, axis=1).astype(np.uint8).reshape(256, 1, 3)


def correct(img: np.ndarray, gains: np.ndarray | None) -> np.ndarray:
    """``img`` (uint8 BGR) as under white light; ``img`` itself when ``gains`` is None."""
    if gains is None:
        return img
    return cv2.LUT(img, _tables(gains))


def lut_gains(gains: np.ndarray | None, params: BallParams) -> np.ndarray:
    """The gains in the rim stage's values (:func:`~.params.value_lut`), ones when None."""
    if gains is None:
        return np.ones(3)
    return np.asarray(gains, float) ** (params.mix_gamma if params.srgb else 1.0)
