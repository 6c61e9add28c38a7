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
from .refine import MODE_PIXEL, WS_SIZE, lm_refine, residuals, tangent_bases

__all__ = ["RobustResult", "observation_errors", "largest_consistent_set", "other_consistent_poses", "MIN_VERIFIABLE"]

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


def other_consistent_poses(problem: PairProblem, first: Solution, sigma: float, confidence: float,
                           tries: int = 6) -> list[Pose]:
    """Optima other than ``first`` that pass the chi-square test too and that
    ``first``'s covariance rules out (beyond its 99.9 % ellipsoid): refined
    from the best-ranked of ``first``'s candidates outside that ellipsoid
    (at most ``tries`` refinements).  Not empty means the observations fit
    two different poses (a robot seen by one camera through four markers at
    range, typically) and neither may be reported as solved."""
    n = len(problem.side)
    dof = 2 * n - 6
    if dof <= 0:
        return []
    gate = chi2_quantile(confidence, dof) * sigma**2
    info = first.information / sigma**2
    limit = chi2_quantile(0.999, 6)
    cand = first.candidates
    # ranked by their cost before refinement: a start far above the gate lies in no consistent basin
    keep = np.flatnonzero(first.candidate_costs <= 50.0 * gate)
    if not len(keep):
        return []
    Rs, ts = cand.R[keep], cand.t[keep]

    def mahalanobis(R: np.ndarray, t: np.ndarray, pose: Any) -> np.ndarray:
        d = np.concatenate([_rotvecs(R @ pose.R.T), t - pose.t], axis=-1)
        return np.einsum("...i,ij,...j->...", d, info, d)

    far = mahalanobis(Rs, ts, first.pose) > limit
    args = problem.kernel_args()
    found: list[Pose] = []
    attempts = 0
    for i in np.flatnonzero(far):
        if attempts >= tries:
            break
        if any(mahalanobis(Rs[i], ts[i], f) <= limit for f in found):
            continue
        attempts += 1
        R, t = Rs[i].copy(), ts[i].copy()
        c, _ = lm_refine(*args, R, t, 50)
        if c <= gate and all(mahalanobis(R, t, o) > limit for o in (first.pose, *found)):
            found.append(Pose(R, t))
    return found


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
            sol = estimate(_sub(problem, keep))
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
