"""Observations of nearby times fitted together (mutloc.core.nearby_times)
and the rig check it gives records that fit any rig on their own (issue 38):
two balls per robot, free-running cameras, every record one camera's two
observations."""

import numpy as np
import pytest

from mutloc.core.geometry import so3_exp
from mutloc.core.observations import ObservationSet
from mutloc.core.nearby_times import fitted_together, moved_back
from mutloc.core.team import TeamProblem, team_residuals_any
from mutloc.io import load_rig
from mutloc.sim.calibration import perturb_rig
from mutloc.sim.tracking import camera_records
from mutloc.sim.world import standard_rig
from mutloc.team import in_rays, team_problem
from mutloc.track.frames import expanded_rig
from mutloc.track.rig_check import RIG_HINT
from mutloc.track.tracker import track_log


def _residuals(problem, R, t):
    m = len(problem.cam)
    r, J = np.empty(2 * m), np.empty((m, 2, 6))
    assert team_residuals_any(problem.cam, problem.own, problem.points, problem.uv, problem.wt, problem.K,
                              problem.dist, problem.fr, R, t, r, J, J.copy(), False)
    return r


def _scene(rng, n=6):
    """Three robots (0 the reference), rays of robot 0's and 1's cameras at markers of the others, at
    poses ``R``, ``t`` of an earlier time; velocities that move them ``dt`` on to the later poses."""
    R = np.stack([np.eye(3)] + [so3_exp(rng.normal(scale=0.4, size=3)) for _ in range(2)])
    t = np.stack([np.zeros(3), [0.3, -0.2, 3.0], [-0.5, 0.1, 2.5]])
    vel = np.r_[np.zeros((1, 6)), rng.normal(scale=[0.8, 0.8, 0.8, 1.0, 1.0, 1.0], size=(2, 6))]
    cam = np.array([0, 0, 1, 1, 2, 2, 1, 0][:n + 2], dtype=np.int64)
    own = np.array([1, 2, 0, 2, 0, 1, 2, 1][:n + 2], dtype=np.int64)
    pts = rng.normal(scale=0.2, size=(len(cam), 3))
    frames = np.empty((len(cam), 4, 3))
    for j in range(len(cam)):
        a, b = cam[j], own[j]
        X = R[a].T @ (R[b] @ pts[j] + t[b] - t[a])
        o = rng.normal(scale=0.05, size=3)  # (a camera off the robot's origin)
        d = X - o + rng.normal(scale=0.01, size=3)  # (not exactly through the marker: residuals not zero)
        d /= np.linalg.norm(d)
        e1 = np.cross(d, [0.0, 0.0, 1.0] if abs(d[2]) < 0.9 else [1.0, 0.0, 0.0])
        e1 /= np.linalg.norm(e1)
        frames[j] = [400 * e1, 400 * np.cross(d, e1), d, o]
    problem = TeamProblem(cam, own, pts, np.zeros((len(cam), 2)), np.tile(np.eye(3), (3, 1, 1)), np.zeros((3, 8)),
                          None, frames)
    return problem, R, t, vel


def _later(R, t, vel, dt):
    """The poses ``dt`` later under the filter's motion (R <- exp(w dt) R, t <- t + v dt; the reference stays)."""
    R2, t2 = R.copy(), t.copy()
    for i in range(1, len(R)):
        R2[i] = so3_exp(dt * vel[i, :3]) @ R[i]
        t2[i] = t[i] + dt * vel[i, 3:]
    return R2, t2


@pytest.mark.parametrize("seed", range(5))
def test_rows_moved_back_are_explained_by_the_later_poses_as_the_rows_by_the_earlier_ones(seed):
    """Every residual of the moved rows at the later poses equals the original row's at the earlier poses."""
    rng = np.random.default_rng(seed)
    problem, R, t, vel = _scene(rng)
    dt = 0.04
    R2, t2 = _later(R, t, vel, dt)
    before = _residuals(problem, R, t)
    moved = moved_back(problem, R2, t2, vel, dt, 0)
    assert np.abs(before).max() > 1.0  # (the rays miss their markers: a real check)
    assert np.allclose(_residuals(moved, R2, t2), before, atol=1e-9, rtol=1e-9)
    # (not so without the motion)
    assert not np.allclose(_residuals(problem, R2, t2), before, atol=1e-3)


