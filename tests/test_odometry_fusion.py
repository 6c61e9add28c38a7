"""The robots' odometry fused in the team filter's prediction (SPEC "The
robots' own motion and clocks"): against the simulator's truth, a robot
nobody sees for two seconds keeps a pose within a few centimetres with a
covariance that covers its error; the reference's odometry moves every
relative pose with its noise shared between them (checked against sampled
truth); bad odometry refused in one line or rejected and counted."""

import numpy as np
import pytest

from mutloc.cli.main import main
from mutloc.core.filter import STATE_DIM
from mutloc.core.geometry import so3_exp, so3_log
from mutloc.core.observations import ObservationSet
from mutloc.core.odometry import Odometry, OdometryIncrement, OdometryNoise
from mutloc.core.pose import Pose
from mutloc.core.team_odometry import odometry_predict
from mutloc.errors import OdometryError
from mutloc.io import save_rig
from mutloc.io.logs import write_observation_log
from mutloc.io.trajectory import write_tum
from mutloc.sim.odometry import drifting_odometry, odometry_times
from mutloc.sim.team import TeamScene, random_team, team_motion
from mutloc.track.filtering import FilterOptions
from mutloc.track.team import track_team_log

GAP = (2.0, 4.0)
FPS = 30.0


def _scenario(seed: int, duration: float = 5.0):
    """Two robots driving circles at up to 0.72 m/s, both seen at 30 fps (1 px)
    but for GAP; each robot's odometry at 50 Hz with 1 % / 0.3 deg/m drift."""
    scene = random_team(2, np.random.default_rng(seed), one_way=0.0)
    at = team_motion(scene, seed=seed, amplitude=0.3, speed=0.6)
    rng = np.random.default_rng([seed, 77])
    log, truth = [], []
    for k in range(int(duration * FPS)):
        t = k / FPS
        snap = TeamScene(scene.rig, at(t), scene.links, scene.max_range)
        obs = snap.observations(1.0, rng)
        if GAP[0] <= t < GAP[1]:
            obs = obs.take(np.empty(0, np.int64))
        log.append((t, ObservationSet.trusted(obs.observer, obs.marker, obs.uv, time=t)))
        truth.append(snap.truth()["r1"])
    times = odometry_times(0.0, duration, 50.0)
    noise = OdometryNoise(distance=0.01, deg_per_m=0.3)  # the drift's own figures
    odo = {n: Odometry(times, drifting_odometry(lambda t, n=n: at(t)[n], times, drift_pct=1.0, deg_per_m=0.3,
                                                seed=seed, stream=k), source=n, noise=noise)
           for k, n in enumerate(scene.names)}
    return scene.rig, log, truth, odo


def _gap_errors(rows, log, truth):
    """(rows in the gap, with a pose; translation errors (m); NEES) of the gap's rows."""
    n, errs, nees = 0, [], []
    for row, (t, _), T in zip(rows, log, truth):
        if not GAP[0] <= t < GAP[1]:
            continue
        n += 1
        if row.estimate is None:
            continue
        e = np.r_[so3_log(T.R @ row.estimate.pose.R.T), T.t - row.estimate.pose.t]
        errs.append(float(np.linalg.norm(e[3:])))
        nees.append(float(e @ np.linalg.solve(row.estimate.covariance, e)))
    return n, np.array(errs), np.array(nees)


@pytest.mark.parametrize("seed", [0, 1])
def test_unseen_for_two_seconds_the_odometry_keeps_the_pose_honestly(seed):
    """Both robots' odometry: every row of the two unseen seconds has a pose,
    within a few cm of the truth (median <= 3 cm, worst <= 8 cm), none beyond
    5 sigma (NEES < 45, 6 dof) and the NEES not far below its 6 either (the
    covariance is not inflated past use).  Without odometry the same log
    loses the robot or coasts it tens of cm off."""
    rig, log, truth, odo = _scenario(seed)
    rows = track_team_log(rig, log, "r0", progress=False, filter=FilterOptions(odometry=odo)).tracks["r1"].rows
    n, errs, nees = _gap_errors(rows, log, truth)
    assert n == 60 and len(errs) == n
    assert np.median(errs) <= 0.03 and errs.max() <= 0.08
    assert nees.max() < 45.0 and 0.2 < nees.mean() / 6 < 3.0
    rows = track_team_log(rig, log, "r0", progress=False).tracks["r1"].rows
    n, errs, _ = _gap_errors(rows, log, truth)
    assert len(errs) < n or np.median(errs) > 0.1


