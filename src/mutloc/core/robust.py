"""Finding the observations that do not fit: the largest consistent set.

A wrong detection (a blob of another object, a marker on the wrong robot)
pulls the least-squares pose away and fails the chi-square test.  With five
or more observations the redundancy says which one is wrong: every minimal
subset's poses are hypotheses, each scored by how many observations it
explains within their noise; the best hypothesis's inliers are refined, the
rest tested again one by one, and what is left out is named.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from numba import njit

from ..errors import MutlocError
from .consistency import Consistency, chi2_quantile, consistency
from .estimate import PairProblem, Solution, estimate
from .pose import Pose
from .refine import MODE_PIXEL, WS_SIZE, cost_into, lm_refine, residuals, tangent_bases

__all__ = ["RobustResult", "observation_errors", "largest_consistent_set", "other_consistent_poses", "MIN_VERIFIABLE",
           "other_poses_kernel", "pose_mahalanobis", "covariance_nonlinearity", "NONLINEARITY_LIMIT"]

#: Fewest observations whose fit can be tested (2n - 6 > 0).
MIN_VERIFIABLE = 4
# Per-observation gate (two coordinates): looser than the joint test, since a
# hypothesis from three noisy observations is itself off by some noise.
_OBS_CONFIDENCE = 0.9999


@njit(cache=True)
def observation_errors_kernel(side, pts, meas, basis, Kp, dp, Kq, dq, mode, wt, Rc, tc, out):
    """``out[c, k]``: squared residual of observation k under candidate c, weighted (inf behind a camera)."""
    n = side.shape[0]
    r = np.empty(2)
    J = np.empty((1, 6))
    ws = np.empty(WS_SIZE)
    for c in range(Rc.shape[0]):
        for k in range(n):
            ok = residuals(side[k:k + 1], pts[k:k + 1], meas[k:k + 1], basis[k:k + 1], Kp, dp, Kq, dq, mode,
                           wt[k:k + 1], Rc[c], tc[c], r, J, False, ws)
            out[c, k] = r[0] * r[0] + r[1] * r[1] if ok else np.inf


def _args(problem: PairProblem) -> tuple:
    if problem.frames is not None:  # rays from several centres: already in pixel units
        return problem.kernel_args()
    n = len(problem.side)
    basis = np.empty((n, 3, 3))
    tangent_bases(problem.bearings, basis)
    (Kp, Kq), (dp, dq) = problem.K, problem.dist
    return (problem.side, problem.points, problem.pixels, basis, Kp, dp, Kq, dq, MODE_PIXEL, problem.wt)


def observation_errors(problem: PairProblem, Rs: np.ndarray, ts: np.ndarray) -> np.ndarray:
    """Squared pixel residual of every observation under every pose ``(Rs, ts)``: (poses, n), each in
    units of its own noise (divided by its ``sigma_scale`` squared)."""
    Rs = np.ascontiguousarray(Rs, dtype=float).reshape(-1, 3, 3)
    ts = np.ascontiguousarray(ts, dtype=float).reshape(-1, 3)
    out = np.empty((len(Rs), len(problem.side)))
    observation_errors_kernel(*_args(problem), Rs, ts, out)
    return out


@dataclass
class RobustResult:
    """The solution on the kept observations (``keep``: indices into the problem)."""

    solution: Solution
    keep: np.ndarray
    test: Consistency


def _sub(problem: PairProblem, idx: np.ndarray) -> PairProblem:
    labels = problem.labels
    return PairProblem.trusted(problem.side[idx], problem.points[idx], problem.bearings[idx],
                               None if problem.pixels is None else problem.pixels[idx], problem.K, problem.dist,
                               None if labels is None else [labels[int(i)] for i in idx],
                               None if problem.sigma_scale is None else problem.sigma_scale[idx],
                               None if problem.frames is None else np.ascontiguousarray(problem.frames[idx]))


def largest_consistent_set(problem: PairProblem, first: Solution, sigma: float,
                           confidence: float) -> RobustResult | None:
    """The largest subset of at least :data:`MIN_VERIFIABLE` observations that
    passes the chi-square test, from the hypotheses of ``first`` (the
    all-observation solution, whose candidates come from every minimal subset).
    None when no such subset is found."""
    n = len(problem.side)
    if n <= MIN_VERIFIABLE:
        return None
    gate = chi2_quantile(_OBS_CONFIDENCE, 2) * sigma**2
    cand = first.candidates
    err = observation_errors(problem, cand.R, cand.t)
    inl = err <= gate
    count = inl.sum(axis=1)
    score = np.where(inl, err, 0.0).sum(axis=1)
    order = np.lexsort((score, -count))
    tried: set[bytes] = set()
    found: list[RobustResult] = []
    for c in order[:8]:
        keep = np.flatnonzero(inl[c])
        if len(keep) < MIN_VERIFIABLE or keep.tobytes() in tried:
            continue
        tried.add(keep.tobytes())
        res = _refine_set(problem, keep, sigma, confidence, gate)
        if res is not None and not any(np.array_equal(res.keep, f.keep) for f in found):
            found.append(res)
    if not found:
        return None
    size = max(len(f.keep) for f in found)
    best = min((f for f in found if len(f.keep) == size), key=lambda f: f.solution.cost)
    # Another set as large that passes too, with a pose the first one's
    # covariance rules out: the data cannot say which observation is wrong.
    info = best.solution.information / sigma**2
    limit = chi2_quantile(0.999, 6)
    for f in found:
        if len(f.keep) == size and f is not best:
            d = _pose_difference(f.solution, best.solution)
            if d @ info @ d > limit:
                return None
    return best


#: Fewest observations, and fewest of each robot, for which the search for a second pose may start from the
#: roots of the first minimal subset alone (see :func:`other_consistent_poses`).
SUBSET_SEARCH_MIN_OBS = 7
SUBSET_SEARCH_MIN_SIDE = 2


def other_consistent_poses(problem: PairProblem, first: Solution, sigma: float, confidence: float,
                           tries: int = 6) -> list[Pose]:
    """Optima other than ``first`` that pass the chi-square test too and that
    ``first``'s covariance rules out (beyond its 99.9 % ellipsoid): refined
    from the best-ranked of ``first``'s candidates outside that ellipsoid
    (at most ``tries`` refinements).  Not empty means the observations fit
    two different poses (a robot seen by one camera through four markers at
    range, typically) and neither may be reported as solved.

    The candidates are every minimal subset's, except when ``first`` came
    from one subset tying both robots (``estimate(accept=...)``) and both
    robots saw at least :data:`SUBSET_SEARCH_MIN_SIDE` markers, at least
    :data:`SUBSET_SEARCH_MIN_OBS` in all: then that subset's roots (a pose
    that fits every observation fits those three, so it lies near one of
    their roots), whose other roots all started far above the optimum."""
    n = len(problem.side)
    dof = 2 * n - 6
    if dof <= 0:
        return []
    gate = chi2_quantile(confidence, dof) * sigma**2
    info = np.ascontiguousarray(first.information / sigma**2)
    limit = chi2_quantile(0.999, 6)
    Rc, tc, costs = _search_starts(problem, first)
    Rout = np.empty((max(tries, 1), 3, 3))
    tout = np.empty((max(tries, 1), 3))
    # ranked by their cost before refinement: a start far above the gate lies in no consistent basin
    nf = other_poses_kernel(*problem.kernel_args(), Rc, tc, costs, np.ascontiguousarray(first.pose.R),
                            np.ascontiguousarray(first.pose.t), info, limit, 50.0 * gate, gate, tries, 50, Rout, tout)
    return [Pose(Rout[i].copy(), tout[i].copy()) for i in range(nf)]


def _search_starts(problem: PairProblem, first: Solution) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Where :func:`other_consistent_poses` starts, best first: ``(R, t, cost before refinement)``."""
    roots = first.extra.get("subset_roots")
    if roots is not None and not first.candidates_known:
        side = problem.side
        n1 = int(side.sum())
        if len(side) >= SUBSET_SEARCH_MIN_OBS and min(n1, len(side) - n1) >= SUBSET_SEARCH_MIN_SIDE:
            R, t, c = roots
            o = np.argsort(c, kind="stable")
            return np.ascontiguousarray(R[o]), np.ascontiguousarray(t[o]), np.ascontiguousarray(c[o])
    cand = first.candidates
    return (np.ascontiguousarray(cand.R), np.ascontiguousarray(cand.t),
            np.ascontiguousarray(first.candidate_costs))


