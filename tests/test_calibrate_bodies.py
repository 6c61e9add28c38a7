"""Marker calibration on robots with several cameras, any lens (issue 36):
logs keyed ROBOT/CAMERA, each observation through its camera's mount and
lens, against the simulator's truth."""

import json

import numpy as np
import pytest

import mutloc
from mutloc.calibration import calibrate_markers
from mutloc.cli.main import main
from mutloc.core import calibration as cc
from mutloc.core.calibration import BundleProblem
from mutloc.core.geometry import so3_exp
from mutloc.core.observations import ObservationSet
from mutloc.core.rays import ray_frames
from mutloc.errors import ObservationError
from mutloc.io.logs import write_observation_log
from mutloc.sim.bodies import back_to_back_fisheye
from mutloc.sim.calibration import body_rig, body_sequence, perturb_rig, true_positions

SIGMA = 0.5


def _scale(truth, a="M1", b="M2"):
    """The true distance between two markers of the first robot, as a tape measure gives it."""
    tp = true_positions(truth)
    return (a, b, float(np.linalg.norm(tp[a] - tp[b])))


def _cameras(rig_dict):
    return {r: spec.get("cameras", spec.get("camera")) for r, spec in rig_dict["robots"].items()}


def _check_returns_to_truth(res, truth, measured, gain, max_z=4.0):
    """Every marker within ``max_z`` of its position_sigma of the truth on every axis, and the markers' RMS error
    below ``gain`` times the given rig's."""
    tp, given = true_positions(truth), true_positions(measured)
    assert set(res.markers) == set(tp)
    for n, m in res.markers.items():
        z = (m.new - tp[n]) / m.sigma
        assert np.all(np.abs(z) < max_z), (n, z, m.sigma)
    after = np.sqrt(np.mean([np.sum((m.new - tp[n]) ** 2) for n, m in res.markers.items()]))
    before = np.sqrt(np.mean([np.sum((given[n] - tp[n]) ** 2) for n in res.markers]))
    assert after < gain * before, (after, before)


def test_ray_normal_equations_match_finite_differences():
    """Ray mode (three body robots, fisheye rays from off-centre cameras): the kernel's J^T J blocks and gradient
    equal those of a finite-difference Jacobian of its residuals, and the residuals are the pixel errors of the
    lens projection to first order."""
    rng = np.random.default_rng(0)
    G, S, M = 3, 2, 6
    owner = [0, 0, 1, 1, 2, 2]
    R = np.array([[so3_exp(rng.normal(scale=0.3, size=3)) for _ in range(S)] for _ in range(G)])
    t = rng.normal(size=(G, S, 3)) * 0.3
    t[..., 2] += 3.0
    X = rng.normal(size=(M, 3)) * 0.2
    rows = np.array([(g, o - 1, owner[m] - 1, o, m) for g in range(G) for o in range(3) for m in range(M)
                     if owner[m] != o])
    mount = back_to_back_fisheye("p", {"a": [0.0, 0.0, 1.0]}).cameras["front"]
    # observed rays near (not at) each point, seen from an off-centre camera
    uv = rng.normal(scale=40.0, size=(len(rows), 2)) + [640.0, 400.0]
    frames = ray_frames(mount, uv)[1]
    p = BundleProblem(*(np.ascontiguousarray(rows[:, k]) for k in range(5)), uv, np.zeros((1, 3, 3)),
                      np.zeros((1, 8)), np.ones((G, S), bool), M, ((0, 1, 0.3),), frames=frames)
    system = cc._System(p)

    def resid(R, t, X):
        r = np.zeros((len(rows), 2))
        system.cost(p, X, R, t, 1.0, 1e12, r, np.ones(len(rows)))
        return r.ravel()

    r0 = resid(R, t, X)
    system.linearize(p, X, R, t, 1.0, 1e12)
    npar = G * 6 * S + 3 * M
    J = np.zeros((len(r0), npar))
    eps = 1e-6
    for k in range(npar):
        dg, dm = np.zeros((G, 6 * S)), np.zeros(3 * M)
        if k < G * 6 * S:
            dg.ravel()[k] = eps
        else:
            dm[k - G * 6 * S] = eps
        Rn, tn, Xn = np.empty_like(R), np.empty_like(t), np.empty_like(X)
        cc._apply_step(R, t, X, p.slot_used, dg, dm, Rn, tn, Xn)
        J[:, k] = (resid(Rn, tn, Xn) - r0) / eps
    H, g = J.T @ J, J.T @ r0
    P = 6 * S
    for gi in range(G):
        blk = slice(gi * P, (gi + 1) * P)
        np.testing.assert_allclose(system.Hgg[gi], H[blk, blk], rtol=1e-4, atol=1e-5 * np.abs(H).max())
        np.testing.assert_allclose(system.Hgm[gi], H[blk, G * P:], rtol=1e-4, atol=1e-5 * np.abs(H).max())
    np.testing.assert_allclose(system.Hmm, H[G * P:, G * P:], rtol=1e-4, atol=1e-5 * np.abs(H).max())
    np.testing.assert_allclose(system.gm, g[G * P:], rtol=1e-4, atol=1e-5 * np.abs(g).max())
    # a point 0.3 px off its observed ray (through the lens, from the camera's centre): residual 0.3 px
    b = mount.camera.pixels_to_bearings(np.array([700.0, 380.0]))
    P_cam = 2.5 * b
    uv_off = mount.camera.project(P_cam) + [0.3, 0.0]
    F = ray_frames(mount, uv_off[None])[1][0]
    Xr = mount.pose.apply(P_cam)
    d = Xr - F[3]
    np.testing.assert_allclose([F[0] @ d / (F[2] @ d), F[1] @ d / (F[2] @ d)], [-0.3, 0.0], atol=2e-3)


