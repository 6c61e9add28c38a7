"""Observations of a few nearby times fitted together, each robot moving
at a constant velocity between them: how a window of one-camera records
still tests the rig (issue 38).

With two markers per robot and free-running cameras every record is one
camera's two observations: four numbers for six unknowns, which any rig fits
exactly.  Five such records 1/60 s apart (p's camera, q's, p's, ...) hold
twenty numbers for the relative pose and its velocity over their 0.07 s
(twelve unknowns): fitted together they leave eight degrees of freedom that
do test the rig.  :func:`moved_back` re-expresses an earlier record's rows
so that the poses of a later time explain them (the motion from given
velocities); :func:`fitted_together` is the chi-square of rows of several
times fitted on their own, each robot's pose and velocity free, linearised
where the state is (the Gauss-Newton step's residual, exact to second order
near the optimum).  With the velocities fitted the test owes nothing to the
filter (its velocity, fitted to the same records' noise, would hide some of
it; its velocity covariance, generous, would hide more) and is chi-square
with ``2m - 12q`` degrees of freedom for ``q`` robots while the velocities
stay constant over the rows' span.

The motion: the filter's state (``R_i``, ``t_i``: robot ``i``'s pose in the
reference's frame, ``vel_i = (w_i, v_i)``) moves ``R_i <- exp(w_i dt) R_i``,
``t_i <- t_i + v_i dt`` (:func:`mutloc.core.team_kernels.team_predict`), so
robot ``i`` was ``dt`` earlier at ``T_i' = (exp(-w_i dt) R_i, t_i - v_i dt)
= T_i B_i`` with ``B_i = T_i^-1 T_i'`` (its frame then, in its frame now).
A marker point ``p`` of robot ``j`` then is where ``B_j p`` is now; a ray
(origin ``o``, direction and tangent rows) of robot ``i``'s camera then is
``B_i o``, ``R_B`` times its directions now.  The reference stays put (the
others' poses are relative to it).

No I/O.
"""

from __future__ import annotations

import numpy as np

from .geometry import so3_exp
from .team import TeamProblem, team_residuals_any

__all__ = ["moved_back", "fitted_together"]


def moved_back(problem: TeamProblem, R: np.ndarray, t: np.ndarray, vel: np.ndarray, dt: float,
               reference: int) -> TeamProblem:
    """``problem``'s rows (ray mode: :attr:`TeamProblem.frames` set), made
    ``dt`` seconds before the state ``R``, ``t``, ``vel`` (per robot, rig
    order), re-expressed so that the state's poses explain them."""
    if problem.frames is None:
        raise ValueError("moved_back needs rays (TeamProblem.frames)")
    n = R.shape[0]
    RB = np.tile(np.eye(3), (n, 1, 1))
    tB = np.zeros((n, 3))
    for i in np.unique(np.r_[problem.cam, problem.own]).tolist():
        if i == reference:
            continue
        Ri = R[i]
        RB[i] = Ri.T @ so3_exp(-dt * vel[i, :3]) @ Ri
        tB[i] = -dt * (Ri.T @ vel[i, 3:])
    own, cam = problem.own, problem.cam
    points = np.einsum("nij,nj->ni", RB[own], problem.points) + tB[own]
    frames = np.empty_like(problem.frames)
    frames[:, :3] = np.einsum("nij,nkj->nki", RB[cam], problem.frames[:, :3])
    frames[:, 3] = np.einsum("nij,nj->ni", RB[cam], problem.frames[:, 3]) + tB[cam]
    return TeamProblem(cam, own, points, problem.uv, problem.K, problem.dist, problem.wt, frames)


def _residuals(problem: TeamProblem, R: np.ndarray, t: np.ndarray, jac: bool):
    m = len(problem.cam)
    r = np.empty(2 * m)
    Ja, Jb = np.empty((m, 2, 6)), np.empty((m, 2, 6))
    ok = team_residuals_any(problem.cam, problem.own, problem.points, problem.uv, problem.wt, problem.K,
                            problem.dist, problem.fr, np.ascontiguousarray(R), np.ascontiguousarray(t), r, Ja, Jb,
                            jac)
    return (r, Ja, Jb) if ok else None


def fitted_together(parts: list[tuple[TeamProblem, float]], R: np.ndarray, t: np.ndarray, vel: np.ndarray,
                    robots: np.ndarray, reference: int, sigma: float) -> tuple[float, int]:
    """The chi-square of rows of several times fitted together on their own
    and its degrees of freedom.  ``parts``: ``(rows, dt)`` (ray mode), each
    made ``dt >= 0`` seconds before the poses ``R``, ``t`` (per robot, rig
    order); the robots' poses at that time and their velocities over the
    rows' span are fitted (every robot of ``robots``; the reference stays
    put), linearised at ``R``, ``t`` and ``vel`` (per robot); ``sigma`` the
    detections' noise (px).  Degrees of freedom: ``2m`` less the Jacobian's
    rank.  ``(nan, 0)`` without a degree of freedom or with a marker behind
    its camera."""
    moved = [moved_back(p, R, t, vel, dt, reference) if dt > 0 else p for p, dt in parts]
    joint = TeamProblem.concatenate(moved)
    m = len(joint.cam)
    got = _residuals(joint, R, t, True)
    if m == 0 or got is None:
        return float("nan"), 0
    r, Ja, Jb = got
    index = {int(x): k for k, x in enumerate(robots)}
    q = len(robots)
    H = np.zeros((2 * m, 12 * q))  # each robot's pose, then each robot's velocity
    for j in range(m):
        for side, J in ((joint.cam, Ja), (joint.own, Jb)):
            k = index.get(int(side[j]))
            if k is not None:
                H[2 * j:2 * j + 2, 6 * k:6 * k + 6] += J[j]
    # the residuals' derivative in each robot's velocity (central differences, one step per component)
    h = 1e-4
    for k, x in enumerate(robots.tolist()):
        for c in range(6):
            cols = []
            for step in (h, -h):
                v = vel.copy()
                v[x, c] += step
                back = [moved_back(p, R, t, v, dt, reference) if dt > 0 else p for p, dt in parts]
                got = _residuals(TeamProblem.concatenate(back), R, t, False)
                if got is None:
                    return float("nan"), 0
                cols.append(got[0])
            H[:, 6 * q + 6 * k + c] = (cols[0] - cols[1]) / (2 * h)
    x, _, rank, _ = np.linalg.lstsq(H / sigma, r / sigma, rcond=None)
    dof = 2 * m - int(rank)
    if dof <= 0:
        return float("nan"), 0
    e = (r - H @ x) / sigma
    return float(e @ e), dof
