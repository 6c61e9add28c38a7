"""The second look at partly hidden balls (issue 12): a ball's rim fitted
with the size a pose predicts (mutloc.detect.balls.refit) and the pose
solved again from it (mutloc.track.second_look), against synthetic cones
and rendered scenes with their true poses."""

from __future__ import annotations

import math

import numpy as np
import pytest

from mutloc.core.geometry import so3_exp
from mutloc.detect.balls.fit import cone_fit
from mutloc.detect.balls.refit import RefitContext, apparent_radius_px, balls_near, fixed_cone_fit, refit_ball
from mutloc.detect.base import Detection, DetectionResult
from mutloc.sim.render import ball_visibility, project_markers, relative_pose, render, two_robot_world
from mutloc.sim.scenes import OCCLUDERS, occluder, with_props
from mutloc.sim.synthetic import facing_pose
from mutloc.sim.world import standard_rig
from mutloc.track.frames import detect_markers, expanded_rig, observations_of
from mutloc.track.second_look import ball_centres, needs_second_look, second_look

RIG = standard_rig("balls")
F = 800.0


def _cone(d: np.ndarray, alpha: float, phi: np.ndarray) -> np.ndarray:
    a = np.array([1.0, 0.0, 0.0])
    e1 = np.cross(d, a)
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(d, e1)
    return (math.cos(alpha) * d + math.sin(alpha) * (np.cos(phi)[:, None] * e1 + np.sin(phi)[:, None] * e2))


def _noisy_arc(rng, d, alpha, arc, n=40, noise_px=0.1):
    """Bearings on ``arc`` radians of the cone, each pushed off it radially by noise_px pixels."""
    phi = rng.uniform(0, 2 * np.pi) + np.linspace(0, arc, n)
    alphas = alpha + rng.normal(0, noise_px / F, n)
    b = np.array([_cone(d, a, np.array([p]))[0] for a, p in zip(alphas, phi)])
    return b


def test_fixed_cone_fit_recovers_the_axis_and_ignores_an_occluders_edge():
    rng = np.random.default_rng(0)
    d = np.array([0.2, -0.1, 1.0])
    d /= np.linalg.norm(d)
    alpha = 12.0 / F
    b = _noisy_arc(rng, d, alpha, 0.45 * 2 * np.pi, noise_px=0.0)
    # An occluder's straight edge: points well inside the cone.
    edge = _cone(d, 0.4 * alpha, np.linspace(0.5, 2.0, 12))
    bear = np.vstack([b, edge])
    ok = np.ones(len(bear), bool)
    d0 = d + np.array([2.0, -1.0, 0.0]) / F  # two pixels off
    out = fixed_cone_fit(bear, ok, ok.copy(), d0 / np.linalg.norm(d0), math.cos(alpha), F)
    assert out is not None
    axis, w, rms = out
    assert math.acos(min(1.0, float(axis @ d))) * F < 1e-6  # pixels
    assert np.all(w[len(b):] == 0.0) and np.all(w[: len(b)] > 0.9)
    assert rms < 1e-6


def test_a_known_size_pins_a_short_arc_down_better_than_a_free_fit():
    """The reason for the second look: on 30-50 % of a rim with 0.1 px of
    noise, the free cone's axis slides with its size; the fixed one does not."""
    rng = np.random.default_rng(1)
    free, fixed = [], []
    for _ in range(60):
        d = so3_exp(rng.normal(0, 0.2, 3)) @ np.array([0.0, 0.0, 1.0])
        alpha = rng.uniform(6, 15) / F
        bear = _noisy_arc(rng, d, alpha, rng.uniform(0.3, 0.5) * 2 * np.pi)
        ok = np.ones(len(bear), bool)
        a, w = np.empty(3), np.empty(len(bear))
        good, _, _ = cone_fit(bear, ok, ok.copy(), F, a, w)
        assert good
        free.append(math.acos(min(1.0, float(a @ d))) * F)
        axis, _, _ = fixed_cone_fit(bear, ok, ok.copy(), d, math.cos(alpha), F)
        fixed.append(math.acos(min(1.0, float(axis @ d))) * F)
    assert np.median(fixed) < 0.5 * np.median(free), (np.median(fixed), np.median(free))
    assert np.median(fixed) < 0.05


