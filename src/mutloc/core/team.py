"""Teams: every robot's pose in one reference frame from all observations at once.

The joint maximum-likelihood problem: unknowns are the poses ``T_ref_i =
(R_i, t_i)`` (``x_ref = R_i @ x_i + t_i``) of every robot but the reference
(the identity); each observation "camera ``a`` sees marker ``P`` of robot
``b``" contributes the pixel residual ``project_a(R_a^T (R_b P + t_b - t_a))
- uv`` through camera ``a``'s ``K`` and distortion.  Perturbations are those
of a pair (SPEC): ``R <- exp(dtheta) R``, ``t <- t + dt``, rotation first, so
``sigma^2 H^-1`` with ``H = J^T J`` is the joint covariance in the published
convention.

Robots with several cameras or any lens (``TeamProblem.frames``, ray
mode): each observation is a ray of its observing robot's frame with a
weighted tangent frame and an origin (:mod:`mutloc.core.rays`), and its
residual is the gnomonic one of ``R_a^T (R_b P + t_b - t_a) - o`` around
that ray, scaled by the lens's Jacobian so that it is the pixel error to
first order: costs, the chi-square test and the covariance stay in pixels.
Placements then run the pair solver in :data:`MODE_RAY` and the generalized
minimal solver on rays from the cameras' centres.  One-pinhole robots keep
the pixel residuals above (the same numbers as ever).

Each residual touches at most two 6-blocks, so ``J`` is block-sparse and
``H`` is assembled block by block; the ``6k`` square damped system is then
factorised by an envelope Cholesky with the robots in reverse Cuthill-McKee
order of the observation graph (see bench/bench_team.py).

Initialisation (:func:`initial_poses`) places robots one at a time, the
best-tied first (Prim's algorithm on the observation graph): a robot ``r``
is placed from the pair solver of :mod:`mutloc.core.estimate` between ``r``
and one placed camera ``c`` -- ``c``'s views of ``r``'s markers, plus every
view ``r`` has of markers of any placed robot, those markers expressed in
``c``'s frame (the pair solver takes any known points).  That needs three
such observations; observations of ``r`` by other placed cameras choose
among the minimal solutions and refine the start.  When that stalls, a
robot tied by observations spread over several placed cameras, or a group
of robots tied to the placed ones only together, is solved among itself and
placed as one rigid body by the generalized minimal solver
(:mod:`mutloc.core.generalized`: the placed robots as one multi-camera rig,
rays both ways).  Loops with no rigid sub-group (each link two markers)
are started from seeded random draws on their two-point rays and refined
jointly (:func:`_sampled_group`).  See :func:`initial_poses` for what is
well posed.

A cold start's optimum that fails its chi-square test, or leaves robots
unlocalized that three observations tie to the others, may come from a
wrong exact pose of a placement on three observations: :func:`solve_team`
then starts again from the other exact poses and other spanning trees and
keeps the best (:func:`_restarts`).

A robot held by few observations (:data:`AMBIGUITY_TIES`) may fit a second,
distant pose within the noise as well as its optimum; :func:`other_poses`
searches for one (as a pair's solver keeps every candidate of three
markers), and mutloc.team leaves such a robot unverified.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from numba import njit

from ..errors import DegenerateGeometryError, NoSolutionError
from .camera import project_jac_kernel, project_kernel, readonly, undistort_kernel
from .consistency import DEFAULT_CONFIDENCE, chi2_quantile
from .estimate import PER_SUBSET, minimal_subsets, solve_kernel
from .geometry import matrix_from_quaternion_xyzw, so3_exp, so3_log
from .generalized import KIND_U_RAY, KIND_W_RAY, generalized_p3p
from .refine import MODE_PIXEL, MODE_RAY, so3_exp_left

__all__ = ["TeamProblem", "TeamSolution", "initial_poses", "solve_team", "team_lm", "team_cost", "residual_norms",
           "relative_jacobian", "checked_factor", "inverse_from_factor", "other_poses", "MIN_TIES",
           "AMBIGUITY_TIES", "AMBIGUITY_SIGMAS", "judged_sigma", "misfit_robots"]

#: Observations that tie a robot to the already placed ones, at least.
MIN_TIES = 3
#: Observations each way the pair solver gets when placing a robot.
INIT_PER_SIDE = 3
#: The placement of a robot tries the pair solver on all of its observations
#: only when the start from a few fits its ties this much worse than their
#: noise allows.  The ties' cost includes the errors of the robots placed
#: before (nothing is jointly refined yet), so a start in the right basin
#: often exceeds the pure-noise gate (on 800 random teams of 3-10 robots and
#: chains, half of all placements, up to ~900x); those in a wrong basin that
#: the other candidates of the few could not rescue were 150x and more.
FALLBACK_FACTOR = 25.0
#: ``frames`` of a problem in pixel mode.
NO_FRAMES = np.empty((0, 4, 3))
# Condition number of the Jacobi-scaled information matrix beyond which
# some pose is not isolated (as for a pair).
_MAX_COND = 1e14


def _writable(a, dtype) -> np.ndarray:
    """``a`` as a C-contiguous array of ``dtype``, copied if it is read-only."""
    a = np.ascontiguousarray(a, dtype=dtype)
    return a if a.flags.writeable else a.copy()


@dataclass
class TeamProblem:
    """Observations in solver form.  Robots are indices ``0..N-1``;
    observation ``j``: camera ``cam[j]`` saw, at raw pixel ``uv[j]``, the
    marker at ``points[j]`` in robot ``own[j]``'s frame.  ``K`` (N, 3, 3)
    and ``dist`` (N, 8) per robot."""

    cam: np.ndarray
    own: np.ndarray
    points: np.ndarray
    uv: np.ndarray
    K: np.ndarray
    dist: np.ndarray
    #: (n,) each observation's weight, ``1 / sigma_scale`` (None: 1 for all).
    wt: np.ndarray | None = None
    #: (n, 4, 3) each row's ray frame in its observing robot's frame
    #: (:func:`mutloc.core.rays.ray_frames`: two weighted tangent rows, the
    #: ray's direction, its origin): ray mode, for robots with several
    #: cameras or any lens (``uv``, ``K``, ``dist`` then unused by the
    #: residuals).  None: pixel mode, each robot one pinhole camera.
    frames: np.ndarray | None = None

    def __post_init__(self) -> None:
        # The kernels get the same array types from here as from their compiled
        # callers (rows they pick out: writable; the cameras: read-only, as the
        # pair solver's), so that Numba compiles each once.
        self.cam = _writable(self.cam, np.int64)
        self.own = _writable(self.own, np.int64)
        self.points = _writable(self.points, float).reshape(-1, 3)
        self.uv = _writable(self.uv, float).reshape(-1, 2)
        self.K = readonly(np.ascontiguousarray(self.K, dtype=float).reshape(-1, 3, 3))
        self.dist = readonly(np.ascontiguousarray(self.dist, dtype=float).reshape(-1, 8))
        n = self.cam.shape[0]
        self.wt = np.ones(n) if self.wt is None else _writable(self.wt, float).reshape(n)
        if self.frames is not None:
            self.frames = _writable(self.frames, float).reshape(n, 4, 3)

    @property
    def fr(self) -> np.ndarray:
        """The kernels' ``frames`` argument: the ray frames, or none (pixel mode)."""
        return NO_FRAMES if self.frames is None else self.frames

    def ray(self, j: int) -> tuple[np.ndarray, np.ndarray] | None:
        """Row ``j``'s ray in its observer's frame: ``(origin, unit direction)``;
        None for a pixel that cannot be undistorted."""
        if self.frames is not None:
            return self.frames[j, 3].copy(), self.frames[j, 2].copy()
        a = int(self.cam[j])
        b = _bearing(self.K[a], self.dist[a], self.uv[j])
        return None if b is None else (np.zeros(3), b)

    @property
    def n_robots(self) -> int:
        return self.K.shape[0]

    def take(self, rows: np.ndarray) -> "TeamProblem":
        """The observations ``rows`` only (same robots)."""
        return TeamProblem(self.cam[rows], self.own[rows], self.points[rows], self.uv[rows], self.K, self.dist,
                           self.wt[rows], None if self.frames is None else self.frames[rows])

    @staticmethod
    def concatenate(problems: "list[TeamProblem]") -> "TeamProblem":
        """The rows of several problems over the same robots, in order (all in
        pixels or all in rays)."""
        first = problems[0]
        rays = first.frames is not None
        if any((p.frames is not None) != rays for p in problems):
            raise ValueError("cannot concatenate pixel-mode and ray-mode rows")
        return TeamProblem(np.concatenate([p.cam for p in problems]), np.concatenate([p.own for p in problems]),
                           np.concatenate([p.points for p in problems]), np.concatenate([p.uv for p in problems]),
                           first.K, first.dist, np.concatenate([p.wt for p in problems]),
                           np.concatenate([p.frames for p in problems]) if rays else None)

    def counts(self) -> np.ndarray:
        """``C[a, b]``: observations camera ``a`` made of robot ``b``'s markers."""
        C = np.zeros((self.n_robots, self.n_robots), dtype=np.int64)
        np.add.at(C, (self.cam, self.own), 1)
        return C


@njit(cache=True)
def _skew_mul(M, v, out):
    """out (2, 3) = M (2, 3) @ skew(v)."""
    for k in range(2):
        out[k, 0] = M[k, 1] * v[2] - M[k, 2] * v[1]
        out[k, 1] = M[k, 2] * v[0] - M[k, 0] * v[2]
        out[k, 2] = M[k, 0] * v[1] - M[k, 1] * v[0]


@njit(cache=True)
def team_residuals(cam, own, pts, meas, wt, Ks, ds, Rs, ts, r, Ja, Jb, want_jac):
    """Residuals (2n,) and, with ``want_jac``, each observation's Jacobians
    (n, 2, 6) with respect to the observer's pose (``Ja``) and the marker
    owner's pose (``Jb``), each observation's rows times its weight ``wt``
    (pixel_sigma over its own noise).  False when a marker is behind its
    observer.  Pixel mode (:func:`team_residuals_any` for rays)."""
    return team_residuals_any(cam, own, pts, meas, wt, Ks, ds, np.empty((0, 4, 3)), Rs, ts, r, Ja, Jb, want_jac)


