"""Banded-cylinder markers: band geometry and detection against the renderer's ground truth.

Ground truth: the band centres of ``band_points`` (whose geometry is checked
against the renderer's band formula) projected by the observer's camera with
the world's exact relative pose.  Scenes are rendered from the plain rig
(the expanded rig's band markers would be drawn as balls).
"""

from __future__ import annotations

import numpy as np
import pytest

import mutloc
from mutloc.core.geometry import rotation_error_deg, so3_exp
from mutloc.core.pose import Pose
from mutloc.detect.cylinders import band_marker_names, band_points, detect_cylinders, expand_cylinder_bands
from mutloc.sim.render import relative_pose, render, two_robot_world
from mutloc.sim.world import standard_rig


def test_band_points_match_renderer_formula():
    rig = standard_rig("cylinders")
    m = rig.robot("q").markers["M1"]
    names, pts = band_points(m)
    assert names == band_marker_names("M1", 6) == [f"M1#b{k}" for k in range(6)]
    h = 0.06  # half height
    for k, X in enumerate(pts):
        s = -(X[1] - m.position[1])  # axis coordinate, up = robot -y
        # the renderer's band index of an axis coordinate s: int((h - s) / (2h) * n)
        assert int((h - s) / (2 * h) * 6) == k
        assert np.allclose(X[[0, 2]], m.position[[0, 2]])
    assert np.isclose(pts[:, 1].mean(), m.position[1])
    assert pts[0, 1] < pts[-1, 1]  # b0 is the top band (robot -y)


def test_expand_is_idempotent():
    ex = expand_cylinder_bands(standard_rig("cylinders"))
    assert set(ex.robot("q").markers) >= {"M1", "M1#b0", "M1#b5", "M2#b3"}
    ex2 = expand_cylinder_bands(ex)
    assert set(ex2.robot("p").markers) == set(ex.robot("p").markers)
    assert ex.robot("p").markers["M3#b2"].extra == {"cylinder_of": "M3", "band": 2}


RIG = standard_rig("cylinders")
EX = expand_cylinder_bands(RIG)


def _scene(d):
    T = Pose(so3_exp(np.array([0.0, np.pi + 0.2, 0.0])), np.array([0.1, 0.0, d]))
    return T, two_robot_world(RIG, T)


def _truth(world, obs):
    other = "q" if obs == "p" else "p"
    Tr = relative_pose(world, other, obs)
    cam = RIG.robot(obs).camera
    return {n: cam.project(Tr.apply(m.position)) for n, m in EX.robot(other).markers.items()}


@pytest.fixture(scope="module")
def scenes():
    out = {}
    for d in (1.5, 3.0):
        T, w = _scene(d)
        out[d] = (T, w, {o: render(w, o) for o in ("p", "q")})
    return out


# (distance, observer, cylinders that must be found).  q's view of M4 at 1.5 m has its top
# dark band touching dark poster text; p's view of M1 at 3.0 m has 5-px bands.
CASES = [(1.5, "p", {"M1", "M2"}), (3.0, "q", {"M3", "M4"}), (1.5, "q", {"M3", "M4"}), (3.0, "p", {"M1", "M2"})]


@pytest.mark.parametrize("d,obs,expected", CASES)
def test_band_centres_accurate(scenes, d, obs, expected):
    _, w, imgs = scenes[d]
    gt = _truth(w, obs)
    other = "q" if obs == "p" else "p"
    res = detect_cylinders(imgs[obs], EX.robot(other).markers)
    found = {n for n in res.detections if "#" not in n}
    assert expected <= found
    errs = []
    for name in found:
        names = [name] + band_marker_names(name, 6)
        e = [np.linalg.norm(res.detections[n].uv - gt[n]) for n in names]
        assert max(e) < 1.5, (name, e)  # the right code: every band near its own truth
        errs += e
    assert np.median(errs) <= 0.5, errs
    for name in {"M1", "M2", "M3", "M4"} & set(EX.robot(other).markers) - found:
        assert name in res.missing and f"{name}#b5" in res.missing


def test_wrong_code_not_reported(scenes):
    _, _, imgs = scenes[3.0]
    # q sees p's M3 [1,0,0,1,1,1] and M4 [1,1,1,0,0,1]; ask for a code neither has.
    from mutloc.core.rig import Marker
    fake = Marker("X", "p", np.zeros(3), extra={"cylinder": {"radius": 0.03, "height": 0.12,
                                                             "code": [1, 0, 1, 0, 1, 1, 0, 1]}})
    res = detect_cylinders(imgs["q"], {"X": fake})
    assert not res.detections and "X" in res.missing and "X#b7" in res.missing