def _scene(i: int, share: float, kind: str):
    rng = np.random.default_rng(300 + i)
    d = rng.uniform(1.2, 3.0)
    T = facing_pose(d, np.radians(rng.uniform(-8, 8)), np.radians(rng.uniform(-8, 8)), rng.uniform(-0.1, 0.1) * d)
    w = two_robot_world(RIG, T, seed=200 + i)
    return with_props(w, occluder(w, "q", "M3", share, kind, side=rng.choice([-1, 1])))


def _truth_centre(world, observer: str, marker: str) -> np.ndarray:
    owner = next(r for r in ("p", "q") if marker in RIG.robot(r).markers)
    T = world.pose(observer).inverse() @ world.pose(owner)
    return T.apply(RIG.robot(owner).markers[marker].position)


@pytest.mark.parametrize("kind", ["pole", "cable", "box"])
def test_refit_measures_a_partly_hidden_ball_where_its_true_centre_puts_it(kind):
    errs = []
    for i in range(3):
        w = _scene(i, 0.5, kind)
        img = render(w, "q", seed=i, noise_sigma=1.0)
        ctx = RefitContext.of(img, RIG.robot("q").camera)
        X = _truth_centre(w, "q", "M3")
        det = refit_ball(ctx, "M3", RIG.robot("p").markers["M3"], X, radius_offset_px=-0.065)
        assert det is not None and det.info["refit"]
        errs.append(float(np.linalg.norm(det.uv - project_markers(w, "q")["M3"])))
        # The visible fraction follows the truth.
        assert abs(det.visible_fraction - ball_visibility(w, "q", "M3")) < 0.2
        # Where no ball of its colour is (a ball's width to the side), nothing is measured.
        side = X + np.array([2.5 * 0.03, 0.0, 0.0])
        assert refit_ball(ctx, "M3", RIG.robot("p").markers["M3"], side) is None
        # Nor is the other ball of another colour taken for it.
        assert refit_ball(ctx, "M3", RIG.robot("p").markers["M3"], _truth_centre(w, "q", "M4")) is None
    assert np.median(errs) < 0.15 and max(errs) < 0.4, errs


def test_the_rim_size_prior_moves_a_half_arc_towards_its_true_centre():
    """The second look's prior for the rim's size bias (-0.065 px in ordinary light): a partly hidden ball
    refitted at its rendered centre lands nearer its rendered pixel with it than with no offset."""
    with_prior, without = [], []
    for i, kind in enumerate(["pole", "cable", "box"] * 2):
        w = _scene(10 + i, 0.5, kind)
        ctx = RefitContext.of(render(w, "q", seed=i, noise_sigma=1.0), RIG.robot("q").camera)
        X, truth = _truth_centre(w, "q", "M3"), project_markers(w, "q")["M3"]
        for off, out in ((-0.065, with_prior), (0.0, without)):
            det = refit_ball(ctx, "M3", RIG.robot("p").markers["M3"], X, radius_offset_px=off)
            assert det is not None
            out.append(float(np.linalg.norm(det.uv - truth)))
    assert np.median(with_prior) < 0.7 * np.median(without), (with_prior, without)


def test_apparent_radius_is_the_rendered_size():
    w = _scene(0, 0.3, "pole")
    ctx = RefitContext.of(render(w, "q"), RIG.robot("q").camera)
    X = _truth_centre(w, "q", "M4")
    r = apparent_radius_px(ctx, "M4", RIG.robot("p").markers["M4"], X)
    # Small-angle image of a 3 cm ball: f R / z.
    assert r == pytest.approx(F * 0.03 / X[2], rel=0.02)