@njit(cache=True)
def team_residuals_any(cam, own, pts, meas, wt, Ks, ds, frames, Rs, ts, r, Ja, Jb, want_jac):
    """:func:`team_residuals` in pixel mode (``frames`` empty) or in ray mode
    (``frames`` (n, 4, 3), :attr:`TeamProblem.frames`): the predicted point
    in the observer's frame less the ray's origin, ``X = R_a^T (R_b P + t_b
    - t_a) - o``, gives the gnomonic residual ``(e_k . X) / (b . X)`` on the
    two weighted tangent rows ``e_k`` around the observed ray ``b`` (pixels
    to first order, as :data:`mutloc.core.refine.MODE_RAY`)."""
    ray = frames.shape[0] > 0
    Y = np.empty(3)
    d = np.empty(3)
    X = np.empty(3)
    uv = np.empty(2)
    Jp = np.empty((2, 3))
    M = np.empty((2, 3))
    S = np.empty((2, 3))
    for j in range(cam.shape[0]):
        a = cam[j]
        b = own[j]
        for i in range(3):
            Y[i] = Rs[b, i, 0] * pts[j, 0] + Rs[b, i, 1] * pts[j, 1] + Rs[b, i, 2] * pts[j, 2]
        for i in range(3):
            d[i] = Y[i] + ts[b, i] - ts[a, i]
        for i in range(3):
            X[i] = Rs[a, 0, i] * d[0] + Rs[a, 1, i] * d[1] + Rs[a, 2, i] * d[2]
        w = wt[j]
        if ray:
            # the ray leaves its camera's centre; gnomonic residual around it
            for i in range(3):
                X[i] -= frames[j, 3, i]
            den = frames[j, 2, 0] * X[0] + frames[j, 2, 1] * X[1] + frames[j, 2, 2] * X[2]
            if not den > 1e-150:
                return False
            for k in range(2):
                num = frames[j, k, 0] * X[0] + frames[j, k, 1] * X[1] + frames[j, k, 2] * X[2]
                r[2 * j + k] = w * (num / den)
                for i in range(3):
                    Jp[k, i] = (frames[j, k, i] * den - num * frames[j, 2, i]) / (den * den)
        else:
            if want_jac:
                if not project_jac_kernel(Ks[a], ds[a], X, uv, Jp):
                    return False
            elif not project_kernel(Ks[a], ds[a], X, uv):
                return False
            r[2 * j] = w * (uv[0] - meas[j, 0])
            r[2 * j + 1] = w * (uv[1] - meas[j, 1])
        if want_jac:
            # M = d uv / d x_ref = Jp R_a^T (weighted)
            for k in range(2):
                for i in range(3):
                    M[k, i] = w * (Jp[k, 0] * Rs[a, i, 0] + Jp[k, 1] * Rs[a, i, 1] + Jp[k, 2] * Rs[a, i, 2])
            # owner: d x_ref = -[R_b P]x dtheta_b + dt_b
            _skew_mul(M, Y, S)
            for k in range(2):
                for i in range(3):
                    Jb[j, k, i] = -S[k, i]
                    Jb[j, k, 3 + i] = M[k, i]
            # observer: x_a = R_a^T exp(-dtheta_a)(x_ref - t_a - dt_a)
            _skew_mul(M, d, S)
            for k in range(2):
                for i in range(3):
                    Ja[j, k, i] = S[k, i]
                    Ja[j, k, 3 + i] = -M[k, i]
    return True


@njit(cache=True)
def team_cost(cam, own, pts, meas, wt, Ks, ds, Rs, ts):
    """Sum of squared weighted pixel residuals (inf if a marker is behind its observer); pixel mode."""
    return team_cost_any(cam, own, pts, meas, wt, Ks, ds, np.empty((0, 4, 3)), Rs, ts)


@njit(cache=True)
def team_cost_any(cam, own, pts, meas, wt, Ks, ds, frames, Rs, ts):
    """:func:`team_cost` in pixel or ray mode (see :func:`team_residuals_any`)."""
    n = cam.shape[0]
    r = np.empty(2 * n)
    J = np.empty((1, 2, 6))
    if not team_residuals_any(cam, own, pts, meas, wt, Ks, ds, frames, Rs, ts, r, J, J, np.bool_(False)):
        return np.inf
    c = 0.0
    for k in range(2 * n):
        c += r[k] * r[k]
    return c


@njit(cache=True)
def _accumulate(cam, own, var, r, Ja, Jb, H, g):
    """H = J^T J and g = J^T r from the per-observation blocks (fixed
    robots, ``var < 0``, contribute no column)."""
    H[:, :] = 0.0
    g[:] = 0.0
    for j in range(cam.shape[0]):
        va = var[cam[j]]
        vb = var[own[j]]
        for side in range(2):
            v = va if side == 0 else vb
            if v < 0:
                continue
            A = Ja[j] if side == 0 else Jb[j]
            o = 6 * v
            for p in range(6):
                g[o + p] += A[0, p] * r[2 * j] + A[1, p] * r[2 * j + 1]
                for q in range(p + 1):
                    H[o + p, o + q] += A[0, p] * A[0, q] + A[1, p] * A[1, q]
        if va >= 0 and vb >= 0:
            oa = 6 * va
            ob = 6 * vb
            A = Ja[j]
            B = Jb[j]
            for p in range(6):
                for q in range(6):
                    h = A[0, p] * B[0, q] + A[1, p] * B[1, q]
                    # lower triangle only (mirrored below)
                    if oa + p >= ob + q:
                        H[oa + p, ob + q] += h
                    else:
                        H[ob + q, oa + p] += h
    m = H.shape[0]
    for p in range(m):
        for q in range(p):
            H[q, p] = H[p, q]


