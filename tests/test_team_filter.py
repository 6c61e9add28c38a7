"""The joint team filter (mutloc.core.team_filter) against a simulated team
whose cameras capture at their own times (each record one camera's frame):
ground truth from mutloc.sim.team (poses along smooth motions, markers
projected with 1 px noise)."""

import numpy as np
import pytest

from mutloc.core.filter import MotionNoise
from mutloc.core.geometry import so3_log
from mutloc.core.pose import Pose
from mutloc.core.team_filter import TeamFilter
from mutloc.errors import InputError
from mutloc.sim.team import TeamScene, random_team, team_camera_records, team_motion
from mutloc.team import localize_team, team_problem


def _run(n, seed, duration=3.0):
    rng = np.random.default_rng(seed)
    scene = random_team(n, rng, one_way=0.0)
    recs = team_camera_records(scene, duration, sigma=1.0, seed=seed)
    names = scene.names
    ref = names[0]
    snap = TeamScene(scene.rig, team_motion(scene, seed=seed)(0.0), scene.links)
    team = localize_team(scene.rig, snap.observations(1.0, rng), ref)
    f = TeamFilter(names, ref, MotionNoise(), pixel_sigma=1.0)
    f.reset(0.0, {r: team.poses[r] for r in team.robots}, team.joint_covariance)
    nees, err, rel, rel_marginal, accepted = [], [], [], [], 0
    for t, _, world, obs in recs:
        f.predict(t)
        if len(obs):
            accepted += f.update(team_problem(scene.rig, obs)[0]).accepted
        if t < 0.5:
            continue
        W = world[ref].inverse()
        for r in team.robots:
            T = W @ world[r]
            e = np.r_[so3_log(T.R @ f.pose(r).R.T), T.t - f.pose(r).t]
            nees.append(e @ np.linalg.solve(f.covariance(r), e) / 6)
            err.append(np.linalg.norm(e[3:]))
        a, b = team.robots[:2]
        T = world[b].inverse() @ world[a]
        pose, C = f.relative(a, b)
        e = np.r_[so3_log(T.R @ pose.R.T), T.t - pose.t]
        rel.append(e @ np.linalg.solve(C, e) / 6)
        rel_marginal.append(np.trace(C[3:, 3:]) / np.trace(f.covariance(a)[3:, 3:] + f.covariance(b)[3:, 3:]))
    return dict(nees=np.array(nees), err=np.array(err), rel=np.array(rel), ratio=np.array(rel_marginal),
                accepted=accepted, records=len(recs))


def test_unsynchronized_team_is_tracked_with_honest_joint_covariance():
    """Four robots, each camera at 30 fps a quarter frame after the last:
    every record holds one camera's view.  The poses' normalised errors and
    those of a relative pose between two non-reference robots (from the
    joint covariance, correlations included) are near 1; the correlation
    makes the relative pose better known than the two robots' own
    uncertainties in the reference's frame would say (measured 0.65-0.78
    mean NEES/6, relative 0.57-0.65)."""
    runs = [_run(4, seed) for seed in range(3)]
    nees = np.concatenate([r["nees"] for r in runs])
    rel = np.concatenate([r["rel"] for r in runs])
    assert 0.4 <= nees.mean() <= 1.5 and 0.4 <= rel.mean() <= 1.5
    assert np.mean(nees > 20.5 / 6) < 0.01  # chi2(6) 99.9 %: 20.5
    assert np.median(np.concatenate([r["err"] for r in runs])) < 0.03
    assert all(r["accepted"] >= 0.98 * r["records"] for r in runs)
    assert np.median(np.concatenate([r["ratio"] for r in runs])) < 0.9


def _filter_and_problem():
    rng = np.random.default_rng(5)
    scene = random_team(3, rng, one_way=0.0)
    names = scene.names
    truth = scene.truth(names[0])
    f = TeamFilter(names, names[0], pixel_sigma=1.0)
    f.time = 0.0
    for r in names[1:]:
        f.add(r, truth[r], np.diag([0.01] * 3 + [0.02] * 3) ** 2)
    obs = scene.observations(1.0, rng)
    return f, team_problem(scene.rig, obs)[0], truth


def test_a_far_off_observation_is_dropped_and_a_wrong_frame_rejected():
    f, prob, truth = _filter_and_problem()
    assert len(prob.cam) >= 4
    prob.uv = prob.uv.copy()
    prob.uv[1] += [40.0, -25.0]
    upd = f.update(prob)
    assert upd.accepted and upd.dropped.tolist() == [1]
    for r in truth:
        if r != f.reference:
            assert f.pose(r).translation_error(truth[r]) < 0.02
    before = {r: f.pose(r) for r in truth}
    prob.uv = prob.uv + 60.0
    upd = f.update(prob)
    assert not upd.accepted and "inconsistent" in upd.reason
    assert all(f.pose(r).translation_error(before[r]) == 0.0 for r in truth)


