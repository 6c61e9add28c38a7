"""A light first seen switching off, while the observing camera pans: the
track born then starts with a velocity measured in the two frames before,
so it follows its light through the off half and is named a blink history
after its birth instead of after the next track's.  On a rendered sequence
(mutloc's own room with posters; trust sequence seed 6, robot p's view of
q's lights), against the renderer's true light pixels and states."""

from __future__ import annotations

import pytest

from mutloc.detect.blink import BlinkTracker
from mutloc.detect.blink.params import BlinkParams
from mutloc.sim.render import moving_world, project_markers, render
from mutloc.sim.tracking import light_identity
from mutloc.sim.world import light_is_on, standard_rig

FPS = 30.0
N = 60
SEED = 6


@pytest.fixture(scope="module")
def panning_view():
    """Robot p's view of q at 2 m: q's blue 2 Hz light M1 switches off at
    frame 8 while p's camera pans by ~3 px a frame and keeps q in view."""
    rig = standard_rig("lights")
    world = moving_world(rig, distance=2.0, seed=SEED)
    markers = rig.robot("q").markers
    frames, truth, lit = [], [], []
    for k in range(N):
        t = k / FPS
        frames.append(render(world, "p", t, seed=SEED + k, noise_sigma=1.0))
        truth.append({n: u for n, u in project_markers(world, "p", t, check_occlusion=True).items()
                      if n in markers})
        lit.append({n: light_is_on(m, t) for n, m in markers.items()})
    return rig, markers, frames, truth, lit


def _identity(data, params=None):
    rig, markers, frames, truth, lit = data
    tr = BlinkTracker(markers, FPS, params=params, camera=rig.robot("p").camera)
    return light_identity([tr.update(img, k / FPS) for k, img in enumerate(frames)], truth, lit, FPS)


@pytest.mark.slow
def test_light_first_seen_switching_off_is_followed_and_named(panning_view):
    rig, markers, frames, truth, lit = panning_view
    total = sum(1 for k in range(int(FPS), N) if lit[k]["M1"] and "M1" in truth[k])
    assert total >= 10  # the sequence does show the case
    r = _identity(panning_view)
    missed = sum(1 for f in r.failures if f[1] == "M1")
    # Named within 3 px in all but a few of its lit frames after the first
    # second (before: none until frame 49), never a wrong name.
    assert missed <= 2, r.failures
    assert r.wrong == 0
    # The mechanism: without the velocity at birth the light is named late.
    r0 = _identity(panning_view, BlinkParams(birth_motion=False))
    assert sum(1 for f in r0.failures if f[1] == "M1") >= missed + 8