def _two_ball_records(pixel_sigma, seed, duration=2.0):
    rig = standard_rig("balls")
    return rig, camera_records(rig, duration=duration, offsets={"q": 1 / 60}, pixel_sigma=pixel_sigma, seed=seed)


def _rays(rig, obs):
    p, names, _ = team_problem(rig, obs)
    return in_rays(rig, names, p), names


def test_five_records_of_a_moving_pair_fitted_together_follow_chi_square():
    """p's, q's, p's, q's, p's record (1/60 s apart, each 2 balls: none testable alone), 1 px noise, the
    pose and velocity fitted: the chi-square over 20 - 12 = 8 degrees of freedom has mean 8 and its 99 %
    quantile is passed about 1 % of the time; with every marker of the rig 1-2 cm off it is larger."""
    rig, clean = _two_ball_records(0.0, 3, duration=1.5)
    wrong = expanded_rig(load_rig(perturb_rig(rig.to_dict(), np.random.default_rng([3, 38]))))
    rng = np.random.default_rng(0)
    right_vals, wrong_vals = [], []
    for k in range(0, len(clean.times) - 5, 5):
        ts = clean.times[k:k + 5]
        T, T_eps = clean.truth[k + 4].inverse(), clean.truth[k + 3].inverse()  # (q in p's frame: the state's)
        dt1 = ts[4] - ts[3]
        vel = np.r_[np.zeros((1, 6)), np.r_[_log(T.R @ T_eps.R.T) / dt1, (T.t - T_eps.t) / dt1][None]]
        R, t = np.stack([np.eye(3), T.R]), np.stack([np.zeros(3), T.t])
        for which, vals in ((rig, right_vals), (wrong, wrong_vals)):
            for _ in range(5):
                parts = []
                for j in range(5):
                    obs = clean.frames[k + j]
                    noisy = ObservationSet(obs.observer, obs.marker, obs.uv + rng.normal(size=obs.uv.shape),
                                           obs.time, obs.score)
                    parts.append((_rays(which, noisy)[0], ts[4] - ts[j]))
                c, d = fitted_together(parts, R, t, vel, np.array([1]), 0, 1.0)
                assert d == 8
                vals.append(c)
    right, bad = np.array(right_vals), np.array(wrong_vals)
    assert len(right) >= 80
    assert 8 * 0.85 < right.mean() < 8 * 1.15, right.mean()
    assert np.mean(right > 20.09) < 0.04  # chi2_8's 0.99 quantile
    assert bad.mean() > 1.5 * right.mean(), (bad.mean(), right.mean())


def _log(R):
    from mutloc.core.geometry import so3_log
    return so3_log(R)


@pytest.mark.parametrize("seed", [0, 1])
def test_a_two_ball_pair_with_markers_off_is_flagged_and_the_right_rig_is_not(seed):
    """Free-running cameras, every record one camera's two balls (none testable on its own): with every
    marker 1-2 cm off the track's rows say so within 4 s (the first full window: 150 records, 2.5 s); the
    right rig's never (5 s)."""
    rig, recs = _two_ball_records(1.0, seed, duration=5.0)
    records = list(zip(recs.times, recs.frames))
    good = track_log(rig, records, progress=False)
    assert not any(RIG_HINT in r.reason for r in good.rows)
    wrong = expanded_rig(load_rig(perturb_rig(rig.to_dict(), np.random.default_rng([seed, 99]))))
    bad = track_log(wrong, [(t, f) for t, f in records if t - recs.times[0] < 4.0], progress=False)
    flagged = [r.t for r in bad.rows if RIG_HINT in r.reason]
    assert flagged, "not flagged within 4 s"
