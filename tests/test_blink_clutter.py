"""Three ways background misled the light tracker, on mutloc's own
rendered trust sequences (:func:`mutloc.sim.tracking.varied_world`, 2 m,
robot q's view of p's lights), against the renderer's true light pixels and
states:

- a clipped light over a plain wall was measured 3-4 px off by its halo,
  against background plates taken before its robot moved, and lost; then,
  just named while off, it took a lit wall for itself: the region that
  switched on beside it was where it looked, but the centroid window grew
  onto the wall, 42 px beyond (seed 3);
- a red light passing a magenta poster (255 in red, as bright as the light
  in the brightest channel) had its centre dragged 15 px onto the poster,
  and its track then followed the poster (seed 7);
- a blue light over a pale wall changed the brightest channel's peak by
  25 grey levels when it switched, too faint to be named (seed 24, p's view
  of q: never named)."""

from __future__ import annotations

import dataclasses
import math

import pytest

from mutloc.detect.blink import BlinkParams, BlinkTracker, association
from mutloc.sim.tracking import light_identity, light_view, varied_world
from mutloc.sim.world import standard_rig

FPS = 30.0
N = 60


def _view(seed: int, observer: str = "q", *, poster_text: bool = True):
    rig, world = varied_world(standard_rig("lights"), seed, distance=2.0)
    if not poster_text:
        world = dataclasses.replace(world, room=dataclasses.replace(world.room, poster_text=False))
    markers = rig.robot("p" if observer == "q" else "q").markers
    frames, truth, lit = light_view(world, observer, list(markers), N, FPS, seed)
    return rig, markers, frames, truth, lit, observer


# Every light in the brightness channel (a grey stream; white lights): where
# the mechanisms below act.  Tracked in their colours' own images (the
# default, mutloc.detect.blink.channels), these lights do not meet the case.
BRIGHT = BlinkParams(by_colour=False)


def _identity(data, params=None):
    rig, markers, frames, truth, lit, observer = data
    tr = BlinkTracker(markers, FPS, params=params, camera=rig.robot(observer).camera)
    return light_identity([tr.update(img, k / FPS) for k, img in enumerate(frames)], truth, lit, FPS)


@pytest.fixture(scope="module")
def wall_view():
    return _view(3)


@pytest.mark.slow
def test_a_clipped_light_is_not_measured_by_a_halo_its_outline_contradicts(wall_view, monkeypatch):
    """p's red M3 over a plain pale wall: measured against background plates
    taken while it was off, before p moved, its halo put it 3-4 px off and
    its track lost it; the clipped plateau's outline, from the frame alone,
    vetoes that."""
    assert _identity(wall_view).failures == []
    r = _identity(wall_view, BRIGHT)
    assert r.wrong == 0 and r.failures == [], r.failures
    # The mechanism, in the brightness channel: without the veto M3 is lost
    # for 3 lit frames or more.
    monkeypatch.setattr(association, "HALO_AGREE_PX", math.inf)
    without = _identity(wall_view, BRIGHT)
    assert without.good <= r.good - 3, without.failures


@pytest.mark.slow
def test_a_spot_far_beyond_the_region_that_switched_on_is_not_the_light(wall_view, monkeypatch):
    """Measured by the halo as before (the loss that leaves M3's name to a
    new track), M3, just named while off, takes the wall lit by p's body for
    itself, 42 px beyond the region that switched on: with the switch reach
    it is not, and the name is kept."""
    monkeypatch.setattr(association, "HALO_AGREE_PX", math.inf)
    r = _identity(wall_view, BRIGHT)
    assert r.wrong == 0, r.failures
    # The mechanism: measured wherever the centroid window grows, M3 is
    # reported 100-160 px off (a wrong label) and lost for a second.
    monkeypatch.setattr(association, "SWITCH_REACHES", math.inf)
    without = _identity(wall_view, BRIGHT)
    assert without.wrong >= 1 and without.good <= r.good - 5, without.failures


@pytest.mark.slow
def test_a_light_is_measured_in_its_own_colour_beside_a_poster_as_bright(monkeypatch):
    data = _view(7)
    assert _identity(data).failures == []
    r = _identity(data, BRIGHT)
    assert r.wrong == 0 and r.failures == [], r.failures
    # The mechanism: measured in the brightest channel only, the red light
    # is dragged onto the magenta poster (15 px, then its track follows the
    # poster: wrong labels).
    monkeypatch.setattr(association, "OWN_COLOUR_DISAGREE_PX", math.inf)
    without = _identity(data, BRIGHT)
    assert without.wrong >= 1, without.failures


@pytest.fixture(scope="module")
def pale_wall_view():
    return _view(24, "p")


@pytest.mark.slow
def test_a_coloured_light_over_a_pale_wall_is_named_by_its_own_colour(pale_wall_view):
    data = pale_wall_view
    truth, lit = data[3], data[4]
    m1_lit = sum(1 for k in range(int(FPS), N) if lit[k]["M1"] and "M1" in truth[k])
    assert m1_lit >= 10  # the sequence does show the case
    # Tracked in its own colour's image (the default), or in the brightness
    # channel and named by its own colour's history, the blue light is named.
    for params in (None, BRIGHT):
        r = _identity(data, params)
        assert r.wrong == 0 and r.failures == [], r.failures
    # Named by the brightest channel alone, q's blue M1 never is.
    without = _identity(data, BlinkParams(by_colour=False, own_colour=False))
    assert sum(1 for f in without.failures if f[1] == "M1") == m1_lit, without.failures


@pytest.mark.slow
def test_a_stray_seen_lit_once_is_not_named():
    """Same view (posters without their words), brightness channel: at the
    image's left edge the pan uncovers a bright patch for five frames; the
    track there is taken for lit once, and its history -- a single bump --
    fits q's 2 Hz blink.  Named, it put M1 480 px from the light, predicted,
    before the first second was out.  A light blinking half the time is seen
    lit in about half its history: a track lit in under a quarter is not
    named.

    The posters' words are left out because OpenCV draws them (putText) with
    glyphs that change between releases (5.0 -> 5.1), and the stray's history
    hangs on those pixels: with the words the case showed under 5.0 and not
    under 5.1.  Without them the frames are the same under both."""
    data = _view(24, "p", poster_text=False)
    assert _identity(data, BRIGHT).wrong == 0
    without = _identity(data, BlinkParams(by_colour=False, min_lit_fraction=0.0))
    assert without.wrong >= 1, without.failures


@pytest.mark.slow
def test_a_blue_light_over_a_pale_poster_is_tracked_in_its_own_colour():
    """Trust seed 33, p's view of q: q's blue M1 passes before a pale blue
    poster, bright in the brightest channel too.  Tracked in the blue image
    (blue less the larger of red and green, where the poster is dark) every
    lit light-frame after the first second is named within 3 px; with every
    light in the brightness channel M1 was measured up to 5 px off, lost at
    each off period and never named, and a stray took its name (reported
    over 200 px off)."""
    data = _view(33, "p")
    truth, lit = data[3], data[4]
    assert sum(1 for k in range(int(FPS), N) if lit[k]["M1"] and "M1" in truth[k]) >= 10  # the case is shown
    r = _identity(data)
    assert r.wrong == 0 and r.failures == [], r.failures
    without = _identity(data, BRIGHT)
    assert without.wrong >= 1, without.failures
    assert sum(1 for f in without.failures if f[1] == "M1") >= 10, without.failures