def test_misuse_is_refused():
    f, prob, truth = _filter_and_problem()
    f.predict(1.0)
    with pytest.raises(InputError, match="back"):
        f.predict(0.5)
    with pytest.raises(InputError):
        f.pose("nobody")
    with pytest.raises(InputError):
        f.add(f.reference, truth[f.reference], np.eye(6))
    f.drop(f.robots[1])
    assert not f.is_tracked(f.robots[1]) and f.P.shape == (12, 12)


@pytest.mark.parametrize("few", [False, True])
def test_the_gain_may_weigh_measured_noise_and_the_covariance_stays_the_stated_ones(few):
    """Detections of 0.5 px with the stated noise 2 px: after a few records
    the filter has measured the noise (each update's residual that no pose
    explains) and its gain weighs the detections by it.  One more update
    against a dense reference with a finite-difference Jacobian: the gain's
    own covariance is the Kalman posterior at the measured noise, the
    reported one the Joseph form of that same gain under 2 px, the gate is
    under 2 px, and the residual measured is that of the record's
    observations fitted on their own (the two robots' poses free).  ``few``:
    five observations of the two robots (the update's other arithmetic:
    fewer rows than pose columns)."""
    from scipy.optimize import least_squares

    from mutloc.core.geometry import so3_exp
    from mutloc.core.team import team_residuals

    rng = np.random.default_rng(7)
    scene = random_team(3, rng, one_way=0.0)
    names = scene.names
    truth = scene.truth(names[0])
    f = TeamFilter(names, names[0], pixel_sigma=2.0, max_iter=30)
    f.time = 0.0
    for r in names[1:]:
        f.add(r, Pose(so3_exp(rng.normal(0, 0.003, 3)) @ truth[r].R, truth[r].t + rng.normal(0, 0.005, 3)),
              np.diag([0.01] * 3 + [0.02] * 3) ** 2)
    for k in range(1, 6):
        f.predict(0.01 * k)
        assert f.update(team_problem(scene.rig, scene.observations(0.5, rng))[0]).accepted
    assert 0.35 < f.detection_sigma < 0.65 and f.gain_sigma < 0.8 and f.Pg is not None
    sg, sr = f.gain_sigma, 2.0
    prob = team_problem(scene.rig, scene.observations(0.5, rng))[0]
    if few:
        first = [int(np.flatnonzero((prob.cam == i) | (prob.own == i))[0]) for i in (1, 2)]
        rest = [j for j in range(len(prob.cam)) if j not in first]
        prob = prob.take(np.array(first + rest[:5 - len(set(first))]))
        assert len(prob.cam) == 5
    f.predict(0.06)
    prior = f.snapshot()
    upd = f.update(prob)
    assert upd.accepted and len(upd.dropped) == 0
    m = len(prob.cam)

    def pix(R, t):
        r = np.empty(2 * m)
        J = np.empty((m, 2, 6))
        assert team_residuals(prob.cam, prob.own, prob.points, prob.uv, prob.wt, prob.K, prob.dist, R, t, r, J, J, False)
        return r

    def moved(R, t, dx):  # every tracked robot's pose moved by its error state's pose part
        R, t = R.copy(), t.copy()
        for x, i in enumerate(f.tracked):
            R[i] = so3_exp(dx[12 * x:12 * x + 3]) @ R[i]
            t[i] = t[i] + dx[12 * x + 3:12 * x + 6]
        return R, t

    N = 12 * len(f.tracked)
    H = np.array([(pix(*moved(f.R, f.t, h)) - pix(*moved(f.R, f.t, -h))) / 2e-7 for h in np.eye(N) * 1e-7]).T
    P0, Pg0 = prior.P, prior.Pg
    K = Pg0 @ H.T @ np.linalg.inv(H @ Pg0 @ H.T + sg**2 * np.eye(2 * m))
    A = np.eye(N) - K @ H
    np.testing.assert_allclose(f.Pg, A @ Pg0 @ A.T + sg**2 * K @ K.T, rtol=1e-4, atol=1e-12)
    np.testing.assert_allclose(f.P, A @ P0 @ A.T + sr**2 * K @ K.T, rtol=1e-4, atol=1e-12)
    assert f.noise_scale == pytest.approx((sr / sg) ** 2)
    Rp, tp = np.array([np.eye(3)] * len(names)), np.zeros((len(names), 3))
    for x, i in enumerate(prior.tracked):
        Rp[i], tp[i] = prior.R[x], prior.t[x]
    nu = pix(Rp, tp)
    assert upd.test.chi2 == pytest.approx(nu @ np.linalg.solve(H @ P0 @ H.T + sr**2 * np.eye(2 * m), nu), rel=0.05)
    if few:
        return
    # The record on its own: the residual no pose of the two robots explains, 2m - 12 degrees of freedom.
    fit = least_squares(lambda d: pix(*moved(f.R, f.t, np.r_[d[:6], np.zeros(6), d[6:], np.zeros(6)])),
                        np.zeros(12), xtol=1e-14, ftol=1e-14)
    chi2, dof = f._noise_window[-1]
    assert dof == 2 * m - 12 and chi2 == pytest.approx(np.sum(fit.fun**2), rel=0.02)