@njit(cache=True)
def _envelope(cam, own, var, m):
    """first[i]: the first column of row i of H that can be non-zero (the
    lowest block a robot shares an observation with); Cholesky fills in
    nothing left of it."""
    fb = np.arange(m // 6)
    for j in range(cam.shape[0]):
        va = var[cam[j]]
        vb = var[own[j]]
        if va >= 0 and vb >= 0:
            if va > vb:
                fb[va] = min(fb[va], vb)
            else:
                fb[vb] = min(fb[vb], va)
    first = np.empty(m, dtype=np.int64)
    for i in range(m):
        first[i] = 6 * fb[i // 6]
    return first


@njit(cache=True)
def _cholesky_solve(A, first, b, x, L):
    """x = A^-1 b for symmetric positive definite A whose row i is zero left
    of column first[i] (an envelope Cholesky: with the robots ordered by
    reverse Cuthill-McKee the envelope of a team's H is narrow); False if A
    is not positive definite."""
    n = A.shape[0]
    for i in range(n):
        fi = first[i]
        for j in range(fi, i + 1):
            s = A[i, j]
            k0 = max(fi, first[j])
            for k in range(k0, j):
                s -= L[i, k] * L[j, k]
            if i == j:
                if not s > 0.0:
                    return False
                L[i, i] = np.sqrt(s)
            else:
                L[i, j] = s / L[j, j]
    for i in range(n):
        s = b[i]
        for k in range(first[i], i):
            s -= L[i, k] * x[k]
        x[i] = s / L[i, i]
    for i in range(n - 1, -1, -1):
        s = x[i]
        for k in range(i + 1, n):
            if first[k] <= i:
                s -= L[k, i] * x[k]
        x[i] = s / L[i, i]
    return True


@njit(cache=True)
def team_lm(cam, own, pts, meas, wt, Ks, ds, frames, var, Rs, ts, max_iter, H):
    """Levenberg-Marquardt over the poses of robots with ``var[i] >= 0``
    (column block ``var[i]``), others fixed (pixel or ray mode: ``frames``, see
    :func:`team_residuals_any`); Rs/ts updated in place, ``H``
    (6k, 6k) receives J^T J at the end.  Returns (cost, iterations); cost is
    inf when the start puts a marker behind its observer."""
    n = cam.shape[0]
    N = Rs.shape[0]
    m = H.shape[0]
    r = np.empty(2 * n)
    Ja = np.empty((n, 2, 6))
    Jb = np.empty((n, 2, 6))
    g = np.empty(m)
    A = np.empty((m, m))
    delta = np.empty(m)
    rhs = np.empty(m)
    L = np.empty((m, m))
    first = _envelope(cam, own, var, m)
    Rn = np.empty_like(Rs)
    tn = np.empty_like(ts)
    if not team_residuals_any(cam, own, pts, meas, wt, Ks, ds, frames, Rs, ts, r, Ja, Jb, np.bool_(True)):
        return np.inf, 0
    c = 0.0
    for k in range(2 * n):
        c += r[k] * r[k]
    _accumulate(cam, own, var, r, Ja, Jb, H, g)
    scale = 1.0
    for i in range(N):
        if var[i] >= 0:
            scale = max(scale, 1.0 + np.sqrt(ts[i, 0] ** 2 + ts[i, 1] ** 2 + ts[i, 2] ** 2))
    lam = 1e-4
    it = 0
    for it in range(1, max_iter + 1):
        improved = False
        small = False
        for _ in range(12):
            for p in range(m):
                for q in range(m):
                    A[p, q] = H[p, q]
                A[p, p] += lam * (H[p, p] + 1e-12)
                rhs[p] = -g[p]
            if not _cholesky_solve(A, first, rhs, delta, L):
                lam *= 10.0
                continue
            step = 0.0
            for v in range(m // 6):
                for k in range(3):
                    step += delta[6 * v + k] ** 2 + (delta[6 * v + 3 + k] / scale) ** 2
            step = np.sqrt(step)
            if step < 1e-10:
                small = True
                break
            Rn[:, :, :] = Rs
            tn[:, :] = ts
            for i in range(N):
                v = var[i]
                if v >= 0:
                    so3_exp_left(delta[6 * v:6 * v + 3], Rs[i], Rn[i])
                    for k in range(3):
                        tn[i, k] += delta[6 * v + 3 + k]
            cn = team_cost_any(cam, own, pts, meas, wt, Ks, ds, frames, Rn, tn)
            if cn <= c:
                Rs[:, :, :] = Rn
                ts[:, :] = tn
                dc = c - cn
                c = cn
                lam = max(lam * 0.1, 1e-12)
                improved = True
                small = step < 1e-9 or dc <= 1e-14 * c
                break
            if step < 1e-8:
                small = True
                break
            lam *= 10.0
        if not improved or small:
            break
        team_residuals_any(cam, own, pts, meas, wt, Ks, ds, frames, Rs, ts, r, Ja, Jb, np.bool_(True))
        _accumulate(cam, own, var, r, Ja, Jb, H, g)
    if it > 0:
        team_residuals_any(cam, own, pts, meas, wt, Ks, ds, frames, Rs, ts, r, Ja, Jb, np.bool_(True))
        _accumulate(cam, own, var, r, Ja, Jb, H, g)
    return c, it


def _lm(problem: TeamProblem, var: np.ndarray, Rs: np.ndarray, ts: np.ndarray, max_iter: int) -> tuple[float, int,
                                                                                                      np.ndarray]:
    k = int(var.max()) + 1 if var.size else 0
    H = np.zeros((6 * k, 6 * k))
    c, it = team_lm(problem.cam, problem.own, problem.points, problem.uv, problem.wt, problem.K, problem.dist, problem.fr,
                    var,
                    Rs, ts,
                    max_iter, H)
    return float(c), int(it), H


@dataclass
class TeamSolution:
    """The joint optimum: ``poses[i]`` is ``T_ref_i`` for localized robots
    (``localized[i]``), ``information`` is J^T J over the localized robots
    other than the reference, in index order (``order``)."""

    Rs: np.ndarray
    ts: np.ndarray
    localized: np.ndarray
    order: np.ndarray
    cost: float
    n_obs: int
    information: np.ndarray
    iterations: int
    used: np.ndarray
    #: Robots in the joint problem whose pose the observations do not isolate
    #: (free to turn about two markers) but through which others are held:
    #: solved along, reported unlocalized; the others' ``information`` is
    #: marginalised over them.
    nuisance: np.ndarray | None = None
    #: Parameters of the nuisance robots the observations do fix (rank of their block).
    nuisance_params: int = 0

    @property
    def dof(self) -> int:
        """Redundancy of the optimum: ``2n`` equations less the parameters fixed."""
        return 2 * self.n_obs - 6 * len(self.order) - self.nuisance_params

    @property
    def solved(self) -> np.ndarray:
        """The robots in the joint problem: localized or nuisance."""
        return self.localized if self.nuisance is None else self.localized | self.nuisance

    def covariance(self, sigma: float) -> np.ndarray:
        """The joint covariance (6k square) for isotropic pixel noise ``sigma``."""
        if self.information.size == 0:
            return np.zeros((0, 0))
        return sigma**2 * _checked_inverse(self.information)


def checked_factor(H: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Cholesky factor ``L`` of the Jacobi-scaled information matrix and the
    scales ``d`` (``H = D^-1 L L^T D^-1``, ``D = diag(d)``);
    DegenerateGeometryError when it is singular to rounding (some pose not
    isolated).  The check is cheap; the inverse (:func:`inverse_from_factor`)
    can wait until a covariance is asked for."""
    d = np.sqrt(np.diag(H))
    if not np.all(d > 0):
        raise DegenerateGeometryError("the observations do not determine every pose (a robot's pose is free)")
    Hs = H / d[:, None] / d[None, :]
    try:
        L = np.linalg.cholesky(Hs)
    except np.linalg.LinAlgError:
        raise DegenerateGeometryError("the observations do not determine an isolated pose for every robot") from None
    if np.min(np.diag(L)) ** 2 < H.shape[0] / _MAX_COND:
        raise DegenerateGeometryError("the observations do not determine an isolated pose for every robot")
    return L, d


def inverse_from_factor(L: np.ndarray, d: np.ndarray) -> np.ndarray:
    """``H^-1`` from :func:`checked_factor`'s result."""
    from scipy.linalg import solve_triangular

    Li = solve_triangular(L, np.eye(L.shape[0]), lower=True)
    return (Li.T @ Li) / d[:, None] / d[None, :]


def _checked_inverse(H: np.ndarray) -> np.ndarray:
    """Inverse of the information matrix, checked (:func:`checked_factor`)."""
    return inverse_from_factor(*checked_factor(H))


@njit(cache=True)
def _spread(rows, k):
    """At most ``k`` of ``rows``, spread evenly over them (the indices of
    ``np.round(np.linspace(0, len(rows) - 1, k))``, halves to even)."""
    n = rows.shape[0]
    if n <= k or k < 2:
        return rows
    out = np.empty(k, dtype=rows.dtype)
    step = (n - 1) / (k - 1)
    for i in range(k):
        v = i * step if i < k - 1 else float(n - 1)
        f = np.floor(v)
        d = v - f
        j = int(f)
        if d > 0.5 or (d == 0.5 and j % 2 == 1):
            j += 1
        out[i] = rows[j]
    return out


@njit(cache=True)
def _place_pass(cam, own, pts, uv, wt, Ks, ds, frames, Rs, ts, r, c, sees, seen, ties, subsets, gate, max_iter, out_R,
                out_t):
    """One attempt at placing robot ``r`` (the body of :func:`initial_poses`):
    the pair problem of r's views ``sees`` (placed markers, expressed in
    camera ``c``'s frame) and c's views ``seen`` of r's markers, solved by
    the pair solver (:func:`mutloc.core.estimate.solve_kernel`, minimal
    ``subsets``); its refined best pose, then -- if that does not fit r's
    ``ties`` within ``gate`` -- its other candidates, scored on the ties
    and the best of each refined on them (LM over r's pose only).  Returns
    the best tie cost (inf: nothing fits), the pose in out_R/out_t.  In ray
    mode (``frames`` not empty) the pair problem is one of rays
    (:data:`MODE_RAY`: each row's frame in its observer's robot frame)."""
    ray = frames.shape[0] > 0
    na = sees.shape[0]
    nb = seen.shape[0]
    n = na + nb
    side = np.empty(n, dtype=np.int64)
    P = np.empty((n, 3))
    meas = np.empty((n, 2))
    w = np.empty(n)
    fr = np.empty((n if ray else 0, 4, 3))
    Rc_, tc_ = Rs[c], ts[c]
    for i in range(na):
        j = sees[i]
        b = own[j]
        side[i] = 0
        x = np.empty(3)
        for k in range(3):
            x[k] = Rs[b, k, 0] * pts[j, 0] + Rs[b, k, 1] * pts[j, 1] + Rs[b, k, 2] * pts[j, 2] + ts[b, k] - tc_[k]
        for k in range(3):
            P[i, k] = Rc_[0, k] * x[0] + Rc_[1, k] * x[1] + Rc_[2, k] * x[2]
        meas[i, 0] = uv[j, 0]
        meas[i, 1] = uv[j, 1]
        w[i] = wt[j]
        if ray:
            fr[i] = frames[j]
    for i in range(nb):
        j = seen[i]
        side[na + i] = 1
        for k in range(3):
            P[na + i, k] = pts[j, k]
        meas[na + i, 0] = uv[j, 0]
        meas[na + i, 1] = uv[j, 1]
        w[na + i] = wt[j]
        if ray:
            fr[na + i] = frames[j]
    size = max(subsets.shape[0] * PER_SUBSET, 1)
    Rc = np.empty((size, 3, 3))
    tc = np.empty((size, 3))
    order = np.empty(size, dtype=np.int64)
    costs = np.empty(size)
    Rbest = np.empty((3, 3))
    tbest = np.empty(3)
    H6 = np.empty((6, 6))
    Hinv = np.empty((6, 6))
    bearings = np.empty((n, 3))
    mode = MODE_PIXEL
    if ray:
        mode = MODE_RAY
        for i in range(n):
            for k in range(3):
                bearings[i, k] = fr[i, 2, k]
    status, _, _, nd, _ = solve_kernel(side, P, meas, bearings, fr, Ks[r], ds[r], Ks[c], ds[c],
                                       mode, w, subsets, np.bool_(False), np.int64(0), np.int64(4), np.int64(50), Rc, tc, order, costs, Rbest, tbest,
                                       H6, Hinv)
    if status != 0:
        return np.inf
    # r's ties as a problem of their own
    scam = cam[ties]
    sown = own[ties]
    spts = pts[ties]
    suv = uv[ties]
    swt = wt[ties]
    sfr = frames[ties] if ray else np.empty((0, 4, 3))
    var = np.full(Rs.shape[0], -1, dtype=np.int64)
    var[r] = 0
    H = np.empty((6, 6))
    Rtry = Rs.copy()
    ttry = ts.copy()
    found = np.inf
    # the solver's refined best first; the others only if it does not fit
    # the ties within their noise
    bR = np.empty((3, 3))
    bt = np.empty(3)
    # of three observations every candidate is exact and the solver's pick
    # means nothing: score them all on the ties
    for pool in range(1 if n == 3 else 0, 2):
        best = np.inf
        for q in range(1 if pool == 0 else nd):
            if pool == 0:
                Rq = Rbest
                tq = tbest
            else:
                Rq = Rc[order[q]]
                tq = tc[order[q]]
            for a in range(3):
                for b in range(3):
                    Rtry[r, a, b] = Rc_[a, 0] * Rq[0, b] + Rc_[a, 1] * Rq[1, b] + Rc_[a, 2] * Rq[2, b]
                ttry[r, a] = Rc_[a, 0] * tq[0] + Rc_[a, 1] * tq[1] + Rc_[a, 2] * tq[2] + tc_[a]
            cost = team_cost_any(scam, sown, spts, suv, swt, Ks, ds, sfr, Rtry, ttry)
            if cost < best:
                best = cost
                bR[:, :] = Rtry[r]
                bt[:] = ttry[r]
        if not np.isfinite(best):
            continue
        Rtry[r] = bR
        ttry[r] = bt
        cost, _ = team_lm(scam, sown, spts, suv, swt, Ks, ds, sfr, var, Rtry, ttry, max_iter, H)
        if np.isfinite(cost) and cost < best:
            best = cost
            bR[:, :] = Rtry[r]
            bt[:] = ttry[r]
        if best < found:
            found = best
            out_R[:, :] = bR
            out_t[:] = bt
        if found <= gate:
            break
    return found


class _NoSuchChoice(Exception):
    """A restart asked for a minimal solution that does not exist."""


def _bearing(K: np.ndarray, dist: np.ndarray, uv: np.ndarray) -> np.ndarray | None:
    b = np.empty(3)
    return b if undistort_kernel(K, dist, np.ascontiguousarray(uv, dtype=float), b) else None


def _attach(problem: TeamProblem, Rs: np.ndarray, ts: np.ndarray, placed: np.ndarray, members: np.ndarray,
            Rl: np.ndarray, tl: np.ndarray, sigma: float, max_iter: int, choice: int | None = None) -> bool:
    """Place the rigid group ``members`` (poses ``Rl``/``tl`` in a frame U of
    their own) among the ``placed`` robots by the generalized minimal solver
    (:func:`mutloc.core.generalized.generalized_p3p`): the group's cameras
    see placed markers (rays of U), placed cameras see the group's markers
    (rays of the reference frame), from any number of cameras.  Candidates
    from a few triples of the ties are scored on all ties, the best refined
    (LM over the members).  ``choice``: take that minimal solution of the
    first triple instead (a restart; :class:`_NoSuchChoice` if there is
    none).  Writes Rs/ts/placed and returns True on success."""
    from itertools import combinations

    N = problem.n_robots
    inm = np.zeros(N, dtype=bool)
    inm[members] = True
    cam, own = problem.cam, problem.own
    ties = np.flatnonzero((inm[cam] & placed[own]) | (placed[cam] & inm[own]))
    if len(ties) < MIN_TIES:
        return False
    kinds, origins, dirs, points = [], [], [], []
    usable = []
    for j in ties.tolist():
        a, b = int(cam[j]), int(own[j])
        ray = problem.ray(j)
        if ray is None:
            continue
        o, bear = ray
        usable.append(len(kinds))
        if inm[a]:  # a camera of the group sees a placed marker
            kinds.append(KIND_U_RAY)
            origins.append(tl[a] if problem.frames is None else tl[a] + Rl[a] @ o)
            dirs.append(Rl[a] @ bear)
            points.append(Rs[b] @ problem.points[j] + ts[b])
        else:  # a placed camera sees a marker of the group
            kinds.append(KIND_W_RAY)
            origins.append(ts[a] if problem.frames is None else ts[a] + Rs[a] @ o)
            dirs.append(Rs[a] @ bear)
            points.append(Rl[b] @ problem.points[j] + tl[b])
    if len(usable) < MIN_TIES:
        return False
    kinds_a, origins_a, dirs_a, points_a = (np.array(x) for x in (kinds, origins, dirs, points))
    tie_sub = problem.take(ties)
    gate = sigma**2 * chi2_quantile(0.999, 2 * len(ties) - 6) if len(ties) > 3 else np.inf
    Rtry, ttry = Rs.copy(), ts.copy()

    def apply(R, t, Rout, tout):
        for i in members.tolist():
            Rout[i] = R @ Rl[i]
            tout[i] = R @ tl[i] + t

    pick = _spread(np.arange(len(usable), dtype=np.int64), 6)
    best, bR, bt = np.inf, None, None
    for tri in combinations(pick.tolist(), 3):
        idx = list(tri)
        Rc, tc = generalized_p3p(kinds_a[idx], origins_a[idx], dirs_a[idx], points_a[idx])
        if choice is not None:
            if choice >= len(Rc):
                raise _NoSuchChoice
            Rc, tc = Rc[choice:choice + 1], tc[choice:choice + 1]
        for R, t in zip(Rc, tc):
            apply(R, t, Rtry, ttry)
            cost = team_cost_any(tie_sub.cam, tie_sub.own, tie_sub.points, tie_sub.uv, tie_sub.wt, tie_sub.K,
                                 tie_sub.dist, tie_sub.fr, Rtry, ttry)
            if cost < best:
                best, bR, bt = cost, Rtry[members].copy(), ttry[members].copy()
        if best <= gate or choice is not None:
            break
    if bR is None or not np.isfinite(best):
        return False
    Rtry[members], ttry[members] = bR, bt
    # refine the members on every observation they share with the placed robots or among themselves
    both = placed | inm
    rows = np.flatnonzero(both[cam] & both[own] & (inm[cam] | inm[own]))
    var = np.full(N, -1, dtype=np.int64)
    var[members] = np.arange(len(members))
    cost, _, H = _lm(problem.take(rows), var, Rtry, ttry, max_iter)
    if not np.isfinite(cost):
        Rtry[members], ttry[members] = bR, bt
        cost, _, H = _lm(problem.take(rows), var, Rtry, ttry, 0)
    try:
        # the group's pose must be isolated (say, a robot seen at only two
        # of its markers, from any number of cameras, is free to turn)
        checked_factor(H)
    except DegenerateGeometryError:
        return False
    Rs[members], ts[members] = Rtry[members], ttry[members]
    placed[members] = True
    return True


def _grow(problem: TeamProblem, Rs: np.ndarray, ts: np.ndarray, placed: np.ndarray, sigma: float, max_iter: int,
          choices: dict[int, int], record: list[int] | None) -> None:
    """Prim's placement (:func:`initial_poses`), robot by robot, from the pair solver."""
    N = problem.n_robots
    C = problem.counts()
    cam, own = problem.cam, problem.own
    failed_at = np.full(N, -1)
    out_R, out_t = np.empty((3, 3)), np.empty(3)
    while True:
        # ties of each unplaced robot: its views of placed robots' markers
        # plus the views of the best placed camera of it
        out = C[:, placed].sum(axis=1)
        into = np.where(placed[:, None], C, 0)
        best_cam = np.argmax(into, axis=0)
        score = out + into[best_cam, np.arange(N)]
        score[placed | (failed_at == placed.sum())] = -1
        r = int(np.argmax(score))
        if score[r] < MIN_TIES:
            break
        c = int(best_cam[r])
        if into[c, r] == 0:
            # r sees placed markers only: express them in a camera whose
            # markers r sees (any placed frame would do)
            c = int(np.flatnonzero(placed)[np.argmax(C[r, placed])])
        r_sees = (cam == r) & placed[own]
        sees = np.flatnonzero(r_sees)
        seen = np.flatnonzero((cam == c) & (own == r))
        ties = np.flatnonzero(r_sees | ((own == r) & placed[cam]))
        if len(ties) == MIN_TIES:
            # several exact poses: a restart may ask for another one
            if record is not None:
                record.append(r)
            if r in choices:
                if not _attach(problem, Rs, ts, placed, np.array([r]), np.tile(np.eye(3), (N, 1, 1)),
                               np.zeros((N, 3)), sigma, max_iter, choices[r]):
                    failed_at[r] = placed.sum()
                continue
        # a few observations each way make the candidates (cheap); every
        # candidate is scored on all of r's ties (this also picks among the
        # exact poses of three observations) and the best refined on them;
        # all observations when the few give nothing that fits the ties
        # within FALLBACK_FACTOR times their noise (a small, distant
        # triangle under noise)
        gate = sigma**2 * chi2_quantile(0.999, 2 * len(ties) - 6) if len(ties) > 3 else np.inf
        found = np.inf
        for per_side in (INIT_PER_SIDE, None):
            if per_side is None:
                if (len(sees) <= INIT_PER_SIDE and len(seen) <= INIT_PER_SIDE) or found <= FALLBACK_FACTOR * gate:
                    break
                a, b = sees, seen
            else:
                a, b = _spread(sees, per_side), _spread(seen, per_side)
            if len(a) + len(b) < 3:
                continue
            subsets = minimal_subsets(np.r_[np.zeros(len(a), np.int64), np.ones(len(b), np.int64)])
            R1, t1 = np.empty((3, 3)), np.empty(3)
            cost = _place_pass(cam, own, problem.points, problem.uv, problem.wt, problem.K, problem.dist, problem.fr, Rs,
                               ts, r, c, a, b, ties, subsets, gate, max_iter, R1, t1)
            if cost < found:
                found, out_R, out_t = cost, R1, t1
            if found <= gate:
                break
        if not np.isfinite(found):
            # no pose explains them: try r again once more robots are placed
            failed_at[r] = placed.sum()
            continue
        Rs[r], ts[r] = out_R, out_t
        placed[r] = True


def _components(C: np.ndarray, among: np.ndarray) -> list[np.ndarray]:
    """Connected components of the robots ``among`` by their observations of each other."""
    A = (C + C.T) > 0
    left = set(np.flatnonzero(among).tolist())
    comps = []
    while left:
        stack = [left.pop()]
        comp = list(stack)
        while stack:
            i = stack.pop()
            for j in np.flatnonzero(A[i] & among).tolist():
                if j in left:
                    left.remove(j)
                    comp.append(j)
                    stack.append(j)
        comps.append(np.array(sorted(comp), dtype=np.int64))
    return comps


def _attach_group(problem: TeamProblem, Rs: np.ndarray, ts: np.ndarray, placed: np.ndarray, sigma: float,
                  max_iter: int, choices: dict[int, int], record: list[int] | None) -> bool:
    """When Prim's placement stalls: a group of unplaced robots, solved among
    themselves (:func:`initial_poses` from one of them) and tied to the
    placed ones by three or more observations spread over several robots,
    placed as one rigid body (:func:`_attach`).  True if one was placed."""
    C = problem.counts()
    unplaced = ~placed
    ties = C[:, placed].sum(axis=1) + C[placed, :].sum(axis=0)
    for comp in _components(C, unplaced & (C.sum(axis=0) + C.sum(axis=1) > 0)):
        if ties[comp].sum() < MIN_TIES:
            continue
        inside = np.zeros(problem.n_robots, dtype=bool)
        inside[comp] = True
        sub = problem.take(np.flatnonzero(inside[problem.cam] & inside[problem.own]))
        # the best-tied first; its group: what the observations among the
        # component place around it (a robot of a group tried already
        # would grow the same group)
        tried = np.zeros(problem.n_robots, dtype=bool)
        for u in comp[np.argsort(-ties[comp], kind="stable")].tolist():
            if tried[u]:
                continue
            Rl, tl, group = initial_poses(sub, u, sigma=sigma, max_iter=max_iter, choices=choices, record=record)
            members = np.flatnonzero(group & inside)
            tried[members] = True
            n_ties = int(ties[members].sum())
            if n_ties < MIN_TIES:
                continue
            if n_ties == MIN_TIES and record is not None:
                record.append(u)
            choice = choices.get(u) if n_ties == MIN_TIES else None
            if _attach(problem, Rs, ts, placed, members, Rl, tl, sigma, max_iter, choice):
                return True
    return False


#: Sampled starts :func:`_sampled_group` tries for a group at most, and the
#: optima within the noise it compares before it keeps the lowest.
SAMPLED_STARTS = 120
SAMPLED_FITS = 4


def _isolated(H: np.ndarray, rank: bool = False) -> Any:
    """Per robot of an information matrix (6-blocks): is its pose isolated --
    no direction of the (Jacobi-scaled) null space touches it; with
    ``rank``, also H's rank (its parameters the data fix)."""
    k = H.shape[0] // 6
    d = np.sqrt(np.maximum(np.diag(H), 1e-300))
    w, V = np.linalg.eigh(H / d[:, None] / d[None, :])
    small = w < 1e-9 * max(float(w.max()), 1e-300)
    null = V[:, small]
    out = np.array([bool(np.all(np.diag(H)[6 * i:6 * i + 6] > 0)) for i in range(k)])
    if null.size:
        out &= np.abs(null).reshape(k, 6, -1).max(axis=(1, 2)) < 1e-6
    return (out, int(np.count_nonzero(~small))) if rank else out


def _relative_sample(rng: np.random.Generator, bearings: np.ndarray, points: np.ndarray,
                     origins: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray] | None:
    """A random pose ``T_ab`` (R, t) that puts points ``points`` (b's frame)
    exactly on rays ``bearings`` (a's camera; from ``origins`` in a's frame
    when given, else from its origin): with two or more points, the
    first two at depths drawn along their rays at their true distance and a
    random turn about the line through them; with one, a random depth and
    rotation."""
    R0 = _random_rotation(rng)
    if len(points) == 1 or np.linalg.norm(points[1] - points[0]) < 1e-9:
        lam = float(np.exp(rng.uniform(np.log(0.3), np.log(20.0))))
        X = lam * bearings[0] if origins is None else origins[0] + lam * bearings[0]
        return R0, X - R0 @ points[0]
    b1, b2 = bearings[0], bearings[1]
    d = float(np.linalg.norm(points[1] - points[0]))
    c = float(np.clip(b1 @ b2, -1.0, 1.0))
    s = np.sqrt(max(1.0 - c * c, 1e-12))
    lam1 = float(rng.uniform(0.02, 1.0)) * min(d / s, 50.0)
    if origins is None:
        disc = lam1 * lam1 * (c * c - 1.0) + d * d
        if disc < 0:
            return None
        roots = [r for r in (lam1 * c + np.sqrt(disc), lam1 * c - np.sqrt(disc)) if r > 1e-6]
        X1 = lam1 * b1
    else:
        # |o2 + lam2 b2 - X1| = d: lam2^2 + 2 lam2 b2.w + |w|^2 - d^2 = 0, w = o2 - X1
        X1 = origins[0] + lam1 * b1
        w = origins[1] - X1
        bw = float(b2 @ w)
        disc = bw * bw - float(w @ w) + d * d
        if disc < 0:
            return None
        roots = [r for r in (-bw + np.sqrt(disc), -bw - np.sqrt(disc)) if r > 1e-6]
    if not roots:
        return None
    lam2 = roots[int(rng.integers(len(roots)))]
    X2 = lam2 * b2 if origins is None else origins[1] + lam2 * b2
    u, v = (X2 - X1) / d, (points[1] - points[0]) / d
    # the rotation taking v to u, then a random turn about u
    w = np.cross(v, u)
    sw, cw = np.linalg.norm(w), float(v @ u)
    if sw < 1e-12:
        align = np.eye(3) if cw > 0 else so3_exp(np.pi * _perpendicular(v))
    else:
        align = so3_exp(w / sw * np.arctan2(sw, cw))
    R = so3_exp(u * rng.uniform(-np.pi, np.pi)) @ align
    return R, X1 - R @ points[0]


def _random_rotation(rng: np.random.Generator) -> np.ndarray:
    """A rotation drawn uniformly (a normalised Gaussian quaternion)."""
    q = rng.normal(size=4)
    return matrix_from_quaternion_xyzw(q / np.linalg.norm(q))


def _perpendicular(v: np.ndarray) -> np.ndarray:
    a = np.eye(3)[int(np.argmin(np.abs(v)))]
    w = np.cross(v, a)
    return w / np.linalg.norm(w)


def _sampled_group(problem: TeamProblem, Rs: np.ndarray, ts: np.ndarray, placed: np.ndarray, sigma: float,
                   max_iter: int, nuisance: np.ndarray | None = None) -> bool:
    """When neither robot-by-robot placement nor a rigid sub-group reaches
    further: a group of unplaced robots tied to the placed ones only as a
    whole through pairs of fewer than three observations (a loop r0 -> r1 ->
    r2 -> r0 of two markers each has no rigid sub-group, yet its poses are
    isolated).  The group's poses are drawn at random, each robot from one
    pair of observations with an already drawn or placed robot (the two
    markers exactly on their rays: two free parameters each), and refined
    jointly over every observation among the group and the placed robots;
    an optimum within the noise (chi-square at 99.9%; exactly, to 1e-9
    px^2 per observation, when there is no redundancy) is kept -- the lowest of the first :data:`SAMPLED_FITS` such
    optima -- with its isolated poses.  A robot seen at only two markers
    turns freely about their line: it is not placed; when others are held
    only through it, it is kept in the joint problem as ``nuisance`` (its
    pose solved along, reported unlocalized), else the isolated robots must
    be isolated without it.  Draws are seeded: the same observations give
    the same result.  True if a robot was placed."""
    N = problem.n_robots
    C = problem.counts()
    cam, own = problem.cam, problem.own
    ties = C[:, placed].sum(axis=1) + C[placed, :].sum(axis=0)
    rays = [problem.ray(j) for j in range(len(cam))]
    bears = [None if ray is None else ray[1] for ray in rays]
    centred = problem.frames is None
    rng = np.random.default_rng(20131103)
    # a robot whose camera sees nothing and which is seen at fewer than three
    # distinct markers turns freely about them: never isolated, left out
    pinned = np.zeros(N, dtype=bool)
    pinned[cam] = True
    for i in np.flatnonzero(~pinned).tolist():
        pinned[i] = len(np.unique(problem.points[own == i].round(9), axis=0)) >= 3
    for comp in _components(C, ~placed & (C.sum(axis=0) + C.sum(axis=1) > 0)):
        if ties[comp].sum() == 0 or not pinned[comp].any():
            continue
        inside = placed.copy()
        inside[comp] = True
        rows = np.flatnonzero(inside[cam] & inside[own])
        sub = problem.take(rows)
        var = np.full(N, -1, dtype=np.int64)
        var[comp] = np.arange(len(comp))
        best, found = None, 0
        for _ in range(SAMPLED_STARTS):
            Rtry, ttry = Rs.copy(), ts.copy()
            have = placed.copy()
            while not have[comp].all():
                # an observed pair (drawn, undrawn) with the most observations between them
                drawn = np.where(have[:, None] & ~have[None, :], C + C.T, 0)
                a, b = np.unravel_index(int(np.argmax(drawn)), drawn.shape)
                if drawn[a, b] == 0:
                    break
                # the direction with more observations; its rays in the observer's camera
                one = [j for j in rows.tolist() if cam[j] == a and own[j] == b and bears[j] is not None]
                other = [j for j in rows.tolist() if cam[j] == b and own[j] == a and bears[j] is not None]
                use, flip = (one, False) if len(one) >= len(other) else (other, True)
                if not use:
                    break
                pick = rng.permutation(use)[:2]
                got = _relative_sample(rng, np.array([bears[j] for j in pick]), problem.points[pick],
                                       None if centred else np.array([rays[j][0] for j in pick]))
                if got is None:
                    break
                R, t = got  # T_ab, or T_ba when flipped
                if flip:
                    R, t = R.T, -R.T @ t
                Rtry[b], ttry[b] = Rtry[a] @ R, Rtry[a] @ t + ttry[a]
                have[b] = True
            if not have[comp].all():
                continue
            cost, _, H = _lm(sub, var, Rtry, ttry, max(max_iter, 50))
            if not np.isfinite(cost):
                continue
            iso, rank = _isolated(H, rank=True)
            # the redundancy: equations less the parameters the data fix
            dof = 2 * len(rows) - rank
            if dof < 0 or cost > (sigma**2 * chi2_quantile(0.999, dof) if dof > 0 else 1e-9 * sigma**2 * len(rows)):
                continue
            if iso.any() and (best is None or cost < best[0] - 1e-12 or iso.sum() > best[3].sum()):
                best = (cost, Rtry, ttry, iso)
            found += 1
            if found >= SAMPLED_FITS:
                break
        if best is None:
            continue
        keep = comp[best[3]]
        Rs[comp], ts[comp] = best[1][comp], best[2][comp]
        if nuisance is not None:
            # the others are solved along: the isolated ones are placed
            placed[keep] = True
            nuisance[comp[~best[3]]] = True
            return True
        # the isolated robots, isolated also without the others: a robot
        # pinned only through a robot left out is not placed either
        while len(keep):
            inside = placed.copy()
            inside[keep] = True
            var = np.full(N, -1, dtype=np.int64)
            var[keep] = np.arange(len(keep))
            _, _, H = _lm(problem.take(np.flatnonzero(inside[cam] & inside[own])), var, best[1], best[2], 0)
            iso = _isolated(H)
            if iso.all():
                Rs[keep], ts[keep] = best[1][keep], best[2][keep]
                placed[keep] = True
                return True
            keep = keep[iso]
    return False


def initial_poses(problem: TeamProblem, reference: int, *, sigma: float = 1.0, max_iter: int = 20,
                  choices: dict[int, int] | None = None, record: list[int] | None = None,
                  nuisance: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Start poses ``T_ref_i`` (Rs, ts) and which robots could be placed.

    Robots are placed greedily, the best-tied first.  A robot ``r`` can be
    placed once some placed camera ``c`` has, together with ``r``'s own
    views of markers of placed robots, at least three observations
    (:data:`MIN_TIES`): that is the pair problem ``(r, c)`` with known points
    on both sides, which the minimal solvers solve (3 observations, any split:
    several exact poses, the one fitting ``r``'s other observations best is
    kept) or over-determine.  So "r sees two of q's markers" ties r to the
    team when one more observation joins it: r sees a third marker of any
    placed robot, or some placed robot's camera sees one of r's markers.

    When that stalls, robots tied by observations spread over several placed
    cameras (a non-central problem), and groups of robots tied to the placed
    ones only together, are solved among themselves and placed as one rigid
    body by the generalized minimal solver (:func:`_attach_group`); then the
    robot-by-robot placement resumes.  Robots (and groups) with fewer than
    three ties are not placed: they are never guessed.  ``sigma`` (pixels)
    is the noise a start must fit r's ties within before the cheap start is
    trusted.

    ``record`` (a list) receives every robot placed on exactly three
    observations (and the first robot of every group attached by three):
    several poses fit those exactly.  ``choices`` ``{robot: k}`` makes such
    a placement take the generalized solver's ``k``-th exact pose instead
    (a restart of :func:`solve_team`; :class:`_NoSuchChoice` when there are
    not that many).  ``nuisance`` (a bool array, written): robots a loop's
    start (:func:`_sampled_group`) solved along without isolating them.
    """
    N = problem.n_robots
    placed = np.zeros(N, dtype=bool)
    placed[reference] = True
    Rs = np.zeros((N, 3, 3))
    ts = np.zeros((N, 3))
    Rs[:] = np.eye(3)
    choices = {} if choices is None else choices
    while True:
        _grow(problem, Rs, ts, placed, sigma, max_iter, choices, record)
        if placed.all():
            break
        if not _attach_group(problem, Rs, ts, placed, sigma, max_iter, choices, record) and \
                not _sampled_group(problem, Rs, ts, placed, sigma, max_iter, nuisance):
            break
    return Rs, ts, placed


@njit(cache=True)
def _rcm_kernel(a, b, k):
    """Reverse Cuthill-McKee order of ``k`` nodes joined by the edges
    ``a[j]``--``b[j]``: each component breadth-first from a node of least
    degree, neighbours by increasing degree, then reversed."""
    src = np.empty(2 * a.shape[0], dtype=np.int64)
    dst = np.empty(2 * a.shape[0], dtype=np.int64)
    m = 0
    for j in range(a.shape[0]):
        if a[j] != b[j]:
            src[m] = a[j]
            dst[m] = b[j]
            src[m + 1] = b[j]
            dst[m + 1] = a[j]
            m += 2
    key = np.unique(src[:m] * k + dst[:m])
    ptr = np.zeros(k + 1, dtype=np.int64)
    for e in key:
        ptr[e // k + 1] += 1
    for i in range(k):
        ptr[i + 1] += ptr[i]
    nbr = key % k
    deg = ptr[1:] - ptr[:-1]
    seen = np.zeros(k, dtype=np.bool_)
    order = np.empty(k, dtype=np.int64)
    n = 0
    while n < k:
        start = -1
        for i in range(k):
            if not seen[i] and (start < 0 or deg[i] < deg[start]):
                start = i
        seen[start] = True
        order[n] = start
        head = n
        n += 1
        while head < n:
            v = order[head]
            head += 1
            lo = n
            for e in range(ptr[v], ptr[v + 1]):
                w = nbr[e]
                if not seen[w]:
                    seen[w] = True
                    # insertion by degree keeps the new neighbours sorted
                    p = n
                    while p > lo and deg[order[p - 1]] > deg[w]:
                        order[p] = order[p - 1]
                        p -= 1
                    order[p] = w
                    n += 1
    return order[::-1].copy()


def _rcm(problem: TeamProblem, order: np.ndarray) -> np.ndarray:
    """Reverse Cuthill-McKee permutation of ``order`` (robots) by shared observations."""
    k = len(order)
    if k <= 2:
        return np.arange(k)
    pos = np.full(problem.n_robots, -1)
    pos[order] = np.arange(k)
    a, b = pos[problem.cam], pos[problem.own]
    ok = (a >= 0) & (b >= 0)
    return _rcm_kernel(a[ok], b[ok], k)


#: Restarts :func:`solve_team` tries at most before it reports the best optimum it found.
MAX_RESTARTS = 40


def solve_team(problem: TeamProblem, reference: int, *, initial: tuple[np.ndarray, np.ndarray, np.ndarray]
               | None = None, max_iter: int = 50, sigma: float = 1.0,
               confidence: float = DEFAULT_CONFIDENCE) -> TeamSolution:
    """The joint maximum-likelihood poses of every robot tied to ``reference``.

    ``initial`` = (Rs, ts, localized) skips :func:`initial_poses` (a warm
    start, e.g. the previous frame's solution).  From a cold start, an
    optimum whose residual fails the chi-square test at ``confidence``
    (noise ``sigma`` px) may be a local one, and robots left unlocalized
    though three or more observations tie them to the others may have
    failed on a wrong start of another robot: the team is solved again from
    other starts (:func:`_restarts`: the other exact poses of each placement
    on three observations, then spanning trees from other roots) and the
    best kept -- the most robots localized, then the least cost.  Raises
    NoSolutionError if the optimum puts a marker behind a camera,
    DegenerateGeometryError if some pose is not isolated.
    """
    if initial is not None:
        Rs, ts, localized = (np.array(a, dtype=float if i < 2 else bool) for i, a in enumerate(initial))
        localized = localized.copy()
        localized[reference] = True
        Rs[reference], ts[reference] = np.eye(3), np.zeros(3)
        return _solve_from(problem, reference, Rs, ts, localized, max_iter=max_iter)
    record: list[int] = []
    nuisance = np.zeros(problem.n_robots, dtype=bool)
    try:
        start = initial_poses(problem, reference, sigma=sigma, record=record, nuisance=nuisance)
        sol = _solve_from(problem, reference, *start, nuisance, max_iter=max_iter)
    except NoSolutionError as e:
        sol, error = None, e
    good = sol is not None and _fits(sol, sigma, confidence, problem) and _complete(problem, sol.solved)
    # a placement on three observations took one of several exact poses; when
    # later observations can tell them apart (redundancy), try the others too
    ambiguous = bool(record) and sol is not None and 2 * sol.n_obs > 6 * len(sol.order)
    if good and not ambiguous:
        return sol
    best = _restarts(problem, reference, sol, record, sigma, confidence, max_iter, good)
    if best is None:
        raise error
    return best


def _complete(problem: TeamProblem, localized: np.ndarray) -> bool:
    """False when the robots left unlocalized share three or more
    observations with the localized ones (a placement failed, perhaps on a
    wrong exact pose of an earlier one)."""
    return int(np.count_nonzero(localized[problem.cam] != localized[problem.own])) < MIN_TIES


def _fits(sol: TeamSolution, sigma: float, confidence: float, problem: TeamProblem | None = None) -> bool:
    """The optimum's residual within its noise (the chi-square test of
    mutloc.team; trivially so without redundancy or with the test off) and,
    given the ``problem`` it was solved on, no robot's ties fitting far
    worse than the rest (:func:`misfit_robots`)."""
    dof = sol.dof
    if dof <= 0 or confidence >= 1.0:
        return True
    if sol.cost / sigma**2 > chi2_quantile(confidence, dof):
        return False
    return problem is None or not misfit_robots(problem, sol, sigma, confidence)


#: Each robot's ties are tested at the noise the team's residuals show
#: (:func:`judged_sigma`) when that is below the stated one; False: the
#: team is judged at the stated noise only (the joint test), as before
#: (bench/bench_team_check.py switches it to compare).
JUDGE_AT_MEASURED_NOISE = True
#: The lower tail at which a team's residuals show its stated noise too large (:func:`judged_sigma`).
UNDERSTATED_LEVEL = 1e-3


def judged_sigma(sol: TeamSolution, sigma: float) -> float:
    """The noise a team is judged at: its residuals' own, ``sqrt(cost /
    dof)``, when they reject the stated ``sigma`` as too large (``cost /
    sigma**2`` below the :data:`UNDERSTATED_LEVEL` quantile of chi-square
    with the team's dof; with honest noise that happens at that rate, so a
    correct team is judged as before) -- a joint test at the
    stated noise lets one robot in a wrong basin pass when the others fit
    far better than stated (noise-free or low-noise detections) -- else
    ``sigma``; ``sigma`` too for an exact fit (no redundancy, or a cost of
    rounding).  Covariances stay at the stated ``sigma``."""
    dof = sol.dof
    if not JUDGE_AT_MEASURED_NOISE or dof <= 0 or sol.cost <= 1e-12 * sigma**2 * max(sol.n_obs, 1):
        return sigma
    if sol.cost / sigma**2 >= chi2_quantile(UNDERSTATED_LEVEL, dof):
        return sigma  # residuals as large as the stated noise allows: it stands
    return float(np.sqrt(sol.cost / dof))


def misfit_robots(problem: TeamProblem, sol: TeamSolution, sigma: float,
                  confidence: float = DEFAULT_CONFIDENCE) -> list[int]:
    """Localized robots whose ties (``problem`` the one ``sol`` was solved
    on; observations by or of the robot) fit worse than their noise allows:
    their squared residuals over :func:`judged_sigma` squared above the
    chi-square quantile at ``confidence`` with ``2n - 6`` degrees of freedom
    (``n`` ties; at the joint optimum a robot's ties keep at most that much
    of the noise, so the test errs towards passing).  A robot left in a wrong
    basin while the others fit well shows here though the joint test, its
    misfit shared over the whole team's degrees of freedom, passes.  Robots
    on three ties are never misfit (nothing to test); none when the stated
    noise stands (residuals as large as it allows), and none with the test
    off (``confidence`` 1 or :data:`JUDGE_AT_MEASURED_NOISE` False)."""
    if confidence >= 1.0 or not JUDGE_AT_MEASURED_NOISE or len(sol.order) == 0:
        return []
    s = judged_sigma(sol, sigma)
    if s >= sigma:
        return []  # the stated noise stands: the joint test at it decides, as for any team
    used = problem.take(sol.used)
    e2 = residual_norms(used, sol.Rs, sol.ts) ** 2
    out = []
    for r in sol.order.tolist():
        rows = (used.cam == r) | (used.own == r)
        n_r = int(np.count_nonzero(rows))
        if n_r > MIN_TIES and float(e2[rows].sum()) / s**2 > chi2_quantile(confidence, 2 * n_r - 6):
            out.append(int(r))
    return out


def _restarts(problem: TeamProblem, reference: int, sol: TeamSolution | None, record: list[int], sigma: float,
              confidence: float, max_iter: int, good: bool = False) -> TeamSolution | None:
    """The team solved from other starts, the best kept (see :func:`solve_team`):

    1. each placement on exactly three observations (``record``) takes
       another of its exact poses, one at a time, then with the best such
       change kept, the others again (a greedy descent over the choices);
    2. the placement grown from every other robot as the root (another
       spanning tree), re-expressed in the reference's frame.

    At most :data:`MAX_RESTARTS` solves; stops at the first that fits,
    except when the first solution ``good`` already did: then 1. looks for
    a lower optimum among all the exact poses (the maximum-likelihood one)
    unless one fits exactly, and 2. is skipped."""
    best = sol
    budget = [MAX_RESTARTS]

    def better(s: TeamSolution) -> bool:
        if best is None:
            return True
        nb, ns = int(best.localized.sum()), int(s.localized.sum())
        return ns > nb or (ns == nb and s.cost < best.cost * (1.0 - 1e-9) - 1e-15)

    def done(s: TeamSolution) -> bool:
        if not (_fits(s, sigma, confidence, problem) and _complete(problem, s.solved)):
            return False
        return not good or s.cost <= 1e-12 * sigma**2 * max(s.n_obs, 1)

    def attempt(start) -> TeamSolution | None:
        budget[0] -= 1
        try:
            s = _solve_from(problem, reference, *start, max_iter=max_iter)
            if s.information.size:
                checked_factor(s.information)  # more robots, but not all isolated: no better
            return s
        except (NoSolutionError, DegenerateGeometryError):
            return None

    chosen: dict[int, int] = {}
    keys = list(dict.fromkeys(record))
    while keys and budget[0] > 0:
        step = None
        for key in keys:
            for k in range(8):
                if budget[0] <= 0:
                    break
                nuisance = np.zeros(problem.n_robots, dtype=bool)
                try:
                    start = (*initial_poses(problem, reference, sigma=sigma, choices={**chosen, key: k},
                                            nuisance=nuisance), nuisance)
                except _NoSuchChoice:
                    break
                s = attempt(start)
                if s is not None and better(s):
                    best, step = s, (key, k)
                    if done(s):
                        return s
        if step is None:
            break
        chosen[step[0]] = step[1]
        keys.remove(step[0])
    if good or (best is not None and _fits(best, sigma, confidence, problem) and _complete(problem, best.solved)):
        return best
    C = problem.counts()
    degree = C.sum(axis=0) + C.sum(axis=1)
    for root in np.argsort(-degree, kind="stable").tolist():
        if root == reference or degree[root] == 0 or budget[0] <= 0:
            continue
        nuisance = np.zeros(problem.n_robots, dtype=bool)
        Rs, ts, placed = initial_poses(problem, root, sigma=sigma, nuisance=nuisance)
        if not placed[reference]:
            continue
        # T_ref_i = T_root_ref^-1 T_root_i
        Rr, tr = Rs[reference].copy(), ts[reference].copy()
        Rs = np.einsum("ji,njk->nik", Rr, Rs)
        ts = (ts - tr) @ Rr
        s = attempt((Rs, ts, placed, nuisance))
        if s is not None and better(s):
            best = s
            if _fits(s, sigma, confidence, problem) and _complete(problem, s.solved):
                return s
    return best


def _solve_from(problem: TeamProblem, reference: int, Rs: np.ndarray, ts: np.ndarray, localized: np.ndarray,
                nuisance: np.ndarray | None = None, max_iter: int = 50) -> TeamSolution:
    """The joint LM from the start (Rs, ts) over the ``localized`` robots and
    the ``nuisance`` ones (solved along; see :class:`TeamSolution`)."""
    if nuisance is not None and not nuisance.any():
        nuisance = None
    both = localized if nuisance is None else localized | nuisance
    used = np.flatnonzero(both[problem.cam] & both[problem.own])
    sub = problem.take(used)
    var = np.full(problem.n_robots, -1, dtype=np.int64)
    order = np.array([i for i in range(problem.n_robots) if both[i] and i != reference], dtype=np.int64)
    # unknowns in reverse Cuthill-McKee order of the observation graph: a
    # narrow envelope for the Cholesky factor
    rcm = _rcm(sub, order)
    var[order[rcm]] = np.arange(len(order))
    cost, it, H = _lm(sub, var, Rs, ts, max_iter)
    # back to index order (the order of ``order``)
    idx = (6 * var[order][:, None] + np.arange(6)[None, :]).ravel()
    H = H[np.ix_(idx, idx)]
    if not np.isfinite(cost):
        raise NoSolutionError("the team's start poses put a marker behind the camera observing it")
    params = 0
    if nuisance is not None:
        H, params = _marginalised(H, nuisance[order])
        order = order[~nuisance[order]]
        localized = localized & ~nuisance
    return TeamSolution(Rs=Rs, ts=ts, localized=localized, order=order, cost=cost, n_obs=len(used),
                        information=H, iterations=it, used=used, nuisance=nuisance, nuisance_params=params)


#: A localized robot tied to the others by at most this many observations
#: is searched for a second pose that fits them (:func:`other_poses`): its
#: own redundancy ``2n - 6`` is then at most 6, few enough equations that
#: two distant poses can both fit within the noise (random three-robot teams
#: with one robot on four ties: 18% of them solved far from the truth at
#: 1 px; on five, 2%; on six, none of 200).  Better-tied robots cost nothing.
AMBIGUITY_TIES = 6
#: A second consistent pose is another pose when it lies more than this many
#: standard deviations (Mahalanobis, the robot's marginal covariance) from
#: the optimum; closer, it is the optimum's own spread.
AMBIGUITY_SIGMAS = 5.0
#: A second pose whose ties, the others held, fit this many times worse than
#: their noise allows is re-optimized jointly (the others may move to it).
_JOINT_FACTOR = 10.0


def other_poses(problem: TeamProblem, sol: TeamSolution, reference: int, *, sigma: float = 1.0,
                confidence: float = DEFAULT_CONFIDENCE, max_iter: int = 50
                ) -> tuple[TeamSolution, dict[int, list[tuple[np.ndarray, np.ndarray, float, float]]]]:
    """Every weakly tied robot's other poses that fit the observations as well.

    For each localized robot ``r`` tied to the others by at most
    :data:`AMBIGUITY_TIES` used observations (``problem`` the one ``sol``
    was solved on; ``sol.used`` indexes it), the others held at their
    optimum: every exact pose of every three of its ties (the generalized
    minimal solver, rays of ``r``'s camera and of the cameras seeing it) and
    the optimum turned about r's observed points (:func:`_seeds`) is refined
    on its ties (LM over ``r``'s pose).  Each other minimum is re-optimized
    jointly (every robot); one that stays apart from the optimum and passes
    both the chi-square test of ``r``'s ties (``2n - 6`` degrees of freedom;
    none for three) and the team's joint test is another consistent pose.
    One more than :data:`AMBIGUITY_SIGMAS` standard deviations away (r's
    covariance) leaves ``r`` unverified, as a pair on three markers: the
    observations cannot tell which is right.

    Returns the solution (jointly re-solved from another minimum that fits
    better than the optimum, consistent or not: the start had missed the
    global one) and ``{r: [(R, t, cost, sigmas), ...]}`` -- every other
    consistent pose ``T_ref_r`` found, with the joint cost at it and its
    distance from the optimum in standard deviations, best first.
    ``confidence`` 1 (the test switched off) searches at
    :data:`DEFAULT_CONFIDENCE`."""
    if confidence >= 1.0:
        confidence = DEFAULT_CONFIDENCE
    found: dict[int, list[tuple[np.ndarray, np.ndarray, float, float]]] = {}
    for _ in range(3):
        if sol.information.size == 0:
            return sol, found
        used = problem.take(sol.used)
        cam, own = used.cam, used.own
        weak = [int(i) for i in sol.order
                if np.count_nonzero((cam == i) | (own == i)) <= AMBIGUITY_TIES]
        if not weak:
            return sol, found
        joint_gate = sigma**2 * chi2_quantile(confidence, sol.dof) if sol.dof > 0 else \
            max(1e-9 * sigma**2 * max(sol.n_obs, 1), 1e-12)
        better = None
        found = {}
        for r in weak:
            rows = np.flatnonzero((cam == r) | (own == r))
            if len(rows) < MIN_TIES:
                continue
            ties = used.take(rows)
            n_r = len(rows)
            # r's own test (none on three ties: the others' noise alone may
            # leave no exact pose near the truth, a double root turned complex)
            gate = sigma**2 * chi2_quantile(confidence, 2 * n_r - 6) if n_r > 3 else np.inf
            tc = lambda R_, t_: team_cost_any(ties.cam, ties.own, ties.points, ties.uv, ties.wt, ties.K,  # noqa
                                              ties.dist, ties.fr, R_, t_)
            c0 = tc(sol.Rs, sol.ts)
            rays = []
            for j in range(n_r):
                a, b = int(ties.cam[j]), int(ties.own[j])
                ray = ties.ray(j)
                if ray is None:
                    continue
                o, bear = ray
                if a == r:  # r's camera sees a placed marker: a ray of r's frame
                    rays.append((KIND_U_RAY, o, bear, sol.Rs[b] @ ties.points[j] + sol.ts[b]))
                else:  # a placed camera sees r's marker: a ray of the reference's frame
                    rays.append((KIND_W_RAY, sol.ts[a] if ties.frames is None else sol.ts[a] + sol.Rs[a] @ o,
                                 sol.Rs[a] @ bear, ties.points[j]))
            # r's marginal information (the inverse of its covariance block)
            k = int(np.flatnonzero(sol.order == r)[0])
            E = np.zeros((sol.information.shape[0], 6))
            E[6 * k:6 * k + 6] = np.eye(6)
            try:
                info_r = np.linalg.inv(sigma**2 * np.linalg.solve(sol.information, E)[6 * k:6 * k + 6])
            except np.linalg.LinAlgError:
                return sol, found
            R0, t0 = sol.Rs[r].copy(), sol.ts[r].copy()

            def distance(Ra: np.ndarray, ta: np.ndarray, Rb: np.ndarray, tb: np.ndarray) -> float:
                """Mahalanobis, r's covariance at the optimum."""
                d = np.r_[so3_log(Ra @ Rb.T), ta - tb]
                return float(np.sqrt(max(d @ info_r @ d, 0.0)))

            var = np.full(problem.n_robots, -1, dtype=np.int64)
            var[r] = 0
            H = np.empty((6, 6))
            Rtry, ttry = sol.Rs.copy(), sol.ts.copy()
            # r's minima on its ties, the others held: the optimum's basin first
            minima: list[tuple[np.ndarray, np.ndarray, float]] = [(R0, t0, c0)]
            for R, t in _seeds(rays, R0, t0):
                Rtry[r], ttry[r] = R, t
                cost, _ = team_lm(ties.cam, ties.own, ties.points, ties.uv, ties.wt, ties.K, ties.dist, ties.fr, var,
                                  Rtry, ttry, max_iter, H)
                if np.isfinite(cost) and not any(_close(Rtry[r], ttry[r], m[0], m[1]) for m in minima):
                    minima.append((Rtry[r].copy(), ttry[r].copy(), cost))
            alts: list[tuple[np.ndarray, np.ndarray, float, float]] = []
            for R1, t1, cost in minima[1:]:
                Rj, tj = sol.Rs.copy(), sol.ts.copy()
                Rj[r], tj[r] = R1, t1
                total = sol.cost - c0 + cost
                if total < sol.cost * (1.0 - 1e-9) - 1e-12 and (better is None or total < better[2]):
                    # lower than the optimum, fitting or not (the optimum may
                    # fail its test from a wrong basin): solved again from it
                    better = (Rj.copy(), tj.copy(), total)
                if cost > _JOINT_FACTOR * gate:
                    continue
                # every robot re-optimized from the second pose (the others,
                # held at the optimum, may hold r off its own minimum)
                try:
                    s = _solve_from(problem, reference, Rj, tj, sol.localized.copy(), sol.nuisance,
                                    max_iter=max_iter)
                except NoSolutionError:
                    continue
                d = distance(s.Rs[r], s.ts[r], R0, t0)
                if not np.array_equal(s.used, sol.used) or _close(s.Rs[r], s.ts[r], R0, t0) or \
                        any(_close(s.Rs[r], s.ts[r], a[0], a[1]) for a in alts):
                    continue
                if not (tc(s.Rs, s.ts) <= gate and s.cost <= joint_gate):
                    continue
                alts.append((s.Rs[r].copy(), s.ts[r].copy(), float(s.cost), d))
                if s.cost < sol.cost * (1.0 - 1e-9) - 1e-12 and (better is None or s.cost < better[2]):
                    better = (s.Rs.copy(), s.ts.copy(), s.cost)
            if alts:
                found[r] = sorted(alts, key=lambda a: a[2])
        if better is None:
            return sol, found
        # a second pose fits better than the optimum: the start had missed
        # the global one; solve from it and search again around it
        try:
            s = _solve_from(problem, reference, better[0].copy(), better[1].copy(), sol.localized.copy(),
                            sol.nuisance, max_iter=max_iter)
            if s.information.size:
                checked_factor(s.information)
        except (NoSolutionError, DegenerateGeometryError):
            return sol, found
        if not np.array_equal(s.used, sol.used) or s.cost >= sol.cost:
            return sol, found
        sol = s
    return sol, found


#: Turns of a weakly tied robot about its observed markers that seed the
#: search for its other poses besides the minimal solutions (which vanish,
#: a pair of roots turned complex, when noise moves a near-double root).
SEED_TURNS = 64


def _seeds(rays: list[tuple], R0: np.ndarray, t0: np.ndarray):
    """Starts for :func:`other_poses`: on three rays whose known points
    differ, their every exact pose (generalized minimal solver); then the
    optimum ``(R0, t0)`` turned about the centre of the robot's observed
    points by :data:`SEED_TURNS` seeded random rotations."""
    from itertools import combinations

    # the exact poses of three ties (on more, the turns below find every
    # minimum as well -- the same on the draws of test_team_ambiguity -- at
    # a fraction of the minimal solver's cost)
    for tri in combinations(range(len(rays)), 3) if len(rays) == 3 else ():
        kinds, origins, dirs, points = (np.array([rays[i][f] for i in tri]) for f in range(4))
        # the same marker twice (seen by two cameras): no triangle to fit
        if any(kinds[a] == kinds[b] and np.linalg.norm(points[a] - points[b]) < 1e-9
               for a, b in ((0, 1), (0, 2), (1, 2))):
            continue
        Rc, tc = generalized_p3p(kinds, origins, dirs, points)
        yield from zip(Rc, tc)
    # the robot's own points: its markers others see, its camera centre
    mine = [ray[3] if ray[0] == KIND_W_RAY else ray[1] for ray in rays]
    c = np.mean(mine, axis=0)
    for Q in _turns():
        R = R0 @ Q
        yield R, t0 + R0 @ c - R @ c


_TURNS: list[np.ndarray] = []


def _turns() -> list[np.ndarray]:
    if not _TURNS:
        rng = np.random.default_rng(20130913)
        _TURNS.extend(_random_rotation(rng) for _ in range(SEED_TURNS))
    return _TURNS


def _close(Ra: np.ndarray, ta: np.ndarray, Rb: np.ndarray, tb: np.ndarray) -> bool:
    """One minimum, to what refinement reaches (1e-5 rad, 1e-5 of the
    distance): distinct exact poses of three ties may lie well within the
    covariance, and are distinct candidates all the same."""
    return (np.linalg.norm(Ra - Rb) < 1e-5 * np.sqrt(2.0)
            and np.linalg.norm(ta - tb) < 1e-5 * max(1.0, float(np.linalg.norm(ta))))


def _marginalised(H: np.ndarray, drop: np.ndarray) -> tuple[np.ndarray, int]:
    """The information of the robots not in ``drop`` (a mask over H's
    6-blocks) with the dropped ones marginalised out (Schur complement with
    the pseudo-inverse of their block), and the rank of that block.
    DegenerateGeometryError when a kept robot is not isolated."""
    if not _isolated(H)[~drop].all():
        raise DegenerateGeometryError("the observations do not determine an isolated pose for every robot")
    m = np.repeat(drop, 6)
    Hnn = H[np.ix_(m, m)]
    d = np.sqrt(np.maximum(np.diag(Hnn), 1e-300))
    w, V = np.linalg.eigh(Hnn / d[:, None] / d[None, :])
    big = w > 1e-9 * max(float(w.max()), 1e-300)
    pinv = (V[:, big] / w[big]) @ V[:, big].T / d[:, None] / d[None, :]
    Hin = H[np.ix_(~m, m)]
    marg = H[np.ix_(~m, ~m)] - Hin @ pinv @ Hin.T
    return 0.5 * (marg + marg.T), int(big.sum())


def residual_norms(problem: TeamProblem, Rs: np.ndarray, ts: np.ndarray) -> np.ndarray:
    """Each observation's reprojection error (pixels) at poses (Rs, ts);
    inf for a marker behind its observer."""
    out = np.full(len(problem.cam), np.inf)
    _residual_norms(problem.cam, problem.own, problem.points, problem.uv, problem.wt, problem.K, problem.dist, problem.fr,
                    np.ascontiguousarray(Rs, dtype=float), np.ascontiguousarray(ts, dtype=float), out)
    return out


@njit(cache=True)
def _residual_norms(cam, own, pts, meas, wt, Ks, ds, frames, Rs, ts, out):
    """``out[j]``: observation ``j``'s reprojection error, each on its own (one
    behind its observer leaves its ``out[j]`` as it is)."""
    r = np.empty(2)
    J = np.empty((1, 2, 6))
    for j in range(cam.shape[0]):
        # (frames empty in pixel mode: so is its slice)
        if team_residuals_any(cam[j:j + 1], own[j:j + 1], pts[j:j + 1], meas[j:j + 1], wt[j:j + 1], Ks, ds,
                              frames[j:j + 1], Rs, ts,
                              r, J, J, np.bool_(False)):
            out[j] = np.hypot(r[0], r[1])


def relative_jacobian(Ra: np.ndarray, ta: np.ndarray, Rb: np.ndarray, tb: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Jacobians (6x6 each) of ``T_ba = T_b^-1 T_a`` with respect to the
    perturbations of ``T_a`` and ``T_b`` (both ``T_ref_*``, SPEC convention)."""
    RbT = Rb.T
    d = ta - tb
    S = np.array([[0.0, -d[2], d[1]], [d[2], 0.0, -d[0]], [-d[1], d[0], 0.0]])
    Ja = np.zeros((6, 6))
    Ja[:3, :3] = RbT
    Ja[3:, 3:] = RbT
    Jb = np.zeros((6, 6))
    Jb[:3, :3] = -RbT
    Jb[3:, :3] = RbT @ S
    Jb[3:, 3:] = -RbT
    return Ja, Jb