@njit(cache=True)
def _rotvec_into(R, v):
    """Rotation vector of R into v (3,), as :func:`_rotvecs`."""
    c = min(1.0, max(-1.0, (R[0, 0] + R[1, 1] + R[2, 2] - 1.0) / 2.0))
    angle = np.arccos(c)
    s = np.sin(angle)
    if s < 1e-8 and angle > 1.0:  # a half turn: the axis from the symmetric part
        for a in range(3):
            v[a] = np.sqrt(max((R[a, a] + 1.0) / 2.0, 0.0)) * np.pi
        return
    scale = 0.5 if s < 1e-8 else angle / (2.0 * s)
    v[0] = (R[2, 1] - R[1, 2]) * scale
    v[1] = (R[0, 2] - R[2, 0]) * scale
    v[2] = (R[1, 0] - R[0, 1]) * scale


@njit(cache=True)
def pose_mahalanobis(Ra, ta, Rb, tb, info):
    """``d^T info d`` with ``d`` = (rotation vector of ``Ra Rb^T``, ``ta - tb``)."""
    M = np.empty((3, 3))
    for i in range(3):
        for j in range(3):
            M[i, j] = Ra[i, 0] * Rb[j, 0] + Ra[i, 1] * Rb[j, 1] + Ra[i, 2] * Rb[j, 2]
    d = np.empty(6)
    _rotvec_into(M, d[:3])
    for a in range(3):
        d[3 + a] = ta[a] - tb[a]
    q = 0.0
    for i in range(6):
        for j in range(6):
            q += d[i] * info[i, j] * d[j]
    return q