def test_second_look_brings_a_missing_ball_back_and_verifies_the_pose():
    """Three balls at their exact pixels and the partly hidden one missing
    (three observations: unverified); the second look finds it where the
    pose's candidates put it, and the pose is verified and accurate."""
    from mutloc.api import localize

    rig = expanded_rig(RIG)
    for i in range(3):
        w = _scene(i, 0.5, "box")
        imgs = {r: render(w, r, seed=i, noise_sigma=1.0) for r in ("p", "q")}
        dets = {obs: DetectionResult({m: Detection(m, np.array(uv), 1.0, visible_fraction=1.0)
                                      for m, uv in project_markers(w, obs).items()}) for obs in ("p", "q")}
        del dets["q"].detections["M3"]
        dets["q"].missing = ["M3"]
        est = localize(rig, observations_of(dets), "p", "q")
        assert est.status == "unverified"
        assert needs_second_look(rig, dets, "p", "q")
        out = second_look(rig, imgs, dets, est, None, "p", "q")
        assert out is not None
        res, new = out
        truth = relative_pose(w, "p", "q")
        assert res.status == "solved" and "M3" in res.markers_used
        m3 = new["q"].detections["M3"]
        assert m3.info.get("refit") and 0.3 <= m3.visible_fraction <= 0.75
        assert np.linalg.norm(m3.uv - project_markers(w, "q")["M3"]) < 0.4
        assert res.pose.translation_error(truth) < 0.005 and res.pose.rotation_error_deg(truth) < 0.1


def test_balls_near_measures_a_hidden_ball_within_the_rig_s_reach():
    """A half-hidden ball found among the blobs of its colour near its mate,
    sized for the mate's distance, at its true pixel; none out of reach."""
    for i, kind in enumerate(("pole", "box")):
        w = _scene(i, 0.5, kind)
        ctx = RefitContext.of(render(w, "q", seed=i, noise_sigma=1.0), RIG.robot("q").camera)
        truth = project_markers(w, "q")
        D = float(np.linalg.norm(_truth_centre(w, "q", "M4")))
        m3 = RIG.robot("p").markers["M3"]
        reach = [(truth["M4"], 0.3 / D * F * 1.25)]
        found = balls_near(ctx, "M3", m3, D, reach)
        assert found and all(d.info["refit"] for d in found)
        assert min(float(np.linalg.norm(d.uv - truth["M3"])) for d in found) < 0.5
        # Reach that does not come near the ball: nothing there is measured.
        far = truth["M4"] + np.array([0.0, 200.0])
        assert not any(float(np.linalg.norm(d.uv - truth["M3"])) < 5.0
                       for d in balls_near(ctx, "M3", m3, D, [(far, 10.0)]))


def _occluded_run(i: int):
    """A scene like tests/test_balls_real.py's ``occluded_runs`` (one ball of each robot 30-70 % hidden;
    its draws in another order: bench/balls_occluded.py --gen alt)."""
    from mutloc.sim.scenes import OCCLUDERS

    rng = np.random.default_rng(1000 + i)
    d = rng.uniform(1.2, 3.5)
    T = facing_pose(d, np.radians(rng.uniform(-10, 10)), np.radians(rng.uniform(-10, 10)),
                    rng.uniform(-0.15, 0.15) * d)
    w = two_robot_world(RIG, T, seed=i)
    props = [occluder(w, obs, str(rng.choice(ms)), rng.uniform(0.3, 0.7), OCCLUDERS[rng.integers(3)],
                      side=rng.choice([-1, 1])) for obs, ms in (("q", ["M3", "M4"]), ("p", ["M1", "M2"]))]
    return with_props(w, *props)


