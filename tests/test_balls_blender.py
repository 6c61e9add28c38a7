"""The ball detector on frames from a renderer it was not tuned on: Blender's Cycles (issue 28).

``tests/data/blender/`` holds crops of scenes of ``bench/make_blender_set.py``
(mutloc's standard two-ball rig, robots 2-3 m apart, 960x540, f = 800 px):
path-traced with soft and hard shadows, bounce light, glossy highlights,
reflective mounts, a pixel filter and a denoiser, plus 1 grey level of
sensor noise.  Their truth is geometry: the projection of each sphere's
centre, and the share of its disc other objects hide (rays against the same
primitives).  Each crop keeps the observed robot's two balls; its
intrinsics are the camera's with the principal point moved by the crop's
corner, so the detector's perspective correction is the full frame's.

The bounds are what the detector achieved on these crops when the test was
written (largest error, ``bench/bench_balls_blender.py`` measures the
whole set) with a margin; a worse centre fails.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import cv2
import numpy as np
import pytest

from mutloc.core.camera import Camera
from mutloc.detect.balls import BallParams, detect_balls
from mutloc.sim.world import standard_rig

DATA = Path(__file__).parent / "data" / "blender"
CASES = json.loads((DATA / "truth.json").read_text())
# Balls less than this share hidden count as whole.
WHOLE = 0.05
# Bounds (px) on the first look's centre error, measured when written: whole balls at most 0.22 px
# (backlit_01_q M4), partly hidden ones (37-58 %) at most 0.43 px (pole_00_p M2); with a margin.
WHOLE_PX = 0.35
HIDDEN_PX = 0.6
# Crops where the first look fails today (issue 28), kept so a failure stays visible: a strict
# xfail turns red the day the detector gets them right, and the bounds above must then cover them.
# None now: box_01_p (M1 70 % hidden by a box edge, a flat poster disc taken for it) and pole_01_p
# (M1 36 % hidden, merged with a speckled bluish poster) are found by the rig's guided look
# (mutloc.detect.balls.guided).
FAILING: dict[str, str] = {}


def _detect(key: str, params: BallParams | None = None):
    c = CASES[key]
    img = cv2.imread(str(DATA / f"{key}.png"), cv2.IMREAD_COLOR)
    assert img is not None and (img.shape[1], img.shape[0]) == tuple(c["size"])
    cam = Camera(np.array(c["K"]), [0.0] * 5, tuple(c["size"]))
    other = "q" if c["observer"] == "p" else "p"
    return detect_balls(img, standard_rig("balls").robot(other).markers, camera=cam, params=params), c


@pytest.mark.parametrize("key", [pytest.param(k, marks=pytest.mark.xfail(strict=True, reason=FAILING[k]))
                                 if k in FAILING else k for k in sorted(CASES)])
def test_blender_ball_centres_within_the_measured_bound(key):
    res, c = _detect(key)
    for m, b in c["balls"].items():
        d = res.detections.get(m)
        assert d is not None, (m, res.missing_reasons.get(m))
        err = math.hypot(d.uv[0] - b["u"], d.uv[1] - b["v"])
        bound = WHOLE_PX if b["hidden"] < WHOLE else HIDDEN_PX
        assert err <= bound, f"{m} ({100 * b['hidden']:.0f}% hidden) off by {err:.3f} px > {bound} px"


def test_whole_balls_narrower_colour_window_measures_better_centres():
    """A whole ball's second round of rays takes its colours nearer the edge (``whole_rim_half_window_px``):
    over the crops' whole balls the centres are better than with the partly hidden balls' wider window
    (median 0.079 against 0.089 px when written)."""
    errs: dict[str, list[float]] = {"narrow": [], "wide": []}
    wide = BallParams(whole_rim_half_window_px=BallParams().local_half_window_px)
    for key in sorted(CASES):
        for what, params in (("narrow", None), ("wide", wide)):
            res, c = _detect(key, params)
            errs[what] += [math.hypot(d.uv[0] - b["u"], d.uv[1] - b["v"]) for m, b in c["balls"].items()
                           if b["hidden"] < WHOLE and (d := res.detections.get(m)) is not None]
    assert len(errs["narrow"]) == len(errs["wide"]) >= 24
    narrow, wide_ = np.median(errs["narrow"]), np.median(errs["wide"])
    assert narrow <= 0.95 * wide_, (narrow, wide_)


def test_blender_subset_covers_hidden_balls_and_every_light():
    """The subset is what the bounds claim: partly hidden balls (30-70 %) and each light condition."""
    hidden = [b["hidden"] for c in CASES.values() for b in c["balls"].values() if b["hidden"] >= WHOLE]
    assert len(hidden) >= 2 and all(0.25 <= h <= 0.75 for h in hidden), hidden
    assert {"hard", "dim", "warm", "backlit", "mounts"} <= {c["condition"] for c in CASES.values()}


def test_blender_hidden_ball_reports_less_visible_rim():
    """A partly hidden ball's reported visible fraction is below a whole ball's in the same crop."""
    seen = 0
    for key, c in CASES.items():
        hid = [m for m, b in c["balls"].items() if b["hidden"] >= 0.3]
        whole = [m for m, b in c["balls"].items() if b["hidden"] < WHOLE]
        if not hid or not whole:
            continue
        res, _ = _detect(key)
        if key in FAILING:
            continue
        assert res.detections[hid[0]].visible_fraction < res.detections[whole[0]].visible_fraction, key
        seen += 1
    assert seen >= 4


def test_scene_spec_draws_the_world_s_own_geometry(tmp_path, monkeypatch):
    """The spec Blender renders holds the world's balls where the world has them, its props, and each
    view's camera as the rig's (no bpy needed); without bpy, rendering is a one-line MissingExtraError."""
    from mutloc.errors import InputError, MissingExtraError
    from mutloc.sim.blender import blender_python, scene_spec
    from mutloc.sim.render import two_robot_world
    from mutloc.sim.scenes import occluder, with_props
    from mutloc.sim.synthetic import facing_pose

    rig = standard_rig("balls")
    w = two_robot_world(rig, facing_pose(2.5), seed=1)
    w = with_props(w, occluder(w, "q", "M3", 0.5, "pole"))
    spec = scene_spec(w, {"q": tmp_path / "q.png"}, texture_dir=tmp_path / "tex", metal=[0])
    balls = {o["name"]: o for o in spec["objects"] if o["kind"] == "sphere"}
    assert set(balls) == {"M1", "M2", "M3", "M4"}
    for rname in ("p", "q"):
        for m in rig.robot(rname).markers.values():
            assert np.allclose(balls[m.name]["centre"], w.pose(rname).apply(m.position), atol=1e-12)
            assert balls[m.name]["radius"] == pytest.approx(0.03) and balls[m.name]["finish"] == "matte"
    metal = [o for o in spec["objects"] if o.get("finish") == "metal"]
    assert len(metal) == 1 and metal[0]["kind"] == "cylinder"
    (view,) = spec["views"]
    assert np.allclose(view["K"], rig.robot("q").camera.K) and np.allclose(view["t"], w.pose("q").t)
    assert sum(o.get("texture") is not None for o in spec["objects"]) == 6  # the room's six surfaces
    assert "glare" not in spec["render"]  # Cycles draws no glow unless asked
    glow = scene_spec(w, {"q": tmp_path / "q.png"}, texture_dir=tmp_path / "tex", glare={"strength": 3})
    assert glow["render"]["glare"] == {"threshold": 0.5, "size": 0.6, "strength": 3.0}
    for bad in ({"size": 2.0}, {"strength": -1.0}, {"threshold": float("nan")}, {"radius": 3.0}, {"size": "big"}, 3):
        with pytest.raises(InputError, match="glare"):
            scene_spec(w, {"q": tmp_path / "q.png"}, texture_dir=tmp_path / "tex", glare=bad)
    monkeypatch.delenv("MUTLOC_BLENDER_PYTHON", raising=False)
    import importlib.util

    if importlib.util.find_spec("bpy") is None:
        with pytest.raises(MissingExtraError, match="render extra"):
            blender_python()


def test_a_poster_disc_that_outscores_a_ball_is_not_taken_for_it():
    """Scene warm_00 of the set, from mutloc's own renderer: a green poster disc, larger and rounder
    than the green ball M4, scored above it and passed the rig check at its loose range allowance
    (0.7 allowed errors), so the ball, smaller than that early good fit, was never refined (186 px
    off on both renderers).  A chosen pair off the rig by more than ``recheck_pair_error`` now has the
    passed-over blobs refined and the choice made again."""
    from mutloc.detect.balls import BallParams
    from mutloc.sim.render import project_markers, render, two_robot_world
    from mutloc.sim.scenes import lit
    from mutloc.sim.synthetic import facing_pose

    rig = standard_rig("balls")
    rng = np.random.default_rng([2811, 4, 0])  # bench/make_blender_set.py's draws for warm_00
    d = rng.uniform(2.0, 3.0)
    T = facing_pose(d, np.radians(rng.uniform(-10, 10)), np.radians(rng.uniform(-10, 10)),
                    rng.uniform(-0.15, 0.15) * d)
    w = lit(two_robot_world(rig, T, seed=740), "warm", observer="q", target="p", seed=0)
    img = render(w, "q", seed=4000, noise_sigma=1.0)
    truth = project_markers(w, "q")
    cam = rig.robot("q").camera
    res = detect_balls(img, rig.robot("p").markers, camera=cam)
    for m in ("M3", "M4"):
        assert math.dist(res.detections[m].uv, truth[m]) < 0.2, (m, res.detections[m].uv, truth[m])
    # Without the second round of choice the disc is taken: the scene still tests what it claims.
    off = detect_balls(img, rig.robot("p").markers, camera=cam, params=BallParams(recheck_pair_error=1e9))
    assert math.dist(off.detections["M4"].uv, truth["M4"]) > 50


def test_a_cut_ball_whose_size_is_off_its_mate_s_is_fitted_again_from_its_visible_outline():
    """pole_00_q: M3, 60 % behind a diagonal cable, was first fitted with part of the cable's edge
    as rim (radius 8.9 px against its whole mate's 10.2 px, centre 1.6 px off); the circle of its
    visible outline now competes with that fit and wins."""
    from mutloc.detect.balls import BallParams

    c = CASES["pole_00_q"]
    img = cv2.imread(str(DATA / "pole_00_q.png"), cv2.IMREAD_COLOR)
    cam = Camera(np.array(c["K"]), [0.0] * 5, tuple(c["size"]))
    b = c["balls"]["M3"]
    errs = []
    for tol in (BallParams().cut_size_tolerance, 1e9):
        res = detect_balls(img, standard_rig("balls").robot("p").markers, camera=cam,
                           params=BallParams(cut_size_tolerance=tol))
        errs.append(math.hypot(res.detections["M3"].uv[0] - b["u"], res.detections["M3"].uv[1] - b["v"]))
    assert errs[0] <= HIDDEN_PX < 1.0 < errs[1], errs