def _random_spd(rng, n, scale):
    A = rng.normal(size=(n, n))
    return scale * (A @ A.T / n + 0.2 * np.eye(n))


@pytest.mark.parametrize("reference", [True, False])
def test_the_references_odometry_moves_every_pose_with_its_noise_shared(reference):
    """One prediction of a three-robot team (r0 the reference, with odometry
    or, ``reference`` False, without; r1 with odometry; r2 without, constant
    velocity) against sampled truth: the initial state, the increments and
    the velocity drawn from their covariances, each sample moved exactly
    (``U^-1 T D``, ``U^-1 CV(T)``; without ``U``: ``CV(T D)``, ``CV(T)``).
    The sampled errors' covariance matches the predicted joint covariance
    entry by entry (as correlations), the cross-robot blocks included --
    which only the reference's shared noise correlates here."""
    rng = np.random.default_rng(5)
    R = np.stack([np.eye(3)] + [so3_exp(rng.normal(0, 1, 3)) for _ in range(2)])
    t = np.array([[0.0, 0, 0], [2.0, 0.1, 1.0], [-1.0, 0.2, 2.5]])
    vel = np.array([np.zeros(6), rng.normal(0, 0.3, 6), rng.normal(0, 0.3, 6)])
    tracked, dt = [1, 2], 0.4
    P0 = np.zeros((2 * STATE_DIM,) * 2)
    for x in range(2):  # independent robots before: any correlation after comes from U
        s = slice(STATE_DIM * x, STATE_DIM * (x + 1))
        P0[s, s] = _random_spd(rng, STATE_DIM, 1e-4)
    D = OdometryIncrement(0.0, dt, Pose(so3_exp([0.05, 0.3, -0.02]), np.array([0.5, 0.0, 1.5])),
                          _random_spd(rng, 6, 4e-4))
    U = OdometryIncrement(0.0, dt, Pose(so3_exp([0.02, -0.4, 0.05]), np.array([-0.05, 0.01, 0.3])),
                          _random_spd(rng, 6, 4e-4))
    qa = ql = 1e-12
    Rp, tp, vp = R.copy(), t.copy(), vel.copy()
    (P,), F = odometry_predict(Rp, tp, vp, tracked, [P0], dt, qa, ql, {1: D}, U if reference else None)
    assert F.shape == (2, STATE_DIM, STATE_DIM)

    n = 6000
    L0 = np.linalg.cholesky(P0)
    LD, LU = np.linalg.cholesky(D.covariance), np.linalg.cholesky(U.covariance)
    errs = np.empty((n, 2 * STATE_DIM))
    for s in range(n):
        d0 = L0 @ rng.normal(size=2 * STATE_DIM)
        dD, dU = LD @ rng.normal(size=6), LU @ rng.normal(size=6)
        RD, tD = so3_exp(dD[:3]) @ D.pose.R, D.pose.t + dD[3:]
        RU, tU = so3_exp(dU[:3]) @ U.pose.R, U.pose.t + dU[3:]
        for x, i in enumerate(tracked):
            o = STATE_DIM * x
            Ri, ti, vi = so3_exp(d0[o:o + 3]) @ R[i], t[i] + d0[o + 3:o + 6], vel[i] + d0[o + 6:o + 12]
            if i == 1:
                Ri, ti = Ri @ RD, Ri @ tD + ti
            if i == 2 or not reference:
                Ri, ti = so3_exp(vi[:3] * dt) @ Ri, ti + vi[3:] * dt
            if reference:
                Ri, ti, vi = RU.T @ Ri, RU.T @ (ti - tU), np.r_[RU.T @ vi[:3], RU.T @ vi[3:]]
            errs[s, o:o + 12] = np.r_[so3_log(Ri @ Rp[i].T), ti - tp[i], vi - vp[i]]
    C = np.cov(errs.T)
    sd = np.sqrt(np.diag(P))
    assert (np.abs(errs.mean(axis=0)) / sd).max() < 0.08  # unbiased to first order
    corr_diff = np.abs(C - P) / np.outer(sd, sd)
    assert corr_diff.max() < 0.08
    cross = np.abs(P[:STATE_DIM, STATE_DIM:]) / np.outer(sd[:STATE_DIM], sd[STATE_DIM:])
    if reference:
        assert cross.max() > 0.3  # the shared noise: the robots are now strongly correlated
    else:
        assert cross.max() < 1e-12
    assert np.allclose(np.diag(C) / np.diag(P), 1.0, atol=0.1)


