"""Per-detection noise (``sigma_scale``): the pose weighs each pixel by its own noise and its
covariance follows, checked against Monte Carlo draws with that noise (independent truth: the
draws' own spread), and the ball detector's scale for a partly hidden ball against its geometry."""

from __future__ import annotations

import numpy as np
import pytest

import mutloc
from mutloc.core.geometry import so3_log
from mutloc.detect.balls.fit import centre_sigma_scale
from mutloc.errors import ObservationError
from mutloc.sim.synthetic import facing_pose
from mutloc.sim.world import standard_rig


def _scene():
    rig = standard_rig("balls")
    T = facing_pose(2.5, np.radians(4.0), np.radians(-3.0), 0.2)
    truth = {}
    for obs, other, pose in (("p", "q", T.inverse()), ("q", "p", T)):
        cam = rig.robot(obs).camera
        ms = rig.robot(other).markers
        truth[obs] = {m: cam.project(pose.apply(ms[m].position)) for m in ms}
    return rig, T, truth


def _observations(truth, rng, sigma, scales):
    """Pixels with noise ``sigma * scale`` per marker, as an ObservationSet carrying the scales."""
    obs, mk, uv, sc = [], [], [], []
    for o, px in truth.items():
        for m, u in px.items():
            s = scales.get(m, 1.0)
            obs.append(o)
            mk.append(m)
            uv.append(u + rng.normal(0.0, sigma * s, 2))
            sc.append(s)
    return mutloc.ObservationSet(obs, mk, np.array(uv), sigma_scale=sc)


def _error(est, T):
    return np.r_[so3_log(T.R @ est.R.T), T.t - est.t]


def test_covariance_scales_with_a_common_sigma_scale():
    rig, T, truth = _scene()
    rng = np.random.default_rng(1)
    o1 = _observations(truth, rng, 0.0, {})
    o2 = mutloc.ObservationSet(o1.observer, o1.marker, o1.uv, sigma_scale=3.0)
    e1 = mutloc.localize(rig, o1, "p", "q")
    e2 = mutloc.localize(rig, o2, "p", "q")
    assert np.allclose(e1.t, e2.t, atol=1e-9)
    np.testing.assert_allclose(e2.covariance, 9.0 * e1.covariance, rtol=1e-6)


def test_weighted_pose_matches_its_covariance_and_beats_the_unweighted_one():
    """One ball seen 6x noisier than the rest: the weighted estimate's errors follow its covariance
    (NEES ~ 6 over draws), the unweighted estimate (the same pixels, scales dropped) is worse."""
    rig, T, truth = _scene()
    rng = np.random.default_rng(7)
    scales = {"M1": 6.0}
    sigma = 0.3
    nees, err_w, err_u = [], [], []
    for _ in range(300):
        o = _observations(truth, rng, sigma, scales)
        ew = mutloc.localize(rig, o, "p", "q", pixel_sigma=sigma, confidence=1.0)
        eu = mutloc.localize(rig, mutloc.ObservationSet(o.observer, o.marker, o.uv), "p", "q",
                             pixel_sigma=sigma, confidence=1.0)
        d = _error(ew, T)
        nees.append(float(d @ np.linalg.solve(ew.covariance, d)))
        err_w.append(np.linalg.norm(ew.t - T.t))
        err_u.append(np.linalg.norm(eu.t - T.t))
    assert 5.0 < np.mean(nees) < 7.2
    assert np.median(err_w) < 0.8 * np.median(err_u)


def test_a_bad_sigma_scale_is_refused():
    with pytest.raises(ObservationError, match="sigma_scale"):
        mutloc.ObservationSet(["p"], ["M1"], [[1.0, 2.0]], sigma_scale=[0.0])
    with pytest.raises(ObservationError, match="sigma_scale"):
        mutloc.ObservationSet(["p"], ["M1"], [[1.0, 2.0]], sigma_scale=[np.nan])


def test_sigma_scale_survives_take_concatenate_and_records():
    o = mutloc.ObservationSet(["p", "q"], ["M1", "M3"], [[1.0, 2.0], [3.0, 4.0]], sigma_scale=[2.0, 1.0])
    assert list(o.take([1, 0]).sigma_scale) == [1.0, 2.0]
    assert list(mutloc.ObservationSet.concatenate([o, o]).sigma_scale) == [2.0, 1.0, 2.0, 1.0]
    assert mutloc.ObservationSet.from_records(list(o)) == o
    assert o != mutloc.ObservationSet(o.observer, o.marker, o.uv)


def test_centre_sigma_scale_of_an_arc_matches_a_monte_carlo_circle_fit():
    """The scale for a rim seen over an arc against the spread of algebraic circle fits to noisy
    points on that arc (radius free), relative to fits on the whole rim."""
    n = 64
    ang = np.linspace(-np.pi, np.pi, n, endpoint=False)
    rng = np.random.default_rng(3)

    def spread(used):
        a = ang[used]
        cs = []
        for _ in range(2000):
            r = 10.0 + rng.normal(0.0, 0.1, len(a))
            x, y = r * np.cos(a), r * np.sin(a)
            M = np.c_[x, y, np.ones_like(x)]
            sol = np.linalg.lstsq(M, x * x + y * y, rcond=None)[0]
            cs.append(sol[:2] / 2.0)
        return np.sqrt(np.linalg.eigvalsh(np.cov(np.array(cs).T))[-1])

    whole = spread(np.ones(n, bool))
    for hidden in (0.3, 0.5):
        used = np.abs(ang) >= np.pi * hidden
        assert centre_sigma_scale(ang, used) == pytest.approx(spread(used) / whole, rel=0.12)
    assert centre_sigma_scale(ang, np.ones(n, bool)) == pytest.approx(1.0)


def test_the_team_solver_weighs_the_same_way():
    """A team's joint solve reads the same column: a common scale scales its covariance, and one
    noisy ball's weight gives the pair solver's pose and covariance."""
    rig, T, truth = _scene()
    o = _observations(truth, np.random.default_rng(5), 0.3, {"M1": 4.0})
    flat = mutloc.ObservationSet(o.observer, o.marker, o.uv)
    three = mutloc.ObservationSet(o.observer, o.marker, o.uv, sigma_scale=3.0)
    t1 = mutloc.localize_team(rig, flat, "p")
    t3 = mutloc.localize_team(rig, three, "p")
    np.testing.assert_allclose(t3.covariance("q"), 9.0 * t1.covariance("q"), rtol=1e-5)
    tw = mutloc.localize_team(rig, o, "p")
    pw = mutloc.localize(rig, o, "q", "p", confidence=1.0)
    assert np.allclose(tw.poses["q"].t, pw.t, atol=1e-7)
    np.testing.assert_allclose(tw.covariance("q"), pw.covariance, rtol=1e-4, atol=1e-12)
    assert not np.allclose(t1.poses["q"].t, pw.t, atol=1e-5)


def test_with_sigma_scale_sets_or_clears_the_column():
    o = mutloc.ObservationSet(["p", "q"], ["M1", "M3"], [[1.0, 2.0], [3.0, 4.0]], time=2.0, sigma_scale=[2.0, 3.0])
    assert list(o.with_sigma_scale(None).sigma_scale) == [1.0, 1.0]
    assert list(o.with_sigma_scale(4.0).sigma_scale) == [4.0, 4.0]
    assert o.with_sigma_scale(None).uv.tolist() == o.uv.tolist() and list(o.with_sigma_scale(None).time) == [2.0, 2.0]