@njit(cache=True)
def _far_from_all(R, t, R0, t0, Rf, tf, nf, info, limit):
    if pose_mahalanobis(R, t, R0, t0, info) <= limit:
        return False
    for f in range(nf):
        if pose_mahalanobis(R, t, Rf[f], tf[f], info) <= limit:
            return False
    return True


@njit(cache=True)
def other_poses_kernel(side, pts, meas, basis, Kp, dp, Kq, dq, mode, wt, Rc, tc, costs, R0, t0, info, limit,
                       start_gate, gate, tries, max_iter, Rout, tout):
    """The loop of :func:`other_consistent_poses`: starts ``(Rc, tc)`` best first whose ``costs`` are at most
    ``start_gate`` and that lie outside the ellipsoid ``limit`` of ``info`` around (R0, t0) and around every
    pose found so far are refined (at most ``tries``); those refined to at most ``gate`` and still outside go
    to Rout/tout.  Returns how many."""
    nf = 0
    attempts = 0
    R = np.empty((3, 3))
    t = np.empty(3)
    H = np.empty((6, 6))
    for i in range(Rc.shape[0]):
        if attempts >= tries:
            break
        if not costs[i] <= start_gate:
            continue
        if not _far_from_all(Rc[i], tc[i], R0, t0, Rout, tout, nf, info, limit):
            continue
        attempts += 1
        R[:, :] = Rc[i]
        t[:] = tc[i]
        c, _ = lm_refine(side, pts, meas, basis, Kp, dp, Kq, dq, mode, wt, R, t, max_iter, H)
        if c <= gate and _far_from_all(R, t, R0, t0, Rout, tout, nf, info, limit):
            Rout[nf] = R
            tout[nf] = t
            nf += 1
    return nf


#: How far (as a fraction) the cost at the covariance's 3-sigma boundary, along its least-determined direction,
#: may differ from the quadratic model's 9 sigma^2 before the covariance is said not to describe the pose's
#: uncertainty (:func:`covariance_nonlinearity`).
NONLINEARITY_LIMIT = 1.0


def covariance_nonlinearity(problem: PairProblem, pose: Pose, covariance: np.ndarray, sigma: float,
                            k: float = 3.0) -> float:
    """How badly the linearized covariance describes the cost around ``pose``: along the
    least-determined direction (the largest eigenvector of the correlation matrix, scaled back onto the
    ``k``-sigma ellipsoid, so the answer does not depend on units), the rise of the cost both ways over the
    quadratic model's ``k^2 sigma^2``, as ``max |rise / predicted - 1|``: 0 for a problem that is linear
    there, inf when a marker would leave its camera's view.  A far robot seen through a few markers close
    together in one lens has a cost that is far from quadratic within its own error ellipsoid; the
    covariance then misstates the error (5 sigma and worse happen)."""
    return float(nonlinearity_kernel(*problem.kernel_args(), np.ascontiguousarray(pose.R),
                                     np.ascontiguousarray(pose.t), np.ascontiguousarray(covariance, dtype=float),
                                     float(k), float(sigma)))


