"""Marker self-calibration: a bundle adjustment over every frame's relative
poses and every marker's position (SPEC "Marker calibration").  No I/O.

Unknowns.  A *group* is one frame's robots tied together by their mutual
observations; its first robot is the group's *anchor* and every other member
has a pose ``T_aj`` (``x_a = R @ x_j + t``, perturbed as refine does:
``R <- exp(dtheta) @ R``, ``t <- t + dt``) in a *slot* of the group.  Every
marker is a *body* with one position (its centre) in its own robot's frame
(its camera's, or a body frame for robots with several cameras), shared by
all frames; the observed *points* are fixed offsets in the body's frame: a ball is one point at its centre, a printed tag its four
corners (the body also has a rotation, perturbed on the left like the
poses), a banded cylinder its bands along its axis.  Where robot frames are
camera frames, nothing but the scale is free without a known body size:
scaling every marker and every translation by ``s`` leaves every pixel
unchanged (cameras posed apart on one robot fix it only weakly).  The scale
is held by equality constraints on distances between the centres of
markers of one robot.

Residuals are pixels through each observer's camera model (core.camera's
projection and its Jacobian) with a Huber loss on each observation's
residual length (stray detections).  Robots with several cameras or any
lens (:mod:`mutloc.core.rays`): robot frames are body frames, and each
observation is a ray of its observer's robot frame (its camera's centre,
its lens's unprojection, its tangent directions scaled by the lens's
Jacobian); the residual is the gnomonic error around that ray, the pixel
error in that camera to first order (as :data:`mutloc.core.refine.MODE_RAY`).  The normal equations are sparse: one
dense block per group (six rows per slot) and one block for the markers.
The groups are eliminated (Schur complement), the reduced marker system is
solved together with the linearised constraints (KKT), and the groups are
recovered by back-substitution.  The markers' covariance with the scale
held is ``sigma^2 Z (Z^T S Z)^-1 Z^T``, ``S`` the reduced information and
``Z`` a basis of the directions the constraints leave free.

The kernel works on points; the bodies enter by the chain rule: with ``A``
the points' Jacobian with respect to the bodies' parameters (identity for
balls; ``[I | -[R o]x]`` for a corner at offset ``o`` of a tag turned by
``R``) the body-space blocks are ``H_gm A``, ``A^T H_mm A`` and ``A^T g_m``.
Body parameters: every body's centre (3 each, in body order), then the
rotation of every rotating body (3 each, in body order).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit

from ..errors import InputError
from .camera import project_jac_kernel, project_kernel
from .refine import MODE_PIXEL, MODE_RAY, so3_exp_left

__all__ = ["BundleProblem", "Adjustment", "adjust", "constraint_jacobian", "null_space", "start_depths", "HUBER_K"]

#: Huber threshold, in units of the pixel sigma: an observation whose residual
#: is longer than this counts linearly (a Gaussian 2-D residual exceeds 3.5
#: sigma with probability 0.2 %).
HUBER_K = 3.5
# Levenberg-Marquardt: starting damping, tries per iteration, stopping rule.
_LAMBDA0 = 1e-4
_MAX_TRIES = 12
_REL_COST_TOL = 1e-12
_STEP_TOL = 1e-12


@dataclass(frozen=True)
class BundleProblem:
    """Observations in solver form (one row each) and what they refer to.

    ``group[k]`` is the observation's group, ``observer_slot[k]`` and
    ``owner_slot[k]`` the slots of the observing robot and of the marker's
    robot in that group (-1: the anchor), ``camera[k]`` the observer's
    camera (rows of ``K``/``dist``), ``marker[k]`` the marker (row of the
    positions), ``uv[k]`` the observed raw pixel.  ``slot_used`` (groups,
    slots) says which slots hold a robot.  ``constraints`` are ``(i, j, D)``:
    markers ``i`` and ``j`` (of one robot) held ``D`` metres apart.
    ``prior`` (M, 3), when given, adds ``prior_weight * |m - prior|^2``
    (pixels^2) to the cost: the given positions as a measurement
    (``prior_weight = (pixel_sigma / prior_sigma)^2``).

    ``marker[k]`` indexes *points* (``n_markers`` of them).  Without
    ``point_body`` every point is a body of its own (a ball); with it, point
    ``i`` is ``centre[point_body[i]] + R[point_body[i]] @ point_offset[i]``
    and ``body_rotates[b]`` says whether body ``b``'s rotation is estimated
    (a tag) or held (a ball, a cylinder).  ``constraints`` and ``prior``
    refer to bodies.  ``prior_directions`` (h, 3B), orthonormal rows, limits
    the prior to those combinations of the centres:
    ``prior_weight * |D (m - prior)|^2`` (the directions the observations
    determine only weakly, held near the given rig).

    ``frames`` (n, 4, 3), when given, makes every row a ray
    (:func:`mutloc.core.rays.ray_frames`: two lens-scaled tangent rows, the
    ray's direction and its origin, in the observer's robot frame): the
    residual is then the gnomonic error around it (pixels to first order)
    and ``K``/``dist``/``camera``/``uv`` are not used.
    """

    group: np.ndarray
    observer_slot: np.ndarray
    owner_slot: np.ndarray
    camera: np.ndarray
    marker: np.ndarray
    uv: np.ndarray
    K: np.ndarray
    dist: np.ndarray
    slot_used: np.ndarray
    n_markers: int
    constraints: tuple[tuple[int, int, float], ...]
    prior: np.ndarray | None = None
    prior_weight: float = 0.0
    point_body: np.ndarray | None = None
    point_offset: np.ndarray | None = None
    body_rotates: np.ndarray | None = None
    prior_directions: np.ndarray | None = None
    frames: np.ndarray | None = None

    @property
    def mode(self) -> int:
        return MODE_PIXEL if self.frames is None else MODE_RAY

    def ray_frames(self) -> np.ndarray:
        """The rows' ray frames (an empty array in pixel mode: the kernel's argument)."""
        if self.frames is None:
            return np.zeros((0, 4, 3))
        return np.ascontiguousarray(self.frames, dtype=float).reshape(-1, 4, 3)

    @property
    def n_bodies(self) -> int:
        return self.n_markers if self.point_body is None else len(self.body_rotates)

    @property
    def n_rotating(self) -> int:
        return 0 if self.body_rotates is None else int(np.sum(self.body_rotates))

    @property
    def n_parameters(self) -> int:
        """Body parameters: 3 per centre, 3 per estimated rotation."""
        return 3 * self.n_bodies + 3 * self.n_rotating

    def prior_matrix(self) -> np.ndarray | None:
        """The prior's information over the centres (3B, 3B), pixels^-2 units; None without one."""
        if self.prior is None or self.prior_weight <= 0:
            return None
        if self.prior_directions is None:
            return self.prior_weight * np.eye(3 * self.n_bodies)
        D = np.asarray(self.prior_directions, dtype=float).reshape(-1, 3 * self.n_bodies)
        return self.prior_weight * (D.T @ D)

    @property
    def n_groups(self) -> int:
        return int(self.slot_used.shape[0])

    @property
    def n_slots(self) -> int:
        return int(self.slot_used.shape[1])

    @property
    def n_pose_parameters(self) -> int:
        return 6 * int(self.slot_used.sum())

    @property
    def dof(self) -> int:
        """Residuals minus free parameters (the scale is held, not free)."""
        return 2 * len(self.group) - self.n_pose_parameters - (self.n_parameters - len(self.constraints))