def _small_log(tmp_path):
    """A rig, a 2 s log of two moving robots and r1's odometry as a TUM file."""
    rig, log, _, odo = _scenario(0, duration=2.0)
    save_rig(rig, tmp_path / "rig.yaml")
    write_observation_log(tmp_path / "log.jsonl", [obs for _, obs in log])
    o = odo["r1"]
    write_tum(tmp_path / "odo.tum", o.times, o.poses)
    return o


def _track(tmp_path, *extra, team=True):
    return main(["track", "--rig", str(tmp_path / "rig.yaml"), "--observations", str(tmp_path / "log.jsonl"),
                 *(["--reference", "r0"] if team else []), "--out", str(tmp_path / "out"), "--no-progress", *extra])


def test_track_takes_odometry_and_refuses_bad_odometry_in_one_line(tmp_path, capsys):
    o = _small_log(tmp_path)
    assert _track(tmp_path, "--odometry", f"r1={tmp_path / 'odo.tum'}") == 0
    out = capsys.readouterr()
    assert "rejected" not in out.err and "not used" not in out.err and "Traceback" not in out.err
    assert _track(tmp_path, "--odometry", f"r1={tmp_path / 'odo.tum'}", team=False) == 0  # a pair's track too
    capsys.readouterr()
    lines = (tmp_path / "odo.tum").read_text().splitlines()
    jump = lines[3].split()
    jump[1] = str(float(jump[1]) + 3.0)  # 3 m off for one sample (150 m/s)
    bad = {"jump": lines[:3] + [" ".join(jump)] + lines[4:],
           "nan": [ln if k != 3 else "0.06 nan 0 0 0 0 0 1" for k, ln in enumerate(lines)],
           "backwards": ["1.0 0 0 0 0 0 0 1", "0.5 0 0 0 0 0 0 1", "0.2 0 0 0 0 0 0 1"]}
    for name, text in bad.items():
        (tmp_path / f"{name}.tum").write_text("\n".join(text) + "\n")
    # stamps on another clock: the track runs without it, and says so
    shifted = [" ".join([str(float(ln.split()[0]) + 1000.0)] + ln.split()[1:]) for ln in lines]
    (tmp_path / "shifted.tum").write_text("\n".join(shifted) + "\n")
    assert _track(tmp_path, "--odometry", f"r1={tmp_path / 'shifted.tum'}") == 0
    err = capsys.readouterr().err
    assert "odometry of r1" in err and "not used" in err and "Traceback" not in err
    # one sample that jumps, amid good ones: rejected and counted, the rest used
    assert _track(tmp_path, "--odometry", f"r1={tmp_path / 'jump.tum'}") == 0
    err = capsys.readouterr().err
    assert "odometry of r1" in err and "1 jump" in err and "Traceback" not in err
    # a file that cannot be used (a NaN line, time going back to leave one sample, an unknown robot, no file,
    # no filter to fuse it): refused in one line, non-zero exit
    for args in (["--odometry", f"r1={tmp_path / 'nan.tum'}"], ["--odometry", f"r1={tmp_path / 'backwards.tum'}"],
                 ["--odometry", f"r7={tmp_path / 'odo.tum'}"], ["--odometry", f"r1={tmp_path / 'missing.tum'}"],
                 ["--odometry", f"r1={tmp_path / 'odo.tum'}", "--filter", "none"]):
        assert _track(tmp_path, *args) != 0
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1 and "Traceback" not in err and "odometry" in err, (args, err)
    with pytest.raises(OdometryError, match="no robot 'r7'"):
        track_team_log(*_scenario(0, duration=0.5)[:2], "r0", progress=False,
                       filter=FilterOptions(odometry={"r7": o}))