@pytest.mark.parametrize("i", [5, 11])
def test_second_look_solves_a_frame_with_one_ball_seen_from_each_side(i):
    """First looks that keep one ball on each side (no pose at all): the second look finds the others
    among the blobs of their colour near their whole mates, and the pose is verified and accurate.
    (The first look kept only the whole balls of these scenes until it looked for a robot's missing
    ball where the rig puts it (mutloc.detect.balls.guided); the partly hidden balls it finds now are
    taken out of it here.)"""
    from mutloc.errors import TooFewObservationsError
    from mutloc.track.second_look import PARTLY_HIDDEN
    from mutloc.track.tag_look import first_solve

    rig = expanded_rig(RIG)
    w = _occluded_run(i)
    imgs = {r: render(w, r, seed=i, noise_sigma=1.0) for r in ("p", "q")}
    dets = {o: detect_markers(rig, o, imgs[o], targets=[t]) for o, t in (("p", "q"), ("q", "p"))}
    for d in dets.values():
        for m in [m for m, x in d.detections.items() if x.visible_fraction < PARTLY_HIDDEN]:
            del d.detections[m]
            d.alternatives.pop(m, None)
            d.missing.append(m)
    assert all(len(d.detections) == 1 for d in dets.values())
    est, err = first_solve(rig, dets, "p", "q")
    assert est is None and isinstance(err, TooFewObservationsError)
    out = second_look(rig, imgs, dets, est, err, "p", "q")
    assert out is not None
    res, new = out
    truth = relative_pose(w, "p", "q")
    assert res.status == "solved" and len(res.markers_used) == 4
    for obs in ("p", "q"):
        for m, uv in project_markers(w, obs).items():
            assert np.linalg.norm(new[obs].detections[m].uv - uv) < 0.5
    assert res.pose.translation_error(truth) < 0.002 and res.pose.rotation_error_deg(truth) < 0.05


def test_a_fully_hidden_ball_stays_missing():
    from mutloc.api import localize

    rig = expanded_rig(RIG)
    w = _scene(1, 0.97, "box")
    assert ball_visibility(w, "q", "M3") < 0.1
    imgs = {r: render(w, r, seed=1, noise_sigma=1.0) for r in ("p", "q")}
    dets = {obs: DetectionResult({m: Detection(m, np.array(uv), 1.0, visible_fraction=1.0)
                                  for m, uv in project_markers(w, obs).items()}) for obs in ("p", "q")}
    del dets["q"].detections["M3"]
    dets["q"].missing = ["M3"]
    est = localize(rig, observations_of(dets), "p", "q")
    assert second_look(rig, imgs, dets, est, None, "p", "q") is None


def test_whole_balls_need_no_second_look():
    w = two_robot_world(RIG, facing_pose(2.0, 0.05, -0.05, 0.1), seed=3)
    imgs = {r: render(w, r, seed=1, noise_sigma=1.0) for r in ("p", "q")}
    rig = expanded_rig(RIG)
    dets = {"p": detect_markers(rig, "p", imgs["p"], targets=["q"]),
            "q": detect_markers(rig, "q", imgs["q"], targets=["p"])}
    assert not needs_second_look(rig, dets, "p", "q")
    assert second_look(rig, imgs, dets, None, None, "p", "q") is None
    # ball_centres puts each ball where the renderer does.
    truth = relative_pose(w, "p", "q")
    for obs, balls in ball_centres(rig, truth, "p", "q").items():
        proj = project_markers(w, obs)
        for name, X in balls.items():
            assert np.allclose(rig.robot(obs).camera.project(X), proj[name], atol=1e-6)


@pytest.mark.parametrize("filter", ["none", "cv"])
def test_track_uses_the_second_look(filter):
    """Frames whose first look is unsolved (a wrong blob for the partly
    hidden ball, or that ball missing) are solved, and accurate, in a track."""
    from mutloc.api import localize
    from mutloc.errors import MutlocError
    from mutloc.track.sources import Frame
    from mutloc.track.tracker import track

    rig = expanded_rig(RIG)
    for i in (0, 7):
        w = _scene(i, 0.5, "box")
        imgs = {r: render(w, r, seed=i, noise_sigma=1.0) for r in ("p", "q")}
        dets = {o: detect_markers(rig, o, imgs[o], targets=[t]) for o, t in (("p", "q"), ("q", "p"))}
        try:
            first = localize(rig, observations_of(dets), "p", "q").status
        except MutlocError:
            first = "failed"
        assert first != "solved"
        frames = {r: [Frame(k, 0.1 * k, imgs[r]) for k in range(3)] for r in "pq"}
        traj = track(RIG, {r: iter(f) for r, f in frames.items()}, fps=10.0, progress=False, filter=filter)
        truth = relative_pose(w, "p", "q")
        assert [r.status for r in traj.rows] == ["solved"] * 3, traj.summary()
        assert max(r.estimate.pose.translation_error(truth) for r in traj.rows) < 0.002