def test_noise_free_body_log_recovers_the_true_markers_exactly():
    """Three robots with back-to-back fisheyes moving about each other, exact pixels: the true markers come back
    from markers moved 1-2 cm, and the written rig keeps every camera (lens and pose) as given."""
    rng = np.random.default_rng(1)
    truth = body_rig(("p", "q", "r"))
    measured = perturb_rig(truth, rng)
    seq = body_sequence(truth, 20, rng, pixel_sigma=0.0)
    assert any("/back" in o for f in seq.frames for o in f.observer)
    res = calibrate_markers(measured, seq.frames, scale=_scale(truth), pixel_sigma=SIGMA, weak_sigma=None)
    tp = true_positions(truth)
    for n, m in res.markers.items():
        np.testing.assert_allclose(m.new, tp[n], atol=1e-7)
        assert np.linalg.norm(m.old - tp[n]) > 0.009
    assert res.reprojection_rms_px < 1e-6
    assert _cameras(res.rig) == _cameras(measured) == _cameras(truth)


@pytest.mark.parametrize("seed", [2, 3])
def test_noisy_team_of_bodies_returns_to_truth_within_its_sigmas(seed):
    rng = np.random.default_rng(seed)
    truth = body_rig(("p", "q", "r"))
    measured = perturb_rig(truth, rng)
    seq = body_sequence(truth, 30, rng, pixel_sigma=SIGMA)
    res = calibrate_markers(measured, seq.frames, scale=_scale(truth), pixel_sigma=SIGMA)
    _check_returns_to_truth(res, truth, measured, gain=0.25)
    assert res.frames_used >= 28
    assert 0.8 * SIGMA < res.reprojection_rms_px < 1.5 * SIGMA


def test_mixed_rig_of_a_body_and_a_pinhole_robot():
    """p: a body with two fisheyes (keys p/front, p/back); q: one pinhole camera, its frame the camera's (key q).
    Two upright robots leave combinations the log determines only weakly (held near the given rig, 1 cm): the
    sigmas say so, and the rest moves to the truth."""
    rng = np.random.default_rng(4)
    truth = body_rig(("p", "q"), pinhole=("q",))
    measured = perturb_rig(truth, rng)
    seq = body_sequence(truth, 40, rng, pixel_sigma=SIGMA)
    keys = {o for f in seq.frames for o in f.observer}
    assert "q" in keys and {"p/front", "p/back"} & keys
    res = calibrate_markers(measured, seq.frames, scale=_scale(truth), pixel_sigma=SIGMA)
    _check_returns_to_truth(res, truth, measured, gain=0.6)
    assert any(w.held for w in res.weak_directions)
    assert _cameras(res.rig) == _cameras(truth)
    # the weak combinations are said in each robot's own axes: a body's z is up, a camera's y down
    for w in res.weak_directions:
        assert "p's markers (+y)" not in w.description and "p's markers (-y)" not in w.description


def test_bad_keys_are_one_line_errors(tmp_path, capsys):
    rng = np.random.default_rng(5)
    truth = body_rig(("p", "q"))
    frames = body_sequence(truth, 6, rng, pixel_sigma=SIGMA).frames
    for bad, words in (("p/side", "unknown camera 'p/side'"), ("p", "key its observations by camera"),
                       ("x/front", "unknown robot 'x/front'")):
        f = frames[3]
        wrong = ObservationSet([bad if i == 0 else o for i, o in enumerate(f.observer)], f.marker, f.uv, f.times[0])
        log = frames[:3] + [wrong] + frames[4:]
        with pytest.raises(ObservationError, match="frame 3") as exc:
            calibrate_markers(truth, log, scale=_scale(truth), pixel_sigma=SIGMA)
        assert words in str(exc.value) and "\n" not in str(exc.value)
        write_observation_log(tmp_path / "log.jsonl", log)
        (tmp_path / "rig.json").write_text(json.dumps(truth))
        code = main(["calibrate-markers", "--rig", str(tmp_path / "rig.json"), "--observations",
                     str(tmp_path / "log.jsonl"), "--out", str(tmp_path / "new.yaml")])
        err = capsys.readouterr().err
        assert code == 2 and err.count("\n") == 1 and words in err, err
        assert not (tmp_path / "new.yaml").exists()


