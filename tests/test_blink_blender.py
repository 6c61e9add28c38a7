"""The light tracker on lights rendered by a renderer it was not tuned on: Blender's Cycles (issue 28).

``tests/data/blender_lights/`` holds crops of scenes of
``bench/make_blender_lights.py``: mutloc's standard light rig (2 cm emissive
spheres, robots 2-3 m apart, 960x540, f = 800 px), each light on a mounting
rod -- polished metal (``metal_*``: Cycles reflects the lit light in the rod,
a clipped streak joined to the light's clipped disc) or matte (``matte_*``) --
path-traced and denoised, with no lens glow.  Per light, the frame with it lit
and the frame with it dark, cropped around it; the truth is the projection of
the light's centre.  A sequence is composed from the two by the light's blink
(fresh noise per frame) and run through the tracker with the crop's camera.

The bound is what the tracker achieved on these crops when the test was
written (largest error over every lit frame, with a margin); a worse centre
fails.  Without the centre from the clipped core's edge (the fallback where a
light has no halo) the metal crops are measured along the rod, beyond it.
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
    assert len(errs) >= 6 and None not in errs, errs
    assert max(errs) <= BOUND_PX, f"{CASES[key]['finish']} rod: {max(errs):.3f} px > {BOUND_PX} px"


def test_a_polished_rod_drags_the_centroid_without_the_edge_fit(monkeypatch):
    """The bound discriminates: measured by its clipped core's centroid (as before the edge fit), every
    light on a polished rod is off by more than the bound in every lit frame (0.39-1.1 px when written,
    down the rod), while the matte control stays within 0.3 px (0.23 px when written)."""
    monkeypatch.setattr(measure, "EDGE_FALLBACK", False)
    for key, c in sorted(CASES.items()):
        errs = _errors(key)
        assert None not in errs, key
        if c["finish"] == "metal":
            assert min(errs) > 0.3 > BOUND_PX, (key, min(errs))
        else:
            assert max(errs) <= 0.3, (key, max(errs))


def test_blender_light_subset_covers_every_colour_on_both_mounts():
    seen = {(c["finish"], c["marker"]) for c in CASES.values()}
    assert seen == {(f, m) for f in ("metal", "matte") for m in ("M1", "M2", "M3", "M4")}, seen

