"""Light names that the blink alone supports, on mutloc's own rendered
sequences (rooms with posters and clutter), against the renderer's true
light pixels and states.

1. A stray track -- born on clutter, its motion model fitted to a couple of
   centres -- coasts over the background at hundreds of px/s while "off"; the
   brightness it samples there can fit a light's blink by chance.  Named then,
   it put a "predicted" report of q's light M1 470-506 px from the light
   (trust sequence seed 8, p's view, frames 20-22).  A name taken while the
   track coasts is now reported only once its light is measured lit at it.
"""

from __future__ import annotations

import numpy as np
import pytest

from mutloc.detect.blink import BlinkTracker
from mutloc.detect.blink.params import BlinkParams
from mutloc.sim.render import moving_world
from mutloc.sim.tracking import light_identity, light_view
from mutloc.sim.world import standard_rig

FPS = 30.0


def _frames(rig, world, observer: str, other: str, n: int, seed0: int):
    markers = rig.robot(other).markers
    return (markers, *light_view(world, observer, list(markers), n, FPS, seed0))


def _run(rig, observer, data, params):
    markers, frames, truth, lit = data
    tr = BlinkTracker(markers, FPS, params=params, camera=rig.robot(observer).camera)
    return [tr.update(img, k / FPS) for k, img in enumerate(frames)]


def _worst_report(results, truth) -> float:
    """Largest distance (px) of any report from its own light's true pixel."""
    worst = 0.0
    for res, tru in zip(results, truth):
        for name, det in res.detections.items():
            if name in tru:
                worst = max(worst, float(np.hypot(*(det.uv - np.asarray(tru[name])))))
    return worst


@pytest.fixture(scope="module")
def coasting_stray():
    """Robot p's first 21 frames of q's lights (trust sequence seed 8, as
    bench/trust_sequences.py renders it)."""
    rig = standard_rig("lights")
    world = moving_world(rig, distance=2.0, seed=8)
    return rig, _frames(rig, world, "p", "q", 21, 8)


@pytest.mark.slow
def test_a_stray_named_while_coasting_is_not_reported(coasting_stray):
    rig, data = coasting_stray
    truth = data[2]
    # In the brightness channel, where the stray arises (in its own colour's
    # image the light has no such stray): and by default too.
    assert _worst_report(_run(rig, "p", data, BlinkParams()), truth) < 10.0
    # (A stray seen lit so rarely is not named at all now, min_lit_fraction:
    # that check is off here to show this one.)
    without = _run(rig, "p", data, BlinkParams(by_colour=False, confirm_lit=False, min_lit_fraction=0.0))
    with_ = _run(rig, "p", data, BlinkParams(by_colour=False, min_lit_fraction=0.0))
    # The failure exists: a report hundreds of px off (measured 470 px).
    assert _worst_report(without, truth) > 100.0
    # With the check every report lies near its own light (the lights
    # barely move here; measured: under 3 px).
    assert _worst_report(with_, truth) < 10.0
    # Nothing named right is lost, no wrong label added.
    lit = data[3]
    a, b = light_identity(with_, truth, lit, FPS), light_identity(without, truth, lit, FPS)
    assert a.good >= b.good and a.wrong <= b.wrong
