"""The team filter's prediction with the robots' odometry
(:class:`mutloc.core.team_filter.TeamFilter`; SPEC "The robots' own motion
and clocks").

Between two times each tracked robot ``i`` moves by its own motion, then
the reference's motion moves every relative pose:

    T_ref_i  <-  U^-1  M_i(T_ref_i)

- ``U``: the reference's odometry increment over the interval (the
  reference's frame at the end in its frame at the start), where its
  odometry covers the interval; else the identity.
- ``M_i``: with robot ``i``'s odometry increment ``D_i`` and ``U`` both
  known, ``T D_i`` (the pose moves by the odometry alone; the velocity,
  unused, is a random walk); with ``D_i`` alone, the constant-velocity
  model on top of it (``R <- exp(w dt) R R_D``, ``t <- t + R t_D + v dt``:
  the velocity carries the reference's unknown motion); without ``D_i``,
  the constant-velocity model alone (with ``U`` known the velocity is the
  robot's own motion, expressed in the reference's frame).
- With ``U``, each velocity is rotated into the reference's new frame.

The error state is the filter's (SPEC perturbations ``R <- exp(dtheta) R``,
``t <- t + dt``, then ``dw``, ``dv``); an increment's covariance is in the
same convention in the robot's frame at the interval's start
(:class:`~mutloc.core.odometry.OdometryIncrement`).  The transition is
block diagonal (one 12x12 block per robot, kept for the smoother); the
noise is not: ``U``'s error moves every robot's pose, so it enters every
pair's correlation (``Q += L Sigma_U L^T`` over the whole state).

No I/O here.
"""

from __future__ import annotations

import numpy as np

from .filter import STATE_DIM, cv_transition
from .geometry import skew, so3_exp
from .odometry import OdometryIncrement

__all__ = ["odometry_predict"]


def _robot_step(R: np.ndarray, t: np.ndarray, vel: np.ndarray, dt: float, inc: OdometryIncrement | None,
                pure: bool, qa: float, ql: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """One robot's own motion: ``(R', t', F, Q)`` (see the module's text)."""
    F = np.eye(STATE_DIM)
    Q = np.zeros((STATE_DIM, STATE_DIM))
    q = np.array([qa] * 3 + [ql] * 3)
    if pure:
        Q[6:, 6:] = np.diag(q * dt)
        E = np.eye(3)
        Rn, tn = R, t
    else:
        cv_transition(vel, dt, F)
        E = F[:3, :3].copy()
        idx = np.arange(6)
        Q[idx, idx] = q * dt**3 / 3.0
        Q[idx, idx + 6] = Q[idx + 6, idx] = q * dt**2 / 2.0
        Q[idx + 6, idx + 6] = q * dt
        Rn, tn = so3_exp(vel[:3] * dt) @ R, t + vel[3:] * dt
    if inc is None:
        return Rn, tn, F, Q
    RD, tD = inc.pose.R, inc.pose.t
    Rt = R @ tD
    F[3:6, :3] = -skew(Rt)
    G = np.zeros((6, 6))
    G[:3, :3] = E @ R
    G[3:, 3:] = R
    Q[:6, :6] += G @ inc.covariance @ G.T
    return Rn @ RD, tn + Rt, F, Q


def odometry_predict(R: np.ndarray, t: np.ndarray, vel: np.ndarray, tracked: list[int],
                     covariances: list[np.ndarray], dt: float, qa: float, ql: float,
                     own: dict[int, OdometryIncrement], reference: OdometryIncrement | None
                     ) -> tuple[list[np.ndarray], np.ndarray]:
    """Move the ``tracked`` robots (their rows of ``R``, ``t``, ``vel``, in
    place) over ``dt`` seconds by their odometry increments ``own`` (robot
    index -> increment; a robot not in it: the constant-velocity model) and
    the ``reference``'s increment (None: unknown), and propagate each joint
    covariance of ``covariances`` (``F P F^T + Q``, new arrays).  Returns the
    new covariances and the transition's blocks (k x 12 x 12, state order)."""
    k = len(tracked)
    N = STATE_DIM * k
    F = np.empty((k, STATE_DIM, STATE_DIM))
    Q = np.zeros((N, N))
    for x, i in enumerate(tracked):
        o = STATE_DIM * x
        inc = own.get(i)
        R[i], t[i], F[x], Q[o:o + STATE_DIM, o:o + STATE_DIM] = _robot_step(
            R[i], t[i], vel[i], dt, inc, inc is not None and reference is not None, qa, ql)
    if reference is not None:
        RUt, tU = reference.pose.R.T, reference.pose.t
        A = np.zeros((STATE_DIM, STATE_DIM))
        for b in range(4):
            A[3 * b:3 * b + 3, 3 * b:3 * b + 3] = RUt
        L = np.zeros((N, 6))  # the state's error after U^-1 with respect to U's error
        for x, i in enumerate(tracked):
            o = STATE_DIM * x
            L[o:o + 3, :3] = -RUt
            L[o + 3:o + 6, :3] = RUt @ skew(t[i] - tU)
            L[o + 3:o + 6, 3:] = -RUt
            L[o + 6:o + 9, :3] = RUt @ skew(vel[i, :3])
            L[o + 9:o + 12, :3] = RUt @ skew(vel[i, 3:])
            F[x] = A @ F[x]
            Q[o:o + STATE_DIM, :] = A @ Q[o:o + STATE_DIM, :]
            Q[:, o:o + STATE_DIM] = Q[:, o:o + STATE_DIM] @ A.T
            R[i] = RUt @ R[i]
            t[i] = RUt @ (t[i] - tU)
            vel[i, :3] = RUt @ vel[i, :3]
            vel[i, 3:] = RUt @ vel[i, 3:]
        Q += L @ reference.covariance @ L.T
    out = []
    for P in covariances:
        FP = np.empty_like(P)
        for x in range(k):
            s = slice(STATE_DIM * x, STATE_DIM * (x + 1))
            FP[s] = F[x] @ P[s]
        FPF = np.empty_like(P)
        for x in range(k):
            s = slice(STATE_DIM * x, STATE_DIM * (x + 1))
            FPF[:, s] = FP[:, s] @ F[x].T
        FPF += Q
        out.append(np.ascontiguousarray(0.5 * (FPF + FPF.T)))
    return out, F