@njit(cache=True)
def _exp_times(w, sign, R, out):
    """``out = exp(sign * w) @ R`` (Rodrigues)."""
    x, y, z = sign * w[0], sign * w[1], sign * w[2]
    th = np.sqrt(x * x + y * y + z * z)
    if th < 1e-8:
        a, b = 1.0, 0.5
    else:
        a, b = np.sin(th) / th, (1.0 - np.cos(th)) / (th * th)
    W = np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])
    E = np.eye(3) + a * W + b * (W @ W)
    out[:, :] = E @ R


@njit(cache=True)
def nonlinearity_kernel(side, pts, meas, basis, Kp, dp, Kq, dq, mode, wt, R, t, C, k, sigma):
    """:func:`covariance_nonlinearity` in one compiled call."""
    d = np.empty(6)
    for i in range(6):
        if not C[i, i] > 0.0:
            return np.inf
        d[i] = np.sqrt(C[i, i])
    Cn = np.empty((6, 6))
    for i in range(6):
        for j in range(6):
            Cn[i, j] = C[i, j] / (d[i] * d[j])
    w, V = np.linalg.eigh(Cn)
    s = k * np.sqrt(max(w[5], 0.0))
    u = np.empty(6)
    for i in range(6):
        u[i] = s * d[i] * V[i, 5]
    r = np.empty(2 * side.shape[0])
    J = np.empty((1, 6))
    ws = np.empty(WS_SIZE)
    c0 = cost_into(side, pts, meas, basis, Kp, dp, Kq, dq, mode, wt, R, t, r, J, ws)
    R2 = np.empty((3, 3))
    t2 = np.empty(3)
    worst = 0.0
    for sign in (1.0, -1.0):
        _exp_times(u[:3], sign, R, R2)
        for a in range(3):
            t2[a] = t[a] + sign * u[3 + a]
        c = cost_into(side, pts, meas, basis, Kp, dp, Kq, dq, mode, wt, R2, t2, r, J, ws)
        rise = (c - c0) / (k * k * sigma * sigma)
        if not np.isfinite(rise):
            return np.inf
        worst = max(worst, abs(rise - 1.0))
    return worst


def _rotvecs(R: np.ndarray) -> np.ndarray:
    """Rotation vectors of a stack of rotations (..., 3, 3), vectorised; near a half turn (where the axis
    from the skew part is ill-conditioned) the length is right and the direction approximate, enough to
    tell poses apart."""
    c = np.clip((np.trace(R, axis1=-2, axis2=-1) - 1.0) / 2.0, -1.0, 1.0)
    angle = np.arccos(c)
    w = np.stack([R[..., 2, 1] - R[..., 1, 2], R[..., 0, 2] - R[..., 2, 0], R[..., 1, 0] - R[..., 0, 1]], axis=-1)
    s = np.sin(angle)
    small = s < 1e-8
    scale = np.where(small, 0.5, angle / (2.0 * np.where(small, 1.0, s)))
    v = w * scale[..., None]
    near_pi = small & (angle > 1.0)
    if np.any(near_pi):  # a half turn: the axis from the symmetric part
        d = np.sqrt(np.clip((np.diagonal(R, axis1=-2, axis2=-1) + 1.0) / 2.0, 0.0, None))
        v = np.where(near_pi[..., None], d * np.pi, v)
    return v


def _pose_difference(a: Solution, b: Solution) -> np.ndarray:
    """(left rotation vector, translation) from b to a, the covariance's parametrisation."""
    from .geometry import so3_log

    
    return np.r_[so3_log(a.pose.R @ b.pose.R.T), a.pose.t - b.pose.t]


def _refine_set(problem: PairProblem, keep: np.ndarray, sigma: float, confidence: float,
                gate: float) -> RobustResult | None:
    """Refine on ``keep``, take back what the refined pose explains, drop the
    worst while the test fails."""
    n = len(problem.side)
    for _ in range(n):
        try:
            # a set that passes is solved from its first minimal subset when that subset's optimum is clear
            sol = estimate(_sub(problem, keep), accept=chi2_quantile(confidence, 2 * len(keep) - 6) * sigma**2
                           if confidence < 1.0 else None)
        except MutlocError:
            return None
        err = observation_errors(problem, sol.pose.R, sol.pose.t)[0]
        grown = np.flatnonzero(err <= gate)
        if len(grown) > len(keep) and set(keep.tolist()) <= set(grown.tolist()):
            keep = grown
            continue
        test = consistency(sol.cost, len(keep), sigma, confidence)
        if test.passed:
            return RobustResult(sol, keep, test)
        if len(keep) <= MIN_VERIFIABLE:
            return None
        keep = np.delete(keep, int(np.argmax(err[keep])))
    return None