def test_cli_calibrates_a_body_log_and_keeps_the_cameras(tmp_path, capsys):
    rng = np.random.default_rng(6)
    truth = body_rig(("p", "q", "r"))
    measured = perturb_rig(truth, rng)
    write_observation_log(tmp_path / "log.jsonl", body_sequence(truth, 30, rng, pixel_sigma=SIGMA).frames)
    (tmp_path / "rig.json").write_text(json.dumps(measured))
    a, b, d = _scale(truth)
    code = main(["calibrate-markers", "--rig", str(tmp_path / "rig.json"), "--observations",
                 str(tmp_path / "log.jsonl"), "--scale", f"{a}:{b}={d!r}", "--pixel-sigma", str(SIGMA),
                 "--out", str(tmp_path / "new.yaml")])
    assert code == 0
    assert "M12" in capsys.readouterr().out
    new = mutloc.load_rig(tmp_path / "new.yaml")
    assert _cameras(new.to_dict()) == _cameras(truth)
    tp, given = true_positions(truth), true_positions(measured)
    err = [np.linalg.norm(new.marker(n).position - tp[n]) for n in tp]
    before = [np.linalg.norm(given[n] - tp[n]) for n in tp]
    assert np.sqrt(np.mean(np.square(err))) < 0.25 * np.sqrt(np.mean(np.square(before)))
    for robot in new.robots.values():
        for m in robot.markers.values():
            assert len(m.extra["position_sigma"]) == 3 and min(m.extra["position_sigma"]) > 0


def test_tags_on_bodies_calibrate_as_rigid_bodies_exactly():
    """Printed tags on robots with several cameras, the log naming their corners NAME#0..3 (what track
    --observations-out writes): exact corners give back every tag's true centre and rotation from a rig whose
    tags are moved 1-2 cm and turned 2 degrees."""
    from mutloc.api import load_rig
    from mutloc.core.geometry import rotation_error_deg
    from mutloc.sim.calibration import true_rotations
    from mutloc.track.frames import expanded_rig

    rng = np.random.default_rng(7)
    truth = body_rig(("p", "q", "r"))
    for i, (name, m) in enumerate((n, m) for spec in truth["robots"].values() for n, m in spec["markers"].items()):
        m["tag"] = {"family": "tag36h11", "id": i, "size": 0.1, "rotation": rng.normal(scale=1.0, size=3).tolist()}
    measured = perturb_rig(truth, rng, rotation_deg=2.0)
    corners = expanded_rig(load_rig(truth)).to_dict()
    seq = body_sequence(corners, 12, rng, pixel_sigma=0.0)
    frames = [f.take(np.array(["#" in m for m in f.marker])) for f in seq.frames]
    res = calibrate_markers(measured, frames, scale=_scale(truth), pixel_sigma=SIGMA, weak_sigma=None)
    tp, tr = true_positions(truth), true_rotations(truth)
    assert set(res.markers) == set(tp)
    for n, m in res.markers.items():
        np.testing.assert_allclose(m.new, tp[n], atol=1e-7)
        assert rotation_error_deg(so3_exp(m.new_rotation), tr[n]) < 1e-5
        assert rotation_error_deg(so3_exp(m.old_rotation), tr[n]) > 1.9
    assert _cameras(res.rig) == _cameras(truth)


def test_upright_bodies_weak_combination_is_said_in_the_bodys_axes():
    """Two upright bodies that only yaw (no tilt), the log alone: raising one robot's markers while lowering the
    other's changes almost no pixel; the refusal says so along the bodies' z (up), not a camera's y, and asks to
    tilt a robot (a body has no one optical axis to roll about)."""
    from mutloc.errors import UnobservableMarkersError

    rng = np.random.default_rng(3)
    truth = body_rig(("p", "q"))
    seq = body_sequence(truth, 40, rng, pixel_sigma=0.3, tilt_deg=0.0)
    with pytest.raises(UnobservableMarkersError) as exc:
        calibrate_markers(perturb_rig(truth, rng), seq.frames, scale=_scale(truth), weak_sigma=None)
    msg = str(exc.value)
    assert "\n" not in msg
    assert "p's markers (-z)" in msg and "q's markers (+z)" in msg and "about one axis, q's z" in msg, msg
    assert "Tilt one robot (roll or pitch it)" in msg and "optical axis" not in msg, msg
