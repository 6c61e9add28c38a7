"""A blinking light over background as bright as it is in its own colour (a
green light in front of a green poster, both clipping in green): the
brightest channel barely changes when the light switches, the other channels
do.  And a light first seen switching off while the observing camera pans:
the track born then starts with a velocity measured in the two frames
before, so it follows its light through the off half.  On rendered
sequences (mutloc's own room with posters), against the renderer's true
light pixels and states."""

from __future__ import annotations

import dataclasses

import pytest

from mutloc.detect.blink import BlinkTracker
from mutloc.detect.blink.params import BlinkParams
from mutloc.sim.render import moving_world
from mutloc.sim.tracking import light_identity, light_view
from mutloc.sim.world import standard_rig

FPS = 30.0
N = 60


def _view(seed: int, observer: str, *, poster_text: bool = True):
    """Robot ``observer``'s 60 frames of the other robot's lights at 2 m
    (trust sequence ``seed``), their true pixels and on/off states;
    ``poster_text=False`` leaves the posters' words out (OpenCV draws them with
    putText, whose glyphs change between releases: 5.0 -> 5.1)."""
    rig = standard_rig("lights")
    world = moving_world(rig, distance=2.0, seed=seed)
    if not poster_text:
        world = dataclasses.replace(world, room=dataclasses.replace(world.room, poster_text=False))
    markers = rig.robot("q" if observer == "p" else "p").markers
    frames, truth, lit = light_view(world, observer, list(markers), N, FPS, seed)
    return rig, markers, frames, truth, lit, observer


@pytest.fixture(scope="module")
def green_over_green():
    """Robot q's view of p at 2 m (trust sequence seed 6): p's green light M4
    passes in front of a green poster from the first frames on."""
    return _view(6, "q")


@pytest.fixture(scope="module")
def panning_view():
    """Robot p's view of q at 2 m (trust sequence seed 6): q's blue 2 Hz
    light M1 is first seen switching off (frame 8) while p's camera pans by
    ~3 px a frame and keeps q in view."""
    return _view(6, "p", poster_text=False)  # the case hangs on pixels near a poster's words


def _identity(data, params=None):
    rig, markers, frames, truth, lit, observer = data
    tr = BlinkTracker(markers, FPS, params=params, camera=rig.robot(observer).camera)
    return light_identity([tr.update(img, k / FPS) for k, img in enumerate(frames)], truth, lit, FPS)


def _lit_and_missed(data, name: str, params=None):
    """Frames after the first second in which light ``name`` is lit and
    visible; the identity result; how many of those it missed."""
    rig, markers, frames, truth, lit, _ = data
    total = sum(1 for k in range(int(FPS), N) if lit[k][name] and name in truth[k])
    r = _identity(data, params)
    return total, r, sum(1 for f in r.failures if f[1] == name)


@pytest.mark.slow
def test_green_light_over_green_poster_is_identified(green_over_green):
    green_total, r, green_missed = _lit_and_missed(green_over_green, "M4")
    assert green_total >= 8  # the sequence does show the case
    # Goal: the green light named in at least half of its lit frames
    # after the first second (before the colour contrast: in none), never a
    # wrong name.
    assert green_missed <= green_total / 2, r.failures
    assert r.wrong == 0
    # In the brightness channel too, where the colour contrast acts.
    bright = BlinkParams(by_colour=False)
    assert _lit_and_missed(green_over_green, "M4", bright)[2] <= green_total / 2
    # The mechanism: without the colour contrast the green light is never named.
    missed = _lit_and_missed(green_over_green, "M4", bright)[2]
    assert _lit_and_missed(green_over_green, "M4", BlinkParams(by_colour=False, colour_contrast=0.0))[2] > missed


def _followed_and_named(data, name: str) -> int:
    """Light ``name`` is named within 3 px in all but a few of its lit frames
    after the first second, never a wrong name; returns how many it missed."""
    total, r, missed = _lit_and_missed(data, name)
    assert total >= 10  # the sequence does show the case
    assert missed <= 2, r.failures
    assert r.wrong == 0
    return missed


@pytest.mark.slow
def test_light_first_seen_switching_off_is_followed_and_named(panning_view):
    # Before the velocity at birth: named in none until frame 49.
    _followed_and_named(panning_view, "M1")
    # The mechanism: without the velocity at birth the light is named late.
    # (In the brightness channel; tracked in its own colour's image the light
    # is found switching on soon enough.)
    bright_missed = _lit_and_missed(panning_view, "M1", BlinkParams(by_colour=False))[2]
    assert bright_missed <= 2
    assert _lit_and_missed(panning_view, "M1", BlinkParams(by_colour=False, birth_motion=False))[2] \
        >= bright_missed + 8


@pytest.fixture(scope="module")
def lit_edge_view():
    """Robot p's view of q at 2 m (trust sequence seed 0): q's yellow 3 Hz
    light M2 switches on (frame 10) just below a bright edge; its clipped
    spot's centroid, in a window grown to hold it, slid 32 px up the edge."""
    return _view(0, "p")


@pytest.mark.slow
def test_light_below_a_bright_edge_is_followed_and_named(lit_edge_view):
    # Before the centroid check: 10 of its lit frames missed.
    _followed_and_named(lit_edge_view, "M2")
