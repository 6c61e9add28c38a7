"""A clipped light's centroid ignores another bright object in its window.

A large lit light beside a pale poster: the centroid window (sized to the
light) takes in the poster too, which drags the centroid by up to its
window's size; a light confirmed by its colour is then taken for off there,
and over a fast pan the track loses it.  Checked on a drawn spot against its
known centre, and on mutloc's own rendered sequence (bench/blink_identity.py,
3 m, seed 1: robot q pans at 10-12 px a frame while p drives; p's green light
M4, beside a peach poster, was lost at frame 52) against the renderer's true
light pixels and states."""

from __future__ import annotations

import math

import numpy as np
import pytest

from mutloc.core.rig import Marker
from mutloc.detect.blink import BlinkParams, BlinkTracker
from mutloc.detect.blink import inherit, measure
from mutloc.detect.blink.tracker import LightTracker
from mutloc.sim.tracking import panning_lights
from mutloc.sim.tracking import light_identity

FPS = 30.0
N = 58  # the tracker is causal: frames 0-57 hold the loss (52-57)


def _disc(img, uv, radius, level, n=8):
    """Paint a disc of grey ``level`` (area-sampled n x n per pixel) into ``img``."""
    h, w = img.shape
    ys, xs = np.mgrid[0:h * n, 0:w * n]
    inside = ((xs + 0.5) / n - 0.5 - uv[0]) ** 2 + ((ys + 0.5) / n - 0.5 - uv[1]) ** 2 <= radius ** 2
    cover = inside.reshape(h, n, w, n).mean(axis=(1, 3))
    img += cover * (level - img)


@pytest.mark.parametrize("uv", [(60.3, 64.7), (58.85, 66.2)])
def test_clipped_centroid_ignores_a_bright_neighbour(uv, monkeypatch):
    tr = LightTracker({"a": Marker("a", "q", np.array([0.1, 0.0, 0.0]), blink_hz=3.0)}, FPS)
    img = np.full((110, 120), 205.0)
    _disc(img, uv, 8.0, 255.0)  # the lit light, clipped
    _disc(img, (uv[0] - 6.0, uv[1] - 24.0), 10.0, 249.0)  # a pale poster above it, not touching
    img = img.round().astype(np.float32)
    peak = (round(uv[0]), round(uv[1]))
    centre, _ = tr._centroid(img, *peak, 255.0, 20)
    np.testing.assert_allclose(centre, uv, atol=0.3)
    # The bias this removes exists: without it the poster drags the centroid.
    monkeypatch.setattr(measure, "NEIGHBOUR_SHARE", 1.0)
    dragged, _ = tr._centroid(img, *peak, 255.0, 20)
    assert math.hypot(*(dragged - np.asarray(uv))) > 3.0


@pytest.fixture(scope="module")
def pale_poster_pan():
    return panning_lights(3.0, 1, N, FPS)


def _identity(data, params=None):
    rig, markers, frames, truth, lit = data
    tr = BlinkTracker(markers, FPS, camera=rig.robot("q").camera, params=params)
    return light_identity([tr.update(img, k / FPS) for k, img in enumerate(frames)], truth, lit, FPS)


@pytest.mark.slow
def test_light_beside_a_pale_poster_is_kept_over_a_fast_pan(pale_poster_pan, monkeypatch):
    """Every lit frame of both lights after the first second is named within
    3 px (before: M4 lost in frames 52-69; M3 6.2 px off at frame 30, where
    the candidate the track took held no lit spot and the light, 6 px from
    the prediction, was not looked for there); without leaving the poster out
    of the centroid M4 is off or missing in at least 3 of its lit frames
    50-57 (measured: 4, frames 52, 53, 56, 57; with the hand-over of a lost
    light's spot, ``inherit.HAND_OVER_GATES``, 2 -- it is turned off here to
    show what the centroid alone does)."""
    assert _identity(pale_poster_pan).failures == []
    # In the brightness channel (in their own colours' images the lights
    # stand apart from the pale poster anyway):
    monkeypatch.setattr(inherit, "HAND_OVER_GATES", 0.0)
    with_ = _identity(pale_poster_pan, BlinkParams(by_colour=False))
    monkeypatch.setattr(measure, "NEIGHBOUR_SHARE", 1.0)
    without = _identity(pale_poster_pan, BlinkParams(by_colour=False))
    assert with_.wrong <= without.wrong
    assert with_.failures == [], with_.failures
    assert sum(1 for k in range(30, N) if pale_poster_pan[4][k]["M4"] and "M4" in pale_poster_pan[3][k]) >= 12
    lost = [f for f in without.failures if f[1] == "M4" and 50 <= f[0] < N]
    assert len(lost) >= 3, without.failures