@dataclass
class Adjustment:
    """The bundle adjustment's optimum.

    ``markers`` (B, 3) the bodies' centres, ``rotations`` (B, 3, 3) their
    rotations, ``points`` (P, 3) the observed points, ``R`` (groups, slots,
    3, 3), ``t`` (groups, slots, 3); ``information`` is the reduced
    information ``S`` over the body parameters (n, n) in pixels^-2 units
    (``J^T W J`` with the groups eliminated); ``residuals``
    (n, 2) pixels and ``weights`` (n,) the Huber weights at the optimum;
    ``cost`` the robust cost (pixels^2), ``chi2`` the plain sum of squared
    residuals over sigma^2.
    """

    markers: np.ndarray
    R: np.ndarray
    t: np.ndarray
    information: np.ndarray
    residuals: np.ndarray
    weights: np.ndarray
    cost: float
    chi2: float
    iterations: int
    converged: bool

    prior_weight: float = 0.0
    rotations: np.ndarray | None = None
    points: np.ndarray | None = None
    prior_information: np.ndarray | None = None

    def data_information(self) -> np.ndarray:
        """The information without the prior (what the observations alone say)."""
        S = self.information
        if self.prior_information is not None:
            S = S.copy()
            k = self.prior_information.shape[0]
            S[:k, :k] -= self.prior_information
        return S

    def marker_covariance(self, constraints_jacobian: np.ndarray, pixel_sigma: float,
                          data_only: bool = False, prior_sigma: float | None = None) -> tuple[np.ndarray, np.ndarray]:
        """(covariance (n, n) of the body parameters with the constraints
        held, eigenvalues of the constrained information ``Z^T S Z``,
        ascending); ``data_only``: without the prior.

        ``prior_sigma`` (metres): the prior's own error, 1 sigma per
        combination it holds, when its weight is not ``(pixel_sigma /
        prior_sigma)^2`` (a combination held stiffer than it is known, i.e.
        taken from the prior rather than fused with the log): the sandwich
        ``N^-1 (sigma^2 S_data + prior_sigma^2 P P) N^-1`` instead of
        ``sigma^2 N^-1`` (the two agree when the weight is that one)."""
        S = self.data_information() if data_only else self.information
        Z = null_space(constraints_jacobian, S.shape[0])
        N = Z.T @ S @ Z
        N = 0.5 * (N + N.T)
        w, V = np.linalg.eigh(N)
        if w[0] <= 0.0:
            inv = np.full_like(N, np.inf)
        else:
            inv = (V / w) @ V.T
        if prior_sigma is None or data_only or self.prior_information is None or not np.all(np.isfinite(inv)):
            cov = pixel_sigma**2 * (Z @ inv @ Z.T)
        else:
            P = np.zeros_like(S)
            k = self.prior_information.shape[0]
            P[:k, :k] = self.prior_information
            M = pixel_sigma**2 * self.data_information() + prior_sigma**2 * (P @ P)
            G = Z @ inv @ Z.T
            cov = G @ M @ G
        return 0.5 * (cov + cov.T), w


