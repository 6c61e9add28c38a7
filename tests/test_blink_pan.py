"""Which candidate continues which light track, on bench/blink_identity.py's
fast sequences (q pans +-15 degrees while p drives a 4 s path; rooms with
posters and clutter), against the renderer's true light pixels and states.

In a colour's own image a red light's body is red whether the light is lit
or not, so a light moving against the pan leaves a change to dark where it
was (its trail) beside the switch on where it is; and tracks born on such
changes sit where they were born until the light passes them.

1. A light off cannot switch off: a track whose light was off (or a young one
   lit in the last frame) prefers a switch on in its gate to a change to dark.
   Without that (and without rule 4), 2 m seed 7's red light started a new
   track at every frame for a second and was named only 0.6 s late.
2. A switch on in the gate of an identified light whose blink says "on" is
   that light's before it is an unidentified track's without a motion model
   (2 m seed 2: a change to dark left where it was born took the light;
   the name was reported at a prediction 17-35 px behind).
3. When two tracks find the same lit spot, one without a motion model yields
   (1.5 m seed 2: a track born on the light's body while the light was off).
4. A light's spot taken by a track never lit before (born on a change to
   dark beside the light's path) goes to the unidentified track that lost
   the light there, if that one's motion predicted it within 1.5 gates
   (1.5 m seed 21: the light reversing at the end of its path switched on
   15.6 px from the prediction, just outside the 15 px gate; the newcomer,
   its history sampled where the light was not, was named 0.8 s late).
5. A light lit in the last frame is not recentred on a change beside it
   (nor, without a halo, measured onto it: ``measure.EDGE_FALLBACK``).
6. A light's body is not taken for the lit light on the last frame of an
   off half (``BlinkParams.expect_off``).
"""

from __future__ import annotations

import pytest
from _shared_inputs import shared

from mutloc.detect.blink import BlinkParams, BlinkTracker, association, inherit, measure
from mutloc.detect.blink import tracker as light_tracker
from mutloc.sim.tracking import light_identity, panning_lights

FPS = 30.0


# 2 m seed 7 is watched by the first rule's case (50 frames) and by the red light's test (80): its 80
# frames are rendered once per run and the case takes the first 50.  Frame k depends on k alone (rendered at
# t = k / FPS with noise seed 7000 + k), so those are the frames panning_lights(2.0, 7, 50) renders.
LONGEST = {(2.0, 7): 80}


def _pan(tmp_path_factory, distance: float, seed: int, n: int):
    """``panning_lights(distance, seed, n, FPS, vary=True)``; a sequence in LONGEST is rendered once per run."""
    m = LONGEST.get((distance, seed), 0)
    if m < n:  # watched by this test alone
        return panning_lights(distance, seed, n, FPS, vary=True)
    rig, markers, _, _, _ = panning_lights(distance, seed, 0, FPS, vary=True)  # renders nothing
    frames, truth, lit = shared(  # the images and their truth (a rig does not pickle)
        tmp_path_factory, f"panning_lights-d{distance}-s{seed}-n{m}-fps{FPS}-vary",
        lambda: panning_lights(distance, seed, m, FPS, vary=True)[2:])
    return rig, markers, frames[:n], truth[:n], lit[:n]


def _identity(data):
    rig, markers, frames, truth, lit = data
    tr = BlinkTracker(markers, FPS, camera=rig.robot("q").camera)
    return light_identity([tr.update(img, k / FPS) for k, img in enumerate(frames)], truth, lit, FPS)