@pytest.mark.parametrize("i, obs, m", [(36, "q", "M4"), (37, "q", "M3")])
def test_refit_finds_the_rim_against_a_background_of_a_near_hue(i, obs, m):
    """A partly hidden ball bordering a background close to its own hue (a
    light stripe, a salmon poster): the wide window's edges land pixels off
    the outline and the fit drops them, measuring far less rim than shows;
    the rays measured again close to the predicted outline find it, and the
    centre stays where the true pose puts it."""
    w = _occluded_run(i)
    img = render(w, obs, seed=i, noise_sigma=1.0)
    ctx = RefitContext.of(img, RIG.robot(obs).camera)
    owner = "p" if obs == "q" else "q"
    marker = RIG.robot(owner).markers[m]
    X = _truth_centre(w, obs, m)
    shown = ball_visibility(w, obs, m)
    wide = refit_ball(ctx, m, marker, X, radius_offset_px=-0.065, narrow_px=None)
    # (None: too little rim of the ball's colour to measure at all.)
    assert wide is None or wide.visible_fraction < shown - 0.1
    det = refit_ball(ctx, m, marker, X, radius_offset_px=-0.065)
    assert det is not None
    assert abs(det.visible_fraction - shown) < 0.1, (det.visible_fraction, shown)
    assert np.linalg.norm(det.uv - project_markers(w, obs)[m]) < 0.1


def test_refit_leaves_out_an_occluders_far_edge_near_the_outline():
    """A pole a little wider than the ball's hidden part (bench/balls_occluded.py's held-out scene alt 318):
    rays from the centre cross it and find its far edge close to the ball's outline on the hidden side.
    That edge is a step from the pole's grey, not from the ball's red: it is not rim.  (Taken as rim, it
    pulled the centre 0.18-0.25 px towards the pole and raised the visible fraction from 0.45 to 0.7.)"""
    i = 318
    rng = np.random.default_rng(1000 + i)
    d = rng.uniform(1.2, 3.5)
    T = facing_pose(d, np.radians(rng.uniform(-10, 10)), np.radians(rng.uniform(-10, 10)),
                    rng.uniform(-0.15, 0.15) * d)
    w = two_robot_world(RIG, T, seed=i)
    props = []
    for obs, ms in (("q", ["M3", "M4"]), ("p", ["M1", "M2"])):
        m = str(rng.choice(ms))
        props.append(occluder(w, obs, m, rng.uniform(0.3, 0.7), OCCLUDERS[rng.integers(3)],
                              side=rng.choice([-1, 1])))
    w = with_props(w, *props)
    assert props[0].kind == "pole"
    ctx = RefitContext.of(render(w, "q", seed=i, noise_sigma=1.0), RIG.robot("q").camera)
    X, truth = _truth_centre(w, "q", "M3"), project_markers(w, "q")["M3"]
    seen = ball_visibility(w, "q", "M3")
    assert 0.4 < seen < 0.5
    for dx in (0.0, 0.002, -0.002):  # predicted centres up to 2 mm off
        det = refit_ball(ctx, "M3", RIG.robot("p").markers["M3"], X + np.array([dx, 0.0, 0.0]),
                         radius_offset_px=-0.065)
        assert det is not None
        assert float(np.linalg.norm(det.uv - truth)) < 0.1
        assert abs(det.visible_fraction - seen) < 0.1
