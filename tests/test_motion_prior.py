"""The constant-velocity motion prior of mutloc.core.filter (what the filter
adds over a step, and what bench/bench_filter_gtsam.py gives GTSAM's motion
factors) against the continuous-time model it claims to integrate: white
acceleration of spectral density ``q`` on each axis, integrated exactly by
Van Loan's matrix exponential (independent of the filter's own formula)."""

import numpy as np
import pytest
from scipy.linalg import expm

from mutloc.core.filter import STATE_DIM, MotionNoise, cv_predict


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


def _added(vel: np.ndarray, dt: float, q_ang: float, q_lin: float) -> np.ndarray:
    """What one prediction from a certain state (zero covariance) adds."""
    R, t, P = np.empty((3, 3)), np.empty(3), np.empty((STATE_DIM, STATE_DIM))
    cv_predict(np.eye(3), np.zeros(3), vel, np.zeros((STATE_DIM, STATE_DIM)), dt, q_ang, q_lin, R, t, P)
    return P


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
    R, t, half, two = np.empty((3, 3)), np.empty(3), _added(np.zeros(6), dt / 2, qa, ql), np.empty((12, 12))
    cv_predict(np.eye(3), np.zeros(3), np.zeros(6), half, dt / 2, qa, ql, R, t, two)
    np.testing.assert_allclose(two, _added(np.zeros(6), dt, qa, ql), rtol=1e-12, atol=1e-18)
