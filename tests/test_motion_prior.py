"""The constant-velocity motion prior of the team filter (what
mutloc.core.team_filter.TeamFilter.predict adds over a step, and what
bench/bench_filter_gtsam.py gives GTSAM's motion factors) against the
continuous-time model it claims to integrate: white acceleration of spectral
density ``q`` on each axis, integrated exactly by Van Loan's matrix
exponential (independent of the filter's own formula); and the prediction's
mean and first-order covariance against the exact motion of sampled states."""

import numpy as np
import pytest
from scipy.linalg import expm

from mutloc.core.filter import STATE_DIM, MotionNoise
from mutloc.core.geometry import so3_exp, so3_log
from mutloc.core.pose import Pose
from mutloc.core.team_filter import TeamFilter


def _van_loan(dt: float, q_ang: float, q_lin: float) -> np.ndarray:
    """``int_0^dt e^(A s) L Qc L' e^(A' s) ds`` for ``d(pose)/dt = vel``,
    ``d(vel)/dt = white noise`` (state: rotation, translation, angular, linear
    velocity): Van Loan (1978), from one exponential of a 24x24 block matrix."""
    n = STATE_DIM
    A = np.zeros((n, n))
    A[:6, 6:] = np.eye(6)
    W = np.zeros((n, n))
    W[6:9, 6:9] = q_ang * np.eye(3)
    W[9:, 9:] = q_lin * np.eye(3)
    M = np.zeros((2 * n, 2 * n))
    M[:n, :n] = -A
    M[:n, n:] = W
    M[n:, n:] = A.T
    E = expm(M * dt)
    F = E[n:, n:].T
    return F @ E[:n, n:]


def _predicted(pose: Pose, vel: np.ndarray, P: np.ndarray, dt: float, q_ang: float, q_lin: float) -> TeamFilter:
    """A team filter whose one robot is at ``pose`` with velocity ``vel`` and
    12x12 covariance ``P`` at time 0, predicted to ``dt``."""
    f = TeamFilter(["r0", "r1"], "r0", MotionNoise(angular=np.sqrt(q_ang), linear=np.sqrt(q_lin), reference_angular=0.0))
    f.time = 0.0
    f.add("r1", pose, P[:6, :6], velocity=vel, state_covariance=P)
    f.predict(dt)
    return f


def _added(vel: np.ndarray, dt: float, q_ang: float, q_lin: float) -> np.ndarray:
    """What one prediction from a certain state (zero covariance) adds."""
    return _predicted(Pose.identity(), vel, np.zeros((STATE_DIM, STATE_DIM)), dt, q_ang, q_lin).P


@pytest.mark.parametrize("dt", [1 / 30, 0.1, 1.0])
def test_the_process_noise_is_the_integrated_white_acceleration(dt):
    noise = MotionNoise()
    qa, ql = noise.angular**2, noise.linear**2
    truth = _van_loan(dt, qa, ql)
    np.testing.assert_allclose(_added(np.zeros(6), dt, qa, ql), truth, rtol=1e-9, atol=1e-15)
    # Translation is linear in the velocity whatever it is: its blocks stay exact while moving.
    moving = _added(np.array([0.3, -0.2, 0.5, 1.0, 0.0, -0.5]), dt, qa, ql)
    lin = np.r_[3:6, 9:12]
    np.testing.assert_allclose(moving[np.ix_(lin, lin)], truth[np.ix_(lin, lin)], rtol=1e-9, atol=1e-15)


def test_two_half_steps_are_one_step():
    """Only an exact discretisation composes: predicting twice over dt/2 from
    rest adds what one prediction over dt does."""
    qa, ql, dt = 0.25, 1.0, 0.2
    half = _added(np.zeros(6), dt / 2, qa, ql)
    two = _predicted(Pose.identity(), np.zeros(6), half, dt / 2, qa, ql).P
    np.testing.assert_allclose(two, _added(np.zeros(6), dt, qa, ql), rtol=1e-12, atol=1e-18)


def test_prediction_moves_by_the_velocity_and_grows_the_covariance():
    """The mean moves by the exact motion; the covariance grows and is, to
    first order, that of sampled error states moved by the exact motion
    (Monte Carlo, 4000 samples)."""
    R = so3_exp([0.1, 2.0, -0.2])
    t = np.array([0.3, -0.1, 2.0])
    vel = np.array([0.0, 0.5, 0.1, 0.2, 0.0, -0.3])
    P = np.eye(STATE_DIM) * 1e-4
    f = _predicted(Pose(R, t), vel, P, 0.5, 0.01, 0.04)
    np.testing.assert_allclose(f.pose("r1").R, so3_exp(vel[:3] * 0.5) @ R, atol=1e-12)
    np.testing.assert_allclose(f.pose("r1").t, t + vel[3:] * 0.5, atol=1e-12)
    assert np.all(np.diag(f.P)[:6] > np.diag(P)[:6]) and np.allclose(f.P, f.P.T)
    rng = np.random.default_rng(0)
    L = np.diag([1e-3, 2e-3, 1e-3, 1e-2, 1e-2, 2e-2, 0.05, 0.02, 0.05, 0.1, 0.1, 0.1])
    f = _predicted(Pose(R, t), vel, L @ L.T, 0.5, 1e-12, 1e-12)
    Ro, to = f.pose("r1").R, f.pose("r1").t
    samples = []
    for _ in range(4000):
        d = L @ rng.normal(size=STATE_DIM)
        Rs, ts, ws = so3_exp(d[:3]) @ R, t + d[3:6], vel + d[6:]
        R1, t1 = so3_exp(ws[:3] * 0.5) @ Rs, ts + ws[3:] * 0.5
        samples.append(np.r_[so3_log(R1 @ Ro.T), t1 - to])
    C = np.cov(np.array(samples).T)
    np.testing.assert_allclose(np.sqrt(np.diag(C)), np.sqrt(np.diag(f.P)[:6]), rtol=0.06)