def test_localize_from_bands(scenes):
    T, w, imgs = scenes[1.5]
    obs = {}
    for o, other in (("p", "q"), ("q", "p")):
        px = detect_cylinders(imgs[o], EX.robot(other).markers).pixels()
        # The ends and centre of each cylinder (all 7 points per cylinder work too, but slowly).
        obs[o] = {n: uv for n, uv in px.items() if "#" not in n or n.endswith(("#b0", "#b5"))}
    est = mutloc.localize(EX, obs, source="p", target="q")
    Tgt = relative_pose(w, "p", "q")
    assert np.linalg.norm(est.t - Tgt.t) < 0.05
    assert rotation_error_deg(est.R, Tgt.R) < 2.0
    print('t err m', np.linalg.norm(est.t - Tgt.t), 'rot err deg', rotation_error_deg(est.R, Tgt.R))


def _sweep_errors(d, yp, yq, seed, **kw):
    from mutloc.sim.render import project_markers
    from mutloc.sim.synthetic import facing_pose

    w = two_robot_world(RIG, facing_pose(d, np.radians(yp), np.radians(yq), 0.05 * d), seed=seed)
    found, expected, errs = 0, 0, []
    for obs, other in (("p", "q"), ("q", "p")):
        gt = _truth(w, obs)
        vis = project_markers(w, obs, check_occlusion=True)
        res = detect_cylinders(render(w, obs, seed=seed, **kw), EX.robot(other).markers)
        for name in RIG.robot(other).markers:
            if name not in vis:
                continue
            expected += 1
            if name in res.detections:
                found += 1
                e = [np.linalg.norm(res.detections[n].uv - gt[n]) for n in [name] + band_marker_names(name, 6)]
                assert max(e) < 4.0, (d, yp, yq, obs, name, e)  # never a wrong place / wrong code
                errs += e
    return found, expected, errs


# Poses where every cylinder is fully visible, at 1.2-3 m and yaw up to 15 degrees, rendered
# clean and with sensor noise + blur + JPEG.  The 16-pose sweep (distances 1.2, 1.5, 2.2,
# 3.0 m x yaws (0, 0), (15, -15), (-15, 15), (10, 5), seed 4 i + j) of which these are four:
# 64/64 found clean and degraded, median band error 0.06 / 0.08 px, 90th percentile 0.22 /
# 0.20 px, worst 0.40 / 0.41 px (the first detector: 63/64 and 63/64, median 0.16 / 0.17 px,
# worst 2-3 px on the top band at 1.2 m with 15 degrees yaw).  These four: median 0.06 /
# 0.07 px, worst 0.24 / 0.35 px (were 0.15 / 0.15 and 1.27 / 0.79 px).
SWEEP = [(1.2, 0, 0, 0), (1.5, -15, 15, 6), (2.2, 15, -15, 9), (3.0, 10, 5, 15)]
DEGRADED = {"clean": {}, "noise+blur+jpeg": {"noise_sigma": 2.0, "blur_px": 0.7, "jpeg_quality": 90}}


@pytest.mark.parametrize("cond", sorted(DEGRADED))
def test_detection_rate_and_accuracy_sweep(cond):
    found = expected = 0
    errs = []
    for d, yp, yq, seed in SWEEP:
        f, e, er = _sweep_errors(d, yp, yq, seed, **DEGRADED[cond])
        found, expected, errs = found + f, expected + e, errs + er
    assert expected == 16
    assert found == expected, (found, expected)
    assert np.median(errs) <= 0.15, np.median(errs)
    assert np.percentile(errs, 90) <= 0.4
    assert max(errs) <= 0.75


@pytest.mark.parametrize("kw", [{"noise_sigma": 2.0}, {"blur_px": 0.7}, {"jpeg_quality": 90}])
def test_each_degradation_alone(kw):
    f, e, errs = _sweep_errors(1.5, -15, 15, 6, **kw)
    assert f == e == 4
    assert np.median(errs) <= 0.2
    assert max(errs) <= 0.75