def test_detections_as_stated_leave_the_filter_as_it_was():
    """With 1 px detections and 1 px stated the measured noise is not
    clearly below the stated: no second covariance, and every update leaves
    the state the filter without noise measurement gets, bit for bit."""
    rng = np.random.default_rng(5)
    scene = random_team(3, rng, one_way=0.0)
    names = scene.names
    truth = scene.truth(names[0])
    f, g = TeamFilter(names, names[0]), TeamFilter(names, names[0], measure_noise=False)
    for x in (f, g):
        x.time = 0.0
        for r in names[1:]:
            x.add(r, truth[r], np.diag([0.01] * 3 + [0.02] * 3) ** 2)
    for k in range(1, 8):
        prob = team_problem(scene.rig, scene.observations(1.0, rng))[0]
        for x in (f, g):
            x.predict(0.01 * k)
            assert x.update(prob).accepted
        assert f.Pg is None and np.array_equal(f.P, g.P) and np.array_equal(f.t, g.t) and np.array_equal(f.R, g.R)
    assert 0.7 < f.detection_sigma < 1.3 and f.gain_sigma == 1.0 and g.gain_sigma == 1.0


def test_an_update_is_the_map_estimate():
    """One update of two robots from a prior about 5 cm / 1 degree off: the
    posterior poses are the minimiser of ``e' P^-1 e + |r(e)|^2 / sigma^2``
    over both robots' poses (found here by SciPy on the team's pixel
    residuals), the gate's chi-square is that minimum (``2m`` degrees of
    freedom), and the posterior is nearer the truth than the prior.  Then two
    markers of one robot seen by the reference's camera: four constraints on
    six unknowns, the covariance shrinks in four directions and keeps the
    prior exactly in two."""
    from scipy.linalg import eigh
    from scipy.optimize import least_squares

    from mutloc.core.geometry import so3_exp
    from mutloc.core.team import team_residuals

    rng = np.random.default_rng(11)
    scene = random_team(3, rng, one_way=0.0)
    names = scene.names
    truth = scene.truth(names[0])
    P6 = np.diag([0.02] * 3 + [0.05] * 3) ** 2
    prior = {r: Pose(so3_exp(rng.normal(0, 0.01, 3)) @ truth[r].R, truth[r].t + rng.normal(0, 0.03, 3))
             for r in names[1:]}
    prob = team_problem(scene.rig, scene.observations(1.0, rng))[0]
    m = len(prob.cam)

    def fresh():
        f = TeamFilter(names, names[0], pixel_sigma=1.0, max_iter=20, measure_noise=False)
        f.time = 0.0
        for r in names[1:]:
            f.add(r, prior[r], P6)
        return f

    f = fresh()
    R0, t0 = f.R.copy(), f.t.copy()
    upd = f.update(prob)
    assert upd.accepted and len(upd.dropped) == 0
    idx = [f.index(r) for r in names[1:]]

    def moved(e):
        R, t = R0.copy(), t0.copy()
        for x, i in enumerate(idx):
            R[i] = so3_exp(e[6 * x:6 * x + 3]) @ R[i]
            t[i] = t[i] + e[6 * x + 3:6 * x + 6]
        return R, t

    def pix(R, t):
        r = np.empty(2 * m)
        J = np.empty((m, 2, 6))
        assert team_residuals(prob.cam, prob.own, prob.points, prob.uv, prob.wt, prob.K, prob.dist, R, t, r, J, J,
                              False)
        return r

    Li = np.linalg.cholesky(np.linalg.inv(P6))
    n_r = len(idx)

    def cost(e):
        return np.r_[np.concatenate([Li.T @ e[6 * x:6 * x + 6] for x in range(n_r)]), pix(*moved(e))]

    e = least_squares(cost, np.zeros(6 * n_r), xtol=1e-14, ftol=1e-14, gtol=1e-14).x
    Rm, tm = moved(e)
    for x, (r, i) in enumerate(zip(names[1:], idx)):
        ref = Pose(Rm[i], tm[i])
        assert f.pose(r).translation_error(ref) < 2e-5 and f.pose(r).rotation_error_deg(ref) < 1e-3
        assert f.pose(r).translation_error(truth[r]) < prior[r].translation_error(truth[r])
    assert upd.test.chi2 == pytest.approx(np.sum(cost(e) ** 2), rel=0.02) and upd.test.dof == 2 * m
    # two markers of one robot, seen by the reference's camera
    ref_i, r1 = f.index(names[0]), idx[0]
    rows = np.flatnonzero((prob.cam == ref_i) & (prob.own == r1))[:2]
    assert len(rows) == 2
    g = fresh()
    assert g.update(prob.take(rows)).accepted
    ratio = eigh(g.covariance(names[1]), P6, eigvals_only=True)  # posterior over prior, per direction
    assert np.sum(np.abs(ratio - 1) < 1e-6) == 2 and np.sum(ratio < 0.9) == 4, ratio
    assert np.allclose(g.covariance(names[2]), P6)  # the other robot: uncorrelated, untouched