# (distance m, seed, frames, lit frames counted at least, the rules'
# constants and the values that turn them off, lit frames of M3 lost
# without them at least)
CASES = {
    # 1: the change to dark where the light was is its trail (since rule 4,
    # which hands the light back from the tracks born on the trail, either
    # rule alone keeps it)
    "light_against_the_pan": (2.0, 7, 50, 15, [(association, "UNLIKELY_PX", 0.0),
                                               (inherit, "HAND_OVER_GATES", 0.0)], 5),
    # 2: an identified light due on takes its switch from a track without motion
    "light_due_on": (2.0, 2, 90, 50, [(association, "UNLIKELY_PX", 0.0)], 3),
    # 3: a track without motion yields a spot it shares (claimed as any
    # unidentified track would be: its distance plus gate_px)
    "shared_spot": (1.5, 2, 80, 45, [(light_tracker, "UNMODELLED_CLAIM_PX", 6.0)], 3),
    # 4: a lost light's spot taken by a newcomer is handed back
    "lost_light_handed_over": (1.5, 21, 44, 12, [(inherit, "HAND_OVER_GATES", 0.0)], 5),
}


@pytest.mark.slow
@pytest.mark.parametrize("case", list(CASES))
def test_each_rule_keeps_the_light(case, monkeypatch, tmp_path_factory):
    distance, seed, n, counted, ablations, lost = CASES[case]
    data = _pan(tmp_path_factory, distance, seed, n)
    r = _identity(data)
    assert r.total >= counted and r.failures == [] and r.wrong == 0, r.failures
    for module, name, off in ablations:
        monkeypatch.setattr(module, name, off)
    without = _identity(data)
    assert sum(1 for f in without.failures if f[1] == "M3") >= lost, without.failures


@pytest.mark.slow
def test_a_lit_light_is_not_recentred_on_a_change_beside_it(monkeypatch):
    """Trust sequence seed 41, p's view of q's M2 at 2 m, the posters' words
    left out (OpenCV 5.1 draws them with other glyphs than 5.0, and seed 63's
    case -- M1 recentred on a change to bright 6-7 px beside it while lit,
    its motion fitted to that running 36 px off -- went with 5.0's glyphs).
    A light lit in the last frame, with a motion model, is looked for at its
    prediction, and where it has no halo is measured by its clipped core's
    edge (``measure.EDGE_FALLBACK``); either rule alone keeps it, so both are
    taken away.  Without them M2 lost 5 lit frames here (found by a search
    over seeds 2-46; the frames were not re-inspected for the mechanism)."""
    import dataclasses

    from mutloc.sim.tracking import light_view, varied_world
    from mutloc.sim.world import standard_rig

    rig, world = varied_world(standard_rig("lights"), 41, distance=2.0)
    world = dataclasses.replace(world, room=dataclasses.replace(world.room, poster_text=False))
    markers = rig.robot("q").markers
    frames, truth, lit = light_view(world, "p", list(markers), 60, FPS, 41)

    def identity():
        tr = BlinkTracker(markers, FPS, camera=rig.robot("p").camera)
        return light_identity([tr.update(img, k / FPS) for k, img in enumerate(frames)], truth, lit, FPS)

    r = identity()
    assert r.total >= 25 and r.failures == [] and r.wrong == 0, r.failures
    monkeypatch.setattr(light_tracker, "LIT_KEEPS_PREDICTION", False)
    monkeypatch.setattr(measure, "EDGE_FALLBACK", False)
    without = identity()
    assert sum(1 for f in without.failures if f[1] == "M2") >= 5, without.failures


@pytest.mark.slow
def test_a_red_light_off_is_not_taken_for_lit_on_its_last_off_frame(tmp_path_factory):
    """2 m seed 7 (bench/blink_identity.py): p's red M3 at 5 Hz is off three
    frames of six, the first and last at exactly -0.5 of its fitted blink;
    its body, red in its own colour's image whether lit or not, was taken for
    the lit light 12.6 px off at the last one (a wrong label) with the veto
    at -0.5; at -0.45 every off frame is vetoed and no lit frame."""
    data = _pan(tmp_path_factory, 2.0, 7, 80)
    assert BlinkParams().expect_off == 0.45
    r = _identity(data)
    assert r.wrong == 0 and r.failures == [], r.failures
    rig, markers, frames, truth, lit = data
    tr = BlinkTracker(markers, FPS, camera=rig.robot("q").camera, params=BlinkParams(expect_off=0.5))
    without = light_identity([tr.update(img, k / FPS) for k, img in enumerate(frames)], truth, lit, FPS)
    assert without.wrong >= 1