# The first detector's known failures (issue), each (distance, yaw_p, yaw_q, seed of the sweep
# above, render options, observer, cylinder):
HARD_CASES = [
    # Missed: the middle and bottom dark bands touch a dark disc and dark text beside them over
    # their whole height, so no row run had a band's own width.
    pytest.param(1.5, 10, 5, 7, {}, "p", "M2", id="1.5m-p-M2-clutter-beside-bands"),
    pytest.param(1.5, 10, 5, 7, DEGRADED["noise+blur+jpeg"], "p", "M2", id="1.5m-p-M2-degraded"),
    # Missed with sensor noise, or JPEG: the top band touches dark text beside it.
    pytest.param(1.2, 0, 0, 0, {"noise_sigma": 2.0}, "q", "M4", id="1.2m-q-M4-noise"),
    pytest.param(1.2, 0, 0, 0, {"jpeg_quality": 90}, "q", "M4", id="1.2m-q-M4-jpeg"),
    pytest.param(1.2, 0, 0, 0, {"noise_sigma": 2.0, "jpeg_quality": 90}, "q", "M4", id="1.2m-q-M4-noise-jpeg"),
    # 2-3 px on the top band at 1.2 m, 15 degrees yaw: the top band against dark posters (its
    # run widened by them tilted the centre line; a poster's edge taken for the cylinder's top),
    # and boundaries that show as tilted, curved ellipse arcs.
    pytest.param(1.2, 15, -15, 1, {}, "q", "M3", id="1.2m-yaw15-q-M3"),
    pytest.param(1.2, 15, -15, 1, {}, "p", "M2", id="1.2m-yaw15-p-M2"),
    pytest.param(1.2, -15, 15, 2, {}, "p", "M1", id="1.2m-yaw15-p-M1"),
    pytest.param(1.2, -15, 15, 2, {}, "p", "M2", id="1.2m-yaw15-p-M2b"),
    pytest.param(1.2, 15, -15, 1, DEGRADED["noise+blur+jpeg"], "q", "M3", id="1.2m-yaw15-q-M3-degraded"),
]


@pytest.mark.parametrize("d,yp,yq,seed,kw,obs,name", HARD_CASES)
def test_known_hard_cases(d, yp, yq, seed, kw, obs, name):
    """Found, every band centre near its truth (median <= 0.5 px), and nothing else reported
    anywhere but at its own truth.  Truth: ``project_markers`` on the same scene with the band
    markers (the renderer draws the plain rig; the band points are the same geometry)."""
    from mutloc.sim.render import project_markers
    from mutloc.sim.synthetic import facing_pose

    T = facing_pose(d, np.radians(yp), np.radians(yq), 0.05 * d)
    w = two_robot_world(RIG, T, seed=seed)
    gt = project_markers(two_robot_world(EX, T, seed=seed), obs)
    other = "q" if obs == "p" else "p"
    res = detect_cylinders(render(w, obs, seed=seed, **kw), EX.robot(other).markers)
    assert name in res.detections, res.missing
    names = [name] + band_marker_names(name, 6)
    errs = [float(np.linalg.norm(res.detections[n].uv - np.asarray(gt[n]))) for n in names]
    print(name, np.round(errs, 3))
    assert np.median(errs) <= 0.5, errs
    assert max(errs) <= 1.0, errs
    for n, det in res.detections.items():
        assert np.linalg.norm(det.uv - np.asarray(gt[n])) <= 1.0, (n, det.uv, gt[n])


def test_odd_band_count_middle_band_on_the_centre_tracks():
    """A cylinder with an odd number of bands has its middle band on its
    centre: the expanded rig holds both (the band is derived from the
    cylinder), the detections name the bands and not the centre (the same
    pixel twice would count one measurement twice), and the pose from the
    images matches the world's."""
    from mutloc.track.frames import detect_markers, expanded_rig

    spec = standard_rig("cylinders").to_dict()
    codes = {"M1": [1, 0, 1, 0, 1], "M2": [1, 1, 0, 1, 1], "M3": [1, 0, 0, 1, 1], "M4": [1, 1, 1, 0, 1]}
    for r in spec["robots"].values():
        for n, m in r["markers"].items():
            m["cylinder"] = dict(m["cylinder"], code=codes[n])
    rig = mutloc.load_rig(spec)
    ex = expanded_rig(rig)
    assert np.allclose(ex.robot("p").markers["M3#b2"].position, rig.robot("p").markers["M3"].position)
    T = Pose(so3_exp(np.array([0.0, np.pi + 0.2, 0.0])), np.array([0.1, 0.0, 1.5]))
    world = two_robot_world(rig, T)
    imgs = {o: render(world, o) for o in ("p", "q")}
    det = detect_markers(ex, "q", imgs["q"])
    assert {"M3#b0", "M3#b2", "M3#b4"} <= set(det.detections), (det.detections.keys(), det.missing)
    assert "M3" not in det.detections and "M4" not in det.detections
    res = mutloc.localize_images(spec, imgs)
    truth = relative_pose(world, "p", "q")
    assert np.linalg.norm(res.estimate.t - truth.t) < 0.02
    assert rotation_error_deg(res.estimate.R, truth.R) < 1.0