def null_space(C: np.ndarray, n: int) -> np.ndarray:
    """Orthonormal basis (n, n - rank) of the directions ``C`` leaves free."""
    if C.shape[0] == 0:
        return np.eye(n)
    _, s, Vt = np.linalg.svd(C, full_matrices=True)
    rank = int(np.sum(s > 1e-12 * max(1.0, s[0])))
    return Vt[rank:].T


def constraint_jacobian(markers: np.ndarray, constraints: tuple[tuple[int, int, float], ...],
                        n_parameters: int | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Values ``|m_i - m_j| - D`` (nc,) and their Jacobian (nc, n_parameters;
    default 3M: the centres alone)."""
    M = markers.shape[0]
    c = np.zeros(len(constraints))
    C = np.zeros((len(constraints), 3 * M if n_parameters is None else n_parameters))
    for k, (i, j, D) in enumerate(constraints):
        d = markers[i] - markers[j]
        n = float(np.linalg.norm(d))
        c[k] = n - D
        u = d / n if n > 0 else np.zeros(3)
        C[k, 3 * i:3 * i + 3] = u
        C[k, 3 * j:3 * j + 3] = -u
    return c, C


# ---------------------------------------------------------------------------
# kernels
# ---------------------------------------------------------------------------


@njit(cache=True)
def _linearize(group, oslot, wslot, cam, marker, uv, K, dist, mode, rays, M, R, t, sigma, huber, want,
               Hgg, Hgm, Hmm, gg, gm, res, wts):
    """Robust cost (pixels^2); with ``want`` also the weighted normal
    equations, accumulated into the (zeroed) ``H*``/``g*``.  ``res`` and
    ``wts`` receive each observation's residual and Huber weight.  inf when
    a marker falls behind the camera that sees it (in ``MODE_RAY``: at a
    right angle or more off its observed ray ``rays[i]``)."""
    n = group.shape[0]
    P = np.empty(3)
    D = np.empty(3)
    X = np.empty(3)
    Y = np.empty(3)
    pix = np.empty(2)
    Jp = np.empty((2, 3))
    B = np.empty((2, 3))
    J = np.zeros((2, 15))
    idx = np.empty(15, np.int64)
    act = np.zeros(15, np.bool_)
    cost = 0.0
    for i in range(n):
        g = group[i]
        so = oslot[i]
        sw = wslot[i]
        mi = marker[i]
        c = cam[i]
        if sw >= 0:
            for a in range(3):
                P[a] = R[g, sw, a, 0] * M[mi, 0] + R[g, sw, a, 1] * M[mi, 1] + R[g, sw, a, 2] * M[mi, 2] + t[g, sw, a]
        else:
            for a in range(3):
                P[a] = M[mi, a]
        if so >= 0:
            for a in range(3):
                D[a] = P[a] - t[g, so, a]
            for a in range(3):
                X[a] = R[g, so, 0, a] * D[0] + R[g, so, 1, a] * D[1] + R[g, so, 2, a] * D[2]
        else:
            for a in range(3):
                D[a] = P[a]
                X[a] = P[a]
        if mode == MODE_RAY:
            # the gnomonic error around the observed ray, from its own camera's centre
            for a in range(3):
                Y[a] = X[a] - rays[i, 3, a]
            den = rays[i, 2, 0] * Y[0] + rays[i, 2, 1] * Y[1] + rays[i, 2, 2] * Y[2]
            if not den > 1e-150:
                return np.inf
            for k in range(2):
                num = rays[i, k, 0] * Y[0] + rays[i, k, 1] * Y[1] + rays[i, k, 2] * Y[2]
                pix[k] = num / den
                for a in range(3):
                    Jp[k, a] = (rays[i, k, a] * den - num * rays[i, 2, a]) / (den * den)
            r0 = pix[0]
            r1 = pix[1]
        else:
            if want:
                ok = project_jac_kernel(K[c], dist[c], X, pix, Jp)
            else:
                ok = project_kernel(K[c], dist[c], X, pix)
            if not ok:
                return np.inf
            r0 = pix[0] - uv[i, 0]
            r1 = pix[1] - uv[i, 1]
        res[i, 0] = r0
        res[i, 1] = r1
        sq = r0 * r0 + r1 * r1
        e = np.sqrt(sq) / sigma
        if e <= huber:
            w = 1.0
            cost += sq
        else:
            w = huber / e
            cost += sigma * sigma * (2.0 * huber * e - huber * huber)
        wts[i] = w
        if not want:
            continue
        # B = Jp @ Ro^T: pixels per metre in the anchor's frame.
        for k in range(2):
            for a in range(3):
                if so >= 0:
                    B[k, a] = Jp[k, 0] * R[g, so, a, 0] + Jp[k, 1] * R[g, so, a, 1] + Jp[k, 2] * R[g, so, a, 2]
                else:
                    B[k, a] = Jp[k, a]
        for q in range(15):
            act[q] = False
        # observer's pose: dX/dtheta = Ro^T [D]x, dX/dt = -Ro^T
        if so >= 0:
            for k in range(2):
                J[k, 0] = B[k, 1] * D[2] - B[k, 2] * D[1]
                J[k, 1] = -B[k, 0] * D[2] + B[k, 2] * D[0]
                J[k, 2] = B[k, 0] * D[1] - B[k, 1] * D[0]
                J[k, 3] = -B[k, 0]
                J[k, 4] = -B[k, 1]
                J[k, 5] = -B[k, 2]
            for q in range(6):
                idx[q] = 6 * so + q
                act[q] = True
        # owner's pose: dX/dtheta = -Ro^T [Rw m]x, dX/dt = Ro^T
        if sw >= 0:
            y0 = P[0] - t[g, sw, 0]
            y1 = P[1] - t[g, sw, 1]
            y2 = P[2] - t[g, sw, 2]
            for k in range(2):
                J[k, 6] = -(B[k, 1] * y2 - B[k, 2] * y1)
                J[k, 7] = -(-B[k, 0] * y2 + B[k, 2] * y0)
                J[k, 8] = -(B[k, 0] * y1 - B[k, 1] * y0)
                J[k, 9] = B[k, 0]
                J[k, 10] = B[k, 1]
                J[k, 11] = B[k, 2]
            for q in range(6):
                idx[6 + q] = 6 * sw + q
                act[6 + q] = True
        # marker: dX/dm = Ro^T Rw
        for k in range(2):
            for a in range(3):
                if sw >= 0:
                    J[k, 12 + a] = B[k, 0] * R[g, sw, 0, a] + B[k, 1] * R[g, sw, 1, a] + B[k, 2] * R[g, sw, 2, a]
                else:
                    J[k, 12 + a] = B[k, a]
        for a in range(3):
            idx[12 + a] = 3 * mi + a
        # Weighted outer products into the blocks.
        for qa in range(12):
            if not act[qa]:
                continue
            ia = idx[qa]
            gg[g, ia] += w * (J[0, qa] * r0 + J[1, qa] * r1)
            for qb in range(12):
                if act[qb]:
                    Hgg[g, ia, idx[qb]] += w * (J[0, qa] * J[0, qb] + J[1, qa] * J[1, qb])
            for qb in range(12, 15):
                Hgm[g, ia, idx[qb]] += w * (J[0, qa] * J[0, qb] + J[1, qa] * J[1, qb])
        for qa in range(12, 15):
            ia = idx[qa]
            gm[ia] += w * (J[0, qa] * r0 + J[1, qa] * r1)
            for qb in range(12, 15):
                Hmm[ia, idx[qb]] += w * (J[0, qa] * J[0, qb] + J[1, qa] * J[1, qb])
    return cost


@njit(cache=True)
def _apply_step(R, t, M, used, dg, dm, Rn, tn, Mn):
    """New parameters from a step: poses on the left, markers added."""
    G = R.shape[0]
    S = R.shape[1]
    for g in range(G):
        for s in range(S):
            if used[g, s]:
                so3_exp_left(dg[g, 6 * s:6 * s + 3], R[g, s], Rn[g, s])
                for a in range(3):
                    tn[g, s, a] = t[g, s, a] + dg[g, 6 * s + 3 + a]
            else:
                for a in range(3):
                    tn[g, s, a] = t[g, s, a]
                    for b in range(3):
                        Rn[g, s, a, b] = R[g, s, a, b]
    for i in range(M.shape[0]):
        for a in range(3):
            Mn[i, a] = M[i, a] + dm[3 * i + a]


# ---------------------------------------------------------------------------
# the adjustment
# ---------------------------------------------------------------------------


def _prior_cost(p: BundleProblem, M: np.ndarray, W: np.ndarray | None) -> float:
    if W is None:
        return 0.0
    d = (M - p.prior).ravel()
    return float(d @ W @ d)


class _Bodies:
    """The map from body parameters (centres, rotations) to the observed points."""

    def __init__(self, p: BundleProblem):
        P = p.n_markers
        self.identity = p.point_body is None
        if self.identity:
            self.body = np.arange(P)
            self.offset = np.zeros((P, 3))
            rotates = np.zeros(P, dtype=bool)
        else:
            self.body = np.asarray(p.point_body, dtype=np.int64)
            self.offset = np.asarray(p.point_offset, dtype=float).reshape(P, 3)
            rotates = np.asarray(p.body_rotates, dtype=bool)
        B = len(rotates)
        self.n_bodies = B
        self.rot_index = np.full(B, -1, dtype=np.int64)
        self.rot_index[rotates] = 3 * B + 3 * np.arange(int(rotates.sum()))
        self.n = 3 * B + 3 * int(rotates.sum())

    def points(self, C: np.ndarray, Rb: np.ndarray) -> np.ndarray:
        if self.identity:
            return np.ascontiguousarray(C)
        return np.ascontiguousarray(C[self.body] + np.einsum("pij,pj->pi", Rb[self.body], self.offset))

    def jacobian(self, Rb: np.ndarray) -> np.ndarray | None:
        """d points / d parameters (3P, n); None for the identity."""
        if self.identity:
            return None
        P = len(self.body)
        A = np.zeros((3 * P, self.n))
        for i, b in enumerate(self.body.tolist()):
            A[3 * i:3 * i + 3, 3 * b:3 * b + 3] = np.eye(3)
            k = int(self.rot_index[b])
            if k >= 0:
                x, y, z = Rb[b] @ self.offset[i]
                A[3 * i:3 * i + 3, k:k + 3] = -np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])
        return A

    def step(self, C: np.ndarray, Rb: np.ndarray, dm: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        B = self.n_bodies
        Cn = C + dm[:3 * B].reshape(B, 3)
        Rn = Rb.copy()
        for b in np.flatnonzero(self.rot_index >= 0).tolist():
            k = int(self.rot_index[b])
            so3_exp_left(np.ascontiguousarray(dm[k:k + 3]), Rb[b], Rn[b])
        return Cn, Rn


class _System:
    """Buffers of the normal equations, reused across iterations.  ``Hgm``,
    ``Hmm`` and ``gm`` are in body-parameter space after :meth:`linearize`."""

    def __init__(self, problem: BundleProblem):
        G, S, M = problem.n_groups, problem.n_slots, problem.n_markers
        self.bodies = _Bodies(problem)
        self.Hgg = np.zeros((G, 6 * S, 6 * S))
        self.Hgm = np.zeros((G, 6 * S, 3 * M))
        self.Hmm = np.zeros((3 * M, 3 * M))
        self.gg = np.zeros((G, 6 * S))
        self.gm = np.zeros(3 * M)
        n = len(problem.group)
        self.res = np.zeros((n, 2))
        self.wts = np.ones(n)
        # Empty slots get an identity block so every group block is invertible.
        unused = ~problem.slot_used
        self.pad = np.zeros((G, 6 * S))
        self.pad[np.repeat(unused, 6, axis=1)] = 1.0
        self.W = problem.prior_matrix()
        self.rays = problem.ray_frames()

    def linearize(self, p: BundleProblem, M, R, t, sigma: float, huber: float, Rb=None) -> float:
        """Cost and normal equations at body centres ``M`` (rotations ``Rb``)."""
        pts = self.bodies.points(M, Rb)
        Hgm, Hmm, gm = self.Hgm, self.Hmm, self.gm
        if not self.bodies.identity:
            P3 = 3 * p.n_markers
            Hgm = np.zeros(self.Hgg.shape[:2] + (P3,))
            Hmm = np.zeros((P3, P3))
            gm = np.zeros(P3)
        for a in (self.Hgg, Hgm, Hmm, self.gg, gm):
            a.fill(0.0)
        c = _linearize(p.group, p.observer_slot, p.owner_slot, p.camera, p.marker, p.uv, p.K, p.dist, p.mode,
                       self.rays, pts, R, t,
                       sigma, huber, True, self.Hgg, Hgm, Hmm, self.gg, gm, self.res, self.wts)
        A = self.bodies.jacobian(Rb)
        if A is not None:
            self.Hgm = np.einsum("gpi,in->gpn", Hgm, A)
            self.Hmm = A.T @ Hmm @ A
            self.gm = A.T @ gm
        ii = np.arange(self.Hgg.shape[1])
        self.Hgg[:, ii, ii] += self.pad
        if self.W is not None:
            k = self.W.shape[0]
            self.Hmm[:k, :k] += self.W
            self.gm[:k] += self.W @ (M - p.prior).ravel()
        return c + _prior_cost(p, M, self.W)

    def cost(self, p: BundleProblem, M, R, t, sigma: float, huber: float, res, wts, Rb=None) -> float:
        pts = self.bodies.points(M, Rb)
        c = _linearize(p.group, p.observer_slot, p.owner_slot, p.camera, p.marker, p.uv, p.K, p.dist, p.mode,
                       self.rays, pts, R, t,
                       sigma, huber, False, self.Hgg, self.Hgm, self.Hmm, self.gg, self.gm, res, wts)
        return c + _prior_cost(p, M, self.W)

    def reduce(self, lam: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(damped reduced marker matrix, its right-hand side, the groups'
        solves ``A_gg^-1 [H_gm | g_g]``) for damping ``lam``."""
        ii = np.arange(self.Hgg.shape[1])
        Agg = self.Hgg.copy()
        dg = Agg[:, ii, ii]
        Agg[:, ii, ii] = dg + lam * (dg + 1e-9)
        rhs = np.concatenate([self.Hgm, self.gg[:, :, None]], axis=2)
        try:
            sol = np.linalg.solve(Agg, rhs)
        except np.linalg.LinAlgError:
            # a group's pose not determined (at lam = 0): the least damping that solves it
            Agg[:, ii, ii] += 1e-9 * (np.abs(dg) + 1.0)
            sol = np.linalg.solve(Agg, rhs)
        jm = np.arange(self.Hmm.shape[0])
        Amm = self.Hmm.copy()
        Amm[jm, jm] += lam * (np.diag(self.Hmm) + 1e-9)
        Smm = Amm - np.einsum("gpi,gpj->ij", self.Hgm, sol[:, :, :-1])
        b = -self.gm + np.einsum("gpi,gp->i", self.Hgm, sol[:, :, -1])
        return 0.5 * (Smm + Smm.T), b, sol


def start_depths(problem: BundleProblem, markers: np.ndarray, R: np.ndarray, t: np.ndarray,
                 rotations: np.ndarray | None = None) -> np.ndarray:
    """Depth (n,) of every observation's point in its observer's camera at
    the given parameters (a point at depth <= 0 cannot be projected); in
    ray mode its distance along the observed ray from the camera's centre."""
    p = problem
    pts = _Bodies(p).points(np.asarray(markers, float), rotations)[p.marker]
    G, S = p.slot_used.shape
    Rs = np.concatenate([np.broadcast_to(np.eye(3), (G, 1, 3, 3)), R], axis=1)  # slot -1 -> index 0
    ts = np.concatenate([np.zeros((G, 1, 3)), t], axis=1)
    Rw, tw = Rs[p.group, p.owner_slot + 1], ts[p.group, p.owner_slot + 1]
    Ro, to = Rs[p.group, p.observer_slot + 1], ts[p.group, p.observer_slot + 1]
    P = np.einsum("nij,nj->ni", Rw, pts) + tw
    X = np.einsum("nji,nj->ni", Ro, P - to)
    if p.frames is not None:
        # along the observed ray, from its camera's centre
        F = p.ray_frames()
        return np.einsum("ni,ni->n", F[:, 2], X - F[:, 3])
    return X[:, 2]


def adjust(problem: BundleProblem, markers0: np.ndarray, R0: np.ndarray, t0: np.ndarray, *,
           pixel_sigma: float = 1.0, huber: float = HUBER_K, max_iter: int = 100,
           rotations0: np.ndarray | None = None) -> Adjustment:
    """Levenberg-Marquardt from the initial body centres (B, 3) (and
    rotations (B, 3, 3), default identity) and group poses (groups, slots,
    3, 3) / (groups, slots, 3) to the constrained optimum.

    The start is first rescaled (centres and translations together, which
    changes no pixel of point markers) to fit the constraints as well as
    one factor can.  Raises InputError when the start puts a marker behind
    the camera that sees it (the caller screens its start for that).
    """
    p = problem
    if not p.constraints:
        raise InputError("marker calibration needs at least one distance to hold the scale")
    M = np.array(markers0, dtype=float)
    B = M.shape[0]
    Rb = np.broadcast_to(np.eye(3), (B, 3, 3)).copy() if rotations0 is None else np.array(rotations0, dtype=float)
    R = np.ascontiguousarray(R0, dtype=float).copy()
    t = np.ascontiguousarray(t0, dtype=float).copy()
    d = np.array([np.linalg.norm(M[i] - M[j]) / D for i, j, D in p.constraints])
    s = float(d.sum() / (d @ d))
    M *= s
    t *= s
    sys = _System(p)
    n_par = sys.bodies.n
    n = len(p.group)
    res_try = np.zeros((n, 2))
    wts_try = np.ones(n)
    Rn, tn = np.empty_like(R), np.empty_like(t)
    cost = sys.linearize(p, M, R, t, pixel_sigma, huber, Rb)
    if not np.isfinite(cost):
        raise InputError("marker calibration: the initial poses put a marker behind the camera that sees it")
    lam = _LAMBDA0
    converged = False
    it = 0
    for it in range(1, max_iter + 1):
        c, C = constraint_jacobian(M, p.constraints, n_par)
        viol = float(np.abs(c).max())
        accepted = False
        small = False
        for _ in range(_MAX_TRIES):
            Smm, b, sol = sys.reduce(lam)
            nc = len(c)
            m3 = Smm.shape[0]
            KKT = np.zeros((m3 + nc, m3 + nc))
            KKT[:m3, :m3] = Smm
            KKT[:m3, m3:] = C.T
            KKT[m3:, :m3] = C
            try:
                x = np.linalg.solve(KKT, np.concatenate([b, -c]))
            except np.linalg.LinAlgError:
                lam *= 10.0
                continue
            dm = x[:m3]
            dg = -sol[:, :, -1] - np.einsum("gpi,i->gp", sol[:, :, :-1], dm)
            step = float(np.sqrt(dm @ dm + np.sum(dg * dg)))
            Mn, Rbn = sys.bodies.step(M, Rb, dm)
            _apply_step(R, t, np.zeros((0, 3)), p.slot_used, dg, dm[:0], Rn, tn, np.zeros((0, 3)))
            cn = sys.cost(p, Mn, Rn, tn, pixel_sigma, huber, res_try, wts_try, Rbn)
            vn = float(np.abs(constraint_jacobian(Mn, p.constraints)[0]).max())
            # A step that restores the constraints may cost a little; accept it
            # while it clearly reduces their violation.
            if np.isfinite(cn) and (cn <= cost or (viol > 1e-9 and vn < 0.5 * viol)):
                dc = cost - cn
                R, Rn = Rn, R
                t, tn = tn, t
                M, Rb = Mn, Rbn
                cost = cn
                lam = max(lam * 0.1, 1e-12)
                accepted = True
                small = (step < _STEP_TOL * (1.0 + np.abs(M).max()) or 0.0 <= dc <= _REL_COST_TOL * max(cost, 1e-30)) \
                    and vn < 1e-12
                break
            lam *= 10.0
            if step < _STEP_TOL:
                small = True
                break
        if not accepted or small:
            converged = small or not accepted
            break
        sys.linearize(p, M, R, t, pixel_sigma, huber, Rb)
    cost = sys.linearize(p, M, R, t, pixel_sigma, huber, Rb)
    S0, _, _ = sys.reduce(0.0)
    res = sys.res.copy()
    return Adjustment(markers=M, R=R, t=t, information=S0, residuals=res, weights=sys.wts.copy(), cost=float(cost),
                      chi2=float(np.sum(res * res)) / pixel_sigma**2, iterations=it, converged=converged,
                      prior_weight=p.prior_weight if p.prior is not None else 0.0, rotations=Rb,
                      points=sys.bodies.points(M, Rb), prior_information=sys.W)
