"""The ball detector's compiled cues against the NumPy / OpenCV / colorsys expressions they replace.

The detector's speed-up moved these figures into Numba; they must stay the
same numbers, bit for bit (a ranking or a threshold must not flip), so each
is checked against the array code it replaced, on random inputs.
"""

import colorsys

import cv2
import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from mutloc.detect.balls.cues import GREY_BELOW, hue_chroma, shading_contrast
from mutloc.detect.balls.light import light_gains
from mutloc.detect.balls.numeric import column_medians, np_sum
from mutloc.detect.balls.params import BallParams, value_lut
from mutloc.detect.balls.search import value_floor

SEEDS = st.integers(0, 2**32 - 1)


def _image(rng: np.random.Generator, h: int, w: int) -> np.ndarray:
    """A random BGR image, sometimes with a colour cast, sometimes a strided view."""
    img = rng.integers(0, 256, (h + 3, w + 5, 3), dtype=np.uint8)
    if rng.random() < 0.5:
        img = (img * rng.uniform(0.1, 1.0, 3)).astype(np.uint8)
    return img[1 : 1 + h, 2 : 2 + w] if rng.random() < 0.5 else np.ascontiguousarray(img[:h, :w])


@settings(max_examples=60, deadline=None)
@given(SEEDS, st.integers(1, 97))
def test_column_medians_are_numpys(seed, n):
    rng = np.random.default_rng(seed)
    a = rng.uniform(0, 1, (n, 3))
    if n > 3:
        a[rng.integers(0, n, n // 3)] = a[0]  # ties
    out = np.empty(3)
    column_medians(a, out)
    assert np.array_equal(out, np.median(a, axis=0))


@settings(max_examples=40, deadline=None)
@given(SEEDS, st.integers(1, 90), st.integers(1, 90))
def test_value_floor_is_the_hsv_percentile(seed, h, w):
    img = _image(np.random.default_rng(seed), h, w)
    v = cv2.extractChannel(cv2.cvtColor(np.ascontiguousarray(img[::4, ::4]), cv2.COLOR_BGR2HSV_FULL), 2)
    cum = np.cumsum(np.bincount(v.ravel(), minlength=256))
    assert value_floor(img) == int(np.clip(0.12 * int(np.searchsorted(cum, 0.99 * cum[-1])), 12, 40))


@settings(max_examples=40, deadline=None)
@given(SEEDS, st.integers(1, 90), st.integers(1, 90), st.booleans())
def test_light_gains_come_from_the_numpy_mean(seed, h, w, srgb):
    img = _image(np.random.default_rng(seed), h, w)
    gamma = 2.2 if srgb else 1.0
    mean = ((np.arange(256) / 255.0) ** gamma)[img[::8, ::8].reshape(-1, 3)].mean(axis=0)
    params = BallParams(srgb=srgb)
    got = light_gains(img, params)
    top = float(mean.max())
    if top <= 1e-6 or float(mean.min()) >= params.auto_white_balance_below * top:
        assert got is None
    else:
        assert np.array_equal(got, (1.0 / np.maximum(mean / top, 1.0 / 16.0)) ** (1.0 / gamma))


@settings(max_examples=80, deadline=None)
@given(SEEDS, st.booleans())
def test_hue_chroma_is_searchsorted_and_colorsys(seed, srgb):
    rng = np.random.default_rng(seed)
    lut = value_lut(srgb, 1.7)
    bgr = rng.uniform(-0.2, 1.2, 3) if rng.random() < 0.5 else lut[rng.integers(0, 256, 3)].astype(float)
    enc = np.searchsorted(lut, np.clip(bgr, 0.0, 1.0)).clip(0, 255).astype(float)
    h, _, _ = colorsys.rgb_to_hsv(*(enc[::-1] / 255.0))
    assert hue_chroma(bgr, lut) == (360.0 * h, float(enc.max() - enc.min()))


def _ball_coloured(c: np.ndarray, hue: float, tol: float) -> bool:
    mx = float(c.max())
    if not mx > 0 or mx - float(c.min()) < GREY_BELOW * mx:
        return False
    h = 360.0 * colorsys.rgb_to_hsv(c[2], c[1], c[0])[0]
    return abs((h - hue + 180.0) % 360.0 - 180.0) <= tol


@settings(max_examples=120, deadline=None)
@given(SEEDS, st.integers(0, 97))
def test_shading_contrast_is_the_numpy_figure(seed, n):
    """The ring's rays of the ball's colour, and its middle where seen (else the half-way points that
    are), as array code with colorsys's hues of the unmixing values."""
    rng = np.random.default_rng(seed)
    lut = value_lut(True, 1.7)
    # A ball of one colour, shaded, with rays and pixels of other colours (an occluder) among them.
    colour = lut[rng.integers(0, 256, 3)].astype(float)
    inner = colour * rng.uniform(0.2, 1.0, (n, 1)) + rng.normal(0, 0.01, (n, 3))
    other = rng.random(n) < rng.uniform(0, 0.6)
    inner[other] = rng.uniform(0, 1, (int(other.sum()), 3))
    inner = np.clip(inner, 0, 1)
    enc = np.searchsorted(lut, colour).clip(0, 255)
    img = rng.integers(0, 256, (9, 11, 3)).astype(np.uint8)
    ball_px = rng.random((9, 11)) < rng.uniform(0, 1)
    img[ball_px] = np.clip(enc * rng.uniform(0.5, 1.0, (int(ball_px.sum()), 1)), 0, 255).astype(np.uint8)
    cx, cy = rng.uniform(-1, 12), rng.uniform(-1, 10)
    if rng.random() < 0.3:  # exactly between pixels: rounding half to even
        cx, cy = np.floor(cx) + 0.5, np.floor(cy) + 0.5
    mid = rng.uniform(-2, 12, (int(rng.integers(0, 12)), 2))
    gain = rng.uniform(0.5, 2.0, 3) if rng.random() < 0.5 else None
    g = np.ones(3) if gain is None else gain
    tol = float(rng.uniform(5, 40))
    want = 0.0
    if n >= 4:
        ball = np.median(inner, axis=0)
        hue = 360.0 * colorsys.rgb_to_hsv(ball[2], ball[1], ball[0])[0]
        ring = np.sort([c.sum() for c in inner if _ball_coloured(c, hue, tol)])
        if len(ring) >= 4:
            vals = [float(ring[len(ring) // 10]), float(ring[(9 * len(ring)) // 10])]
            i, j = int(round(cy)), int(round(cx))
            seen = 1 <= i < 8 and 1 <= j < 10 and all(
                _ball_coloured(g * lut[p].astype(float), hue, tol) for p in img[i - 1 : i + 2, j - 1 : j + 2].reshape(-1, 3))
            if seen:
                vals.append(float(lut[img[i - 1 : i + 2, j - 1 : j + 2]].sum(axis=2).mean()))
            else:
                pts = [g * lut[img[y, x]].astype(float) for x, y in np.round(mid).astype(int) if 0 <= y < 9 and 0 <= x < 11]
                pts = [c for c in pts if _ball_coloured(c, hue, tol)]
                if pts:
                    vals.append(sum(float(c[0] + c[1] + c[2]) for c in pts) / len(pts))
            hi = max(vals)
            want = (hi - min(vals)) / hi if hi > 0 else 0.0
    assert shading_contrast(img, lut, cx, cy, inner, None, mid, gain, tol) == want


@settings(max_examples=60, deadline=None)
@given(SEEDS, st.integers(0, 300), st.booleans(), st.floats(-1e3, 1e3), st.sampled_from([1e-3, 1.0, 1e4]))
def test_np_sum_adds_in_numpys_order(seed, n, strided, offset, scale):
    a = np.random.default_rng(seed).normal(offset, scale, (n, 2))
    x = a[:, 1] if strided else np.ascontiguousarray(a[:, 1])
    assert np_sum(x, 0, n) == x.sum()  # bit for bit: pairwise, eight running sums per block

