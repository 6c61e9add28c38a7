"""The light tracker on lights rendered by a renderer it was not tuned on: Blender's Cycles (issue 28).

``tests/data/blender_lights/`` holds crops of scenes of
``bench/make_blender_lights.py``: mutloc's standard light rig (2 cm emissive
spheres, robots 2-3 m apart, 960x540, f = 800 px), each light on a mounting
rod -- polished metal (``metal_*``: Cycles reflects the lit light in the rod,
a clipped streak joined to the light's clipped disc) or matte (``matte_*``) --
path-traced and denoised, with no lens glow; and the polished rods again with
a camera's glow (``glow_*``: Blender's compositor blooms the light and its
reflection in the rod alike).  Per light, the frame with it lit
and the frame with it dark, cropped around it; the truth is the projection of
the light's centre.  A sequence is composed from the two by the light's blink
(fresh noise per frame) and run through the tracker with the crop's camera.

The bound is what the tracker achieved on these crops when the test was
written (largest error over every lit frame, with a margin); a worse centre
fails.  Without the centre from the clipped core's edge (the fallback where a
light has no halo) the metal crops are measured along the rod, beyond it; and
without that edge where the glowing light's clipped core has a streak
(``measure.reflection_streak``), the glow crops are measured by their halo,
which the streak's own glow pulls down the rod.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import cv2
import numpy as np
import pytest

from mutloc.core.camera import Camera
from mutloc.detect.blink import BlinkParams, BlinkTracker, measure
from mutloc.sim.world import light_is_on, standard_rig

DATA = Path(__file__).parent / "data" / "blender_lights"
CASES = json.loads((DATA / "truth.json").read_text())
FPS = 30.0
# A 960x540 frame's limit on a light's spread (3 % of the short side), which a crop would lower to 6 px.
PARAMS = BlinkParams(max_blob_std=0.03 * 540)
FRAMES = 45
# Largest error (px) over every lit frame after the first second, measured when written: 0.147 px
# (metal_00_q_M4; the largest on a matte rod 0.143 px), with a margin.
BOUND_PX = 0.2
# The same with a glow: 0.341 px (glow_02_q_M4, whose streak is too short to be told: the halo
# measures it, as it does without the streak rule), with a margin.
GLOW_BOUND_PX = 0.4


def _errors(key: str) -> list[float | None]:
    """The tracker's centre error (px) in every lit frame after the first second (None: not measured)."""
    c = CASES[key]
    imgs = {tag: cv2.imread(str(DATA / f"{key}_{tag}.png"), cv2.IMREAD_COLOR) for tag in ("on", "off")}
    assert all(im is not None and (im.shape[1], im.shape[0]) == tuple(c["size"]) for im in imgs.values())
    cam = Camera(np.array(c["K"]), [0.0] * 5, tuple(c["size"]))
    other = "q" if c["observer"] == "p" else "p"
    m = c["marker"]
    marker = standard_rig("lights").robot(other).markers[m]
    tracker = BlinkTracker({m: marker}, FPS, camera=cam, params=PARAMS)
    rng = np.random.default_rng(sum(map(ord, key)))
    out: list[float | None] = []
    for k in range(FRAMES):
        on = light_is_on(marker, k / FPS)
        img = imgs["on" if on else "off"].astype(np.float32) + rng.normal(0.0, 1.0, imgs["on"].shape)
        res = tracker.update(np.clip(np.rint(img), 0, 255).astype(np.uint8), k / FPS)
        if k < FPS or not on:
            continue
        d = res.detections.get(m)
        out.append(None if d is None or d.predicted else math.hypot(d.uv[0] - c["light"]["u"],
                                                                   d.uv[1] - c["light"]["v"]))
    return out


@pytest.mark.parametrize("key", sorted(CASES))
def test_blender_light_centres_within_the_measured_bound(key):
    errs = _errors(key)
    bound = GLOW_BOUND_PX if CASES[key]["finish"] == "glow" else BOUND_PX
    assert len(errs) >= 6 and None not in errs, errs
    assert max(errs) <= bound, f"{CASES[key]['finish']} rod: {max(errs):.3f} px > {bound} px"


def test_a_glowing_light_s_streak_would_pull_its_halo_down_the_rod(monkeypatch):
    """The streak rule discriminates: of the 12 glowing lights on polished rods, 9 are within 0.2 px in
    every lit frame measured by their core's edge and off by more than 0.2 px in every lit frame when the
    streak is not told (halo fit; 0.21-0.49 px when written, down the rod)."""
    glow = sorted(k for k, c in CASES.items() if c["finish"] == "glow")
    assert len(glow) == 12
    with_rule = {k: _errors(k) for k in glow}
    monkeypatch.setattr(measure, "reflection_streak", lambda *a: False)
    told = 0
    for k in glow:
        without = _errors(k)
        assert None not in with_rule[k] and None not in without, k
        told += max(with_rule[k]) <= 0.2 < min(without)
    assert told >= 8, told


def test_a_polished_rod_drags_the_centroid_without_the_edge_fit(monkeypatch):
    """The bound discriminates: measured by its clipped core's centroid (as before the edge fit), every
    light on a polished rod is off by more than the bound in every lit frame (0.39-1.1 px when written,
    down the rod), while the matte control stays within 0.3 px (0.23 px when written).  (The glowing
    lights have a halo: see the next test.)"""
    monkeypatch.setattr(measure, "EDGE_FALLBACK", False)
    for key, c in sorted(CASES.items()):
        if c["finish"] == "glow":
            continue
        errs = _errors(key)
        assert None not in errs, key
        if c["finish"] == "metal":
            assert min(errs) > 0.3 > BOUND_PX, (key, min(errs))
        else:
            assert max(errs) <= 0.3, (key, max(errs))


def test_blender_light_subset_covers_every_colour_on_both_mounts():
    seen = {(c["finish"], c["marker"]) for c in CASES.values()}
    assert seen == {(f, m) for f in ("metal", "matte", "glow") for m in ("M1", "M2", "M3", "M4")}, seen

