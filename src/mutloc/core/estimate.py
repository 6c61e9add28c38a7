"""From observations to the optimal pose: candidates from every minimal
subset, ranking by the two-way reprojection objective, Levenberg-Marquardt
refinement and the covariance.

An observation ``k`` says: the camera of robot ``side[k]`` (0 = p, 1 = q)
sees, along the unit ray ``bearings[k]`` of its own frame, the marker whose
position in the *other* robot's frame is ``points[k]``.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache
from itertools import combinations
from typing import Callable

import numpy as np
from numba import njit

from ..errors import DegenerateGeometryError, InputError, NoSolutionError, ObservationError, TooFewObservationsError
from .pose import Pose
from .camera import readonly, undistort_kernel
from .generalized import GP3P_WORK_SIZE, generalized_p3p_kernel
from .minimal import solve_minimal_kernel
from .refine import MODE_BEARING, MODE_PIXEL, MODE_RAY, WS_SIZE, cost_into, information, lm_refine, tangent_bases

__all__ = ["PairProblem", "Solution", "estimate", "minimal_subsets"]

#: Candidate slots per minimal subset (the solver reports at most this many).
PER_SUBSET = 16
# Subsets beyond this many are sampled (deterministically): with many
# markers, a few dozen minimal problems already contain a good start.
MAX_SUBSETS = 60
# Condition number of the (Jacobi-scaled) J^T J beyond which the pose is not
# isolated: rounding level, so near-degenerate but valid poses still pass.
_MAX_COND = 1e14


# The camera arrays of a problem without pixels (read-only, see _camera_arrays).
_EYE = readonly(np.eye(3))
_NO_DIST = readonly(np.zeros(8))


def _camera_arrays(K, dist):
    """``K`` and ``dist`` (pairs of arrays, or None) as read-only C-contiguous float arrays.

    Numba compiles each kernel once per argument type, and an array's type
    includes whether it is writable: the pair kernels always get read-only
    ``K``/``dist`` (as :class:`~mutloc.core.camera.Camera` keeps them, and as the
    team solver's rows of its read-only ones are) and a writable ``wt``, so that
    each is compiled once, not once per mix."""
    if K is not None:
        K = tuple(readonly(np.ascontiguousarray(k, dtype=float)) for k in K)
    if dist is not None:
        dist = tuple(readonly(np.ascontiguousarray(d, dtype=float)) for d in dist)
    return K, dist


@dataclass
class PairProblem:
    """The observations between robots p and q in solver form: what
    :meth:`mutloc.ObservationSet.pair` gives, with the markers' positions and
    the rays looked up.

    ``pixels``/``K``/``dist`` are only needed for the pixel objective.
    ``frames`` (n, 4, 3), for robots with several cameras or any lens
    (:mod:`mutloc.core.rays`): each row's two tangent directions weighted by
    its lens's Jacobian, its ray direction (= ``bearings``) and its origin,
    in the observing robot's frame; the objective is then the pixel error to
    first order around rays that leave their own camera centres.
    ``sigma_scale`` (n,) is each observation's detection noise relative to
    the stated ``pixel_sigma`` (None: 1 for all): the objective weighs each
    observation by its inverse, so the information matrix (and the
    covariance ``pixel_sigma**2`` times its inverse) follows each one's own
    noise.
    """

    side: np.ndarray
    points: np.ndarray
    bearings: np.ndarray | None
    pixels: np.ndarray | None = None
    K: tuple[np.ndarray, np.ndarray] | None = None
    dist: tuple[np.ndarray, np.ndarray] | None = None
    labels: list[str] | None = None  # where each row came from, for messages
    sigma_scale: np.ndarray | None = None
    frames: np.ndarray | None = None

    def __post_init__(self) -> None:
        self.side = np.ascontiguousarray(self.side, dtype=np.int64)
        self.points = np.ascontiguousarray(self.points, dtype=float).reshape(-1, 3)
        self.bearings = np.ascontiguousarray(self.bearings, dtype=float).reshape(-1, 3)
        n = self.side.shape[0]
        if self.points.shape[0] != n or self.bearings.shape[0] != n:
            raise InputError("observations: side, points and bearings differ in length")
        if not (np.all(np.isfinite(self.points)) and np.all(np.isfinite(self.bearings))):
            raise InputError("observations contain NaN or inf")
        # Scale each ray by its largest component first so huge but finite
        # values cannot overflow the norm.
        big = np.max(np.abs(self.bearings), axis=1)
        if np.any(big == 0.0):
            raise InputError("observations contain a zero-length bearing")
        b = self.bearings / big[:, None]
        self.bearings = b / np.linalg.norm(b, axis=1)[:, None]
        self.K, self.dist = _camera_arrays(self.K, self.dist)
        scale = np.max(np.abs(self.points)) if n else 0.0
        if scale > 1e9:
            raise InputError(f"marker positions of magnitude {scale:.3g} m are not plausible")
        if n < 3:
            raise TooFewObservationsError(f"{n} marker observations; at least three are needed")
        if self.pixels is not None:
            self.pixels = np.ascontiguousarray(self.pixels, dtype=float).reshape(-1, 2)
        if self.sigma_scale is not None:
            self.sigma_scale = np.ascontiguousarray(self.sigma_scale, dtype=float).reshape(-1)
            if self.sigma_scale.shape[0] != n:
                raise InputError("observations: side and sigma_scale differ in length")
            if not np.all(np.isfinite(self.sigma_scale) & (self.sigma_scale > 0.0)):
                raise InputError("observations: every sigma_scale must be finite and positive")

    @classmethod
    def trusted(cls, side, points, bearings, pixels=None, K=None, dist=None, labels=None,
                sigma_scale=None, frames=None) -> "PairProblem":
        """Build without validation, for callers that already validated
        (contiguous float arrays, unit bearings, at least three rows, positive
        scales).  ``bearings`` may be None with pixels: the solver computes them."""
        obj = cls.__new__(cls)
        obj.side, obj.points, obj.bearings = side, points, bearings
        obj.pixels, obj.labels = pixels, labels
        obj.K, obj.dist = _camera_arrays(K, dist)
        obj.sigma_scale = sigma_scale
        obj.frames = frames
        return obj

    @property
    def wt(self) -> np.ndarray:
        """Each row's weight in the objective: ``1 / sigma_scale`` (a new, writable array: the kernels
        are compiled for a writable ``wt``, as the team solver passes them one, see :func:`_camera_arrays`)."""
        if self.sigma_scale is None:
            return np.ones(len(self.side))
        return 1.0 / self.sigma_scale

    def ensure_bearings(self) -> np.ndarray:
        """The unit rays, computed from the pixels if not yet known
        (ObservationError naming the pixel that cannot be undistorted)."""
        if self.bearings is None:
            n = len(self.side)
            b = np.empty((n, 3))
            for i in range(n):
                s = int(self.side[i])
                if not undistort_kernel(self.K[s], self.dist[s], self.pixels[i], b[i]):
                    u, v = self.pixels[i]
                    label = self.labels[i] if self.labels is not None else f"observation {i}"
                    raise ObservationError(f"{label}: pixel ({u:.2f}, {v:.2f}) cannot be undistorted with this "
                                           "camera's calibration")
            self.bearings = b
        return self.bearings

    @property
    def mode(self) -> int:
        if self.frames is not None:
            return MODE_RAY
        return MODE_PIXEL if self.pixels is not None else MODE_BEARING

    @property
    def origins(self) -> np.ndarray:
        """(n, 3) where each row's ray starts in its observer's frame (zeros: every ray from its robot's origin)."""
        if self.frames is None:
            return np.zeros((len(self.side), 3))
        return np.ascontiguousarray(self.frames[:, 3])

    def kernel_args(self) -> tuple:
        """Arguments shared by the residual kernels."""
        if self.frames is not None:
            basis = self.frames
        else:
            basis = np.empty((len(self.side), 3, 3))
            tangent_bases(self.bearings, basis)
        if self.pixels is not None and self.frames is None:
            meas = self.pixels
            Kp, Kq = self.K
            dp, dq = self.dist
        else:
            meas = np.zeros((len(self.side), 2))
            Kp = Kq = _EYE
            dp = dq = _NO_DIST
        return (self.side, self.points, meas, basis, Kp, dp, Kq, dq, self.mode, self.wt)


class Solution:
    """What :func:`estimate` found: the best pose and everything behind it.

    ``candidates`` (every distinct pose of every minimal subset, ranked by
    the objective before refinement) and ``candidate_costs``: when the first
    minimal subset already gave a verified optimum (``estimate(accept=...)``)
    the other subsets were not solved (``extra["first_subset"]`` is True),
    and both are computed on first access.
    """

    __slots__ = ("pose", "cost", "information", "information_inv", "n_obs", "refined", "extra", "_candidates")

    def __init__(self, pose: Pose, cost: float, information: np.ndarray, information_inv: np.ndarray,
                 candidates: Pose | None, candidate_costs: np.ndarray | None, n_obs: int, refined: bool = True,
                 extra: dict | None = None, ranked: "Callable[[], tuple[Pose, np.ndarray]] | None" = None):
        self.pose, self.cost, self.n_obs, self.refined = pose, cost, n_obs, refined
        self.information, self.information_inv = information, information_inv
        self.extra = {} if extra is None else extra
        self._candidates = ranked if candidates is None else (candidates, candidate_costs)

    def _ranking(self) -> tuple[Pose, np.ndarray]:
        if callable(self._candidates):
            self._candidates = self._candidates()
        return self._candidates

    @property
    def candidates_known(self) -> bool:
        """Whether :attr:`candidates` are solved already (reading them then costs nothing)."""
        return not callable(self._candidates)

    @property
    def candidates(self) -> Pose:
        """Every distinct candidate pose, best first (a stack)."""
        return self._ranking()[0]

    @property
    def candidate_costs(self) -> np.ndarray:
        """The objective at each of :attr:`candidates` (before refinement)."""
        return self._ranking()[1]

    def covariance(self, sigma: float) -> np.ndarray:
        """6x6 covariance of (left rotation vector, translation)."""
        return sigma**2 * self.information_inv


def minimal_subsets(side: np.ndarray, max_subsets: int = MAX_SUBSETS) -> np.ndarray:
    """All 3-subsets of the observations (sampled when there are too many)."""
    return _subsets(tuple(side.tolist()), max_subsets)


@lru_cache(maxsize=256)
def _subsets(side_t: tuple[int, ...], max_subsets: int) -> np.ndarray:
    side = np.array(side_t)
    n = len(side)
    combos = np.array(list(combinations(range(n), 3)), dtype=np.int64)
    if len(combos) > max_subsets:
        rng = np.random.default_rng(0)
        # Prefer mixed subsets (both cameras observing): better conditioned.
        mixed = np.array([len(set(side[c])) > 1 for c in combos])
        order = np.concatenate([rng.permutation(np.flatnonzero(mixed)), rng.permutation(np.flatnonzero(~mixed))])
        combos = combos[np.sort(order[:max_subsets])]
    return np.ascontiguousarray(combos)


@njit(cache=True)
def _one_centre_per_side(sd, O):
    """Whether the subset's rays of each robot leave one centre (then the
    problem is the central mutual one in frames moved to those centres)."""
    for j in range(3):
        for l in range(j + 1, 3):
            if sd[j] == sd[l] and (O[j, 0] != O[l, 0] or O[j, 1] != O[l, 1] or O[j, 2] != O[l, 2]):
                return False
    return True


@njit(cache=True)
def minimal_candidates_kernel(side, points, bearings, origins, subsets, root_filter, Rc, tc):
    """Solve every minimal subset; candidates into Rc/tc, returns the count.

    ``origins`` (n, 3): where each row's ray starts in its observer's frame
    (zeros for robots whose frame is their one camera's).  A subset whose
    rays of each robot leave one centre is the central problem in frames
    moved to those centres; one whose rays leave several centres of a robot
    is the generalized (non-central) P3P.

    With ``root_filter`` the paper's Section III-D filter is applied: the
    range to an observed marker is at least the distance of the observer's
    own markers (in the subset) from its camera.
    """
    sd = np.empty(3, dtype=np.int64)
    b = np.empty((3, 3))
    X = np.empty((3, 3))
    O = np.empty((3, 3))
    Rs = np.empty((PER_SUBSET, 3, 3))
    ts = np.empty((PER_SUBSET, 3))
    rg = np.empty((PER_SUBSET, 3))
    gws = np.empty(GP3P_WORK_SIZE)
    c0 = np.zeros(3)  # the centre of p's rays in the subset
    c1 = np.zeros(3)  # of q's
    nc = 0
    for si in range(subsets.shape[0]):
        for j in range(3):
            k = subsets[si, j]
            sd[j] = side[k]
            b[j] = bearings[k]
            X[j] = points[k]
            O[j] = origins[k]
        if not _one_centre_per_side(sd, O):
            ns = generalized_p3p_kernel(sd, O, b, X, Rs, ts, gws)  # kinds: 0 = p's ray (U = p, W = q)
            root_ok = False  # ranges from several centres: the filter does not apply
        else:
            c0[:] = 0.0
            c1[:] = 0.0
            for j in range(3):
                if sd[j] == 0:
                    c0[:] = O[j]
                else:
                    c1[:] = O[j]
            # Markers seen by p are q's: in the frame moved to q's centre, and vice versa.
            for j in range(3):
                for a in range(3):
                    X[j, a] -= c1[a] if sd[j] == 0 else c0[a]
            ns = solve_minimal_kernel(sd, b, X, Rs, ts, rg)
            # x_q - c1 = R (x_p - c0) + t'  =>  t = t' - R c0 + c1
            for i in range(ns):
                for a in range(3):
                    ts[i, a] += c1[a] - (Rs[i, a, 0] * c0[0] + Rs[i, a, 1] * c0[1] + Rs[i, a, 2] * c0[2])
            root_ok = root_filter
        for i in range(ns):
            if root_ok:
                ok = True
                for j in range(3):
                    for l in range(3):
                        # marker of the observer of j, seen by the other camera
                        if sd[l] != sd[j]:
                            nx = np.sqrt(X[l, 0] ** 2 + X[l, 1] ** 2 + X[l, 2] ** 2)
                            if rg[i, j] < nx:
                                ok = False
                if not ok:
                    continue
            if nc < Rc.shape[0]:
                Rc[nc] = Rs[i]
                tc[nc] = ts[i]
                nc += 1
    return nc


@njit(cache=True)
def _same_basin(Ra, ta, Rb, tb):
    """Starts this close (3 degrees, 5% of the range) to an optimum already
    found converge to it; refining them again is wasted time."""
    tr = 0.0
    dt = 0.0
    nt = 0.0
    for a in range(3):
        dt += (ta[a] - tb[a]) ** 2
        nt += tb[a] ** 2
        for b in range(3):
            tr += Ra[a, b] * Rb[a, b]
    return tr > 1.0 + 2.0 * np.cos(np.radians(3.0)) and dt < 0.0025 * nt


@njit(cache=True)
def rank_refine_kernel(side, pts, meas, basis, Kp, dp, Kq, dq, mode, wt, Rc, tc, nc, n_refine, max_iter,
                       prefer_facing, order, costs, Rbest, tbest):
    """Rank candidates (dedup, best first, into ``order``), refine the top
    ``n_refine`` distinct ones, keep the best in Rbest/tbest.

    Returns (number of distinct candidates, best refined cost).
    """
    key = np.empty(nc)
    r = np.empty(2 * side.shape[0])
    J = np.empty((1, 6))
    ws = np.empty(WS_SIZE)
    for i in range(nc):
        c = cost_into(side, pts, meas, basis, Kp, dp, Kq, dq, mode, wt, Rc[i], tc[i], r, J, ws)
        costs[i] = c
        k = c
        if prefer_facing:
            # Minimal problems: every root fits exactly; prefer the cameras
            # facing each other (each optical centre in front of the other).
            tz = tc[i, 2]
            pz = -(Rc[i, 0, 2] * tc[i, 0] + Rc[i, 1, 2] * tc[i, 1] + Rc[i, 2, 2] * tc[i, 2])
            if not (tz > 0.0 and pz > 0.0):
                k = c + 1e300
        key[i] = k
    idx = np.argsort(key)
    nd = 0
    for ii in range(nc):
        i = idx[ii]
        if not np.isfinite(costs[i]):
            continue
        dup = False
        for jj in range(nd):
            j = order[jj]
            dt = 0.0
            nt = 0.0
            dr = 0.0
            for a in range(3):
                dt += (tc[i, a] - tc[j, a]) ** 2
                nt += tc[j, a] ** 2
                for b in range(3):
                    dr += (Rc[i, a, b] - Rc[j, a, b]) ** 2
            if dt <= 1e-16 * (1.0 + nt) and dr <= 1e-16:
                dup = True
                break
        if not dup:
            order[nd] = i
            nd += 1
    best = np.inf
    R = np.empty((3, 3))
    t = np.empty(3)
    H = np.empty((6, 6))
    for jj in range(min(n_refine, nd)):
        i = order[jj]
        # A runner-up whose start is far worse than the optimum found so far
        # lies in another basin only if the problem is badly conditioned;
        # refining it then is cheap insurance, otherwise wasted time.
        if jj > 0 and costs[i] > 25.0 * best + 1e-12:
            break
        if jj > 0 and _same_basin(Rc[i], tc[i], Rbest, tbest):
            continue
        R[:, :] = Rc[i]
        t[:] = tc[i]
        if max_iter > 0:
            c, _ = lm_refine(side, pts, meas, basis, Kp, dp, Kq, dq, mode, wt, R, t, max_iter, H)
        else:
            c = costs[i]
        if c < best:
            best = c
            Rbest[:, :] = R
            tbest[:] = t
    return nd, best


@njit(cache=True)
def _inverse_checked(H, max_cond, out):
    """Inverse of the symmetric information matrix; False if, Jacobi-scaled,
    its smallest eigenvalue is below about 1 / ``max_cond`` of the largest
    (the pose is not isolated)."""
    # Jacobi scaling first: rotation (rad) and translation (m) columns have
    # different units, and only the scaled matrix's conditioning says whether
    # the pose is determined at all.
    d = np.empty(6)
    for i in range(6):
        if not H[i, i] > 0.0:
            return False
        d[i] = 1.0 / np.sqrt(H[i, i])
    # Cholesky of the scaled matrix (unit diagonal, so its largest eigenvalue
    # is at most 6): a pivot below 6 / max_cond means an eigenvalue that small,
    # i.e. the pose is not isolated.  Faster than an eigendecomposition, and
    # the factor gives the inverse.
    L = np.zeros((6, 6))
    tol = 6.0 / max_cond
    for i in range(6):
        for j in range(i + 1):
            s = H[i, j] * d[i] * d[j]
            for k in range(j):
                s -= L[i, k] * L[j, k]
            if i == j:
                if not s > tol:
                    return False
                L[i, i] = np.sqrt(s)
            else:
                L[i, j] = s / L[j, j]
    Li = np.zeros((6, 6))  # L^-1, lower triangular
    for i in range(6):
        Li[i, i] = 1.0 / L[i, i]
        for j in range(i):
            s = 0.0
            for k in range(j, i):
                s -= L[i, k] * Li[k, j]
            Li[i, j] = s / L[i, i]
    for i in range(6):
        for j in range(i, 6):
            s = 0.0
            for k in range(j, 6):
                s += Li[k, i] * Li[k, j]
            out[i, j] = s * d[i] * d[j]
            out[j, i] = out[i, j]
    return True


# Status codes of solve_kernel (and first_subset_kernel, which adds _FALL_BACK).
_OK, _UNDISTORT, _NO_CANDIDATE, _BEHIND, _DEGENERATE, _FALL_BACK = 0, 1, 2, 3, 4, 5


@njit(cache=True)
def bearings_kernel(side, meas, Kp, dp, Kq, dq, bearings):
    """Unit rays of the pixels ``meas`` into ``bearings``; the index of the
    first pixel that cannot be undistorted, or -1."""
    for i in range(side.shape[0]):
        if side[i] == 0:
            ok = undistort_kernel(Kp, dp, meas[i], bearings[i])
        else:
            ok = undistort_kernel(Kq, dq, meas[i], bearings[i])
        if not ok:
            return i
    return -1


@njit(cache=True)
def first_subset(side, bearings, sub):
    """The minimal subset tried first, into ``sub`` (3 indices): the two rays
    of one camera furthest apart (the widest baseline a pair of markers
    offers) and one ray of the other camera; False when one camera saw
    everything (a plain PnP problem: four nearly coplanar markers have two
    poses that fit, and one subset's roots need not reach both)."""
    n = side.shape[0]
    best = 2.0
    a = -1
    b = -1
    for i in range(n):
        for j in range(i + 1, n):
            if side[i] == side[j]:
                d = (bearings[i, 0] * bearings[j, 0] + bearings[i, 1] * bearings[j, 1]
                     + bearings[i, 2] * bearings[j, 2])
                if d < best:
                    best, a, b = d, i, j
    sub[0] = a
    sub[1] = b
    for k in range(n):
        if side[k] != side[a]:
            sub[2] = k
            return True
    return False


@njit(cache=True)
def first_subset_kernel(side, points, meas, frames, Kp, dp, Kq, dq, mode, wt, accept, max_iter, R, t, H, Hinv,
                        Rc, tc, costs):
    """The estimate from one well-chosen minimal subset (pixel objective, at
    least four observations): its roots ranked on every observation, the
    best refined.  Accepted (status 0, the cost) only when the refined cost
    is at most ``accept`` and no other root starts close enough to it to
    lie in another basin; anything else returns :data:`_FALL_BACK` and the
    caller solves every subset (:func:`solve_kernel`), which also reports
    the failures.  ``mode`` is :data:`MODE_PIXEL` or :data:`MODE_RAY` (rays
    and their frames given in ``frames``).  The subset's roots and their
    costs on every observation are left in ``Rc``/``tc``/``costs``
    (:data:`PER_SUBSET` slots; the third value returned is their count)."""
    n = side.shape[0]
    if mode == MODE_RAY:
        bearings = np.ascontiguousarray(frames[:, 2, :])
        origins = np.ascontiguousarray(frames[:, 3, :])
    else:
        bearings = np.empty((n, 3))
        if bearings_kernel(side, meas, Kp, dp, Kq, dq, bearings) >= 0:
            return _FALL_BACK, np.inf, 0
        origins = np.zeros((n, 3))
    sub = np.empty((1, 3), dtype=np.int64)
    if not first_subset(side, bearings, sub[0]):
        return _FALL_BACK, np.inf, 0
    nc = minimal_candidates_kernel(side, points, bearings, origins, sub, np.bool_(False), Rc, tc)  # not a literal: one compile
    if mode == MODE_RAY:
        basis = frames
    else:
        basis = np.empty((n, 3, 3))
        tangent_bases(bearings, basis)
    r = np.empty(2 * n)
    J = np.empty((1, 6))
    ws = np.empty(WS_SIZE)
    i0 = -1
    for i in range(nc):
        costs[i] = cost_into(side, points, meas, basis, Kp, dp, Kq, dq, mode, wt, Rc[i], tc[i], r, J, ws)
        if np.isfinite(costs[i]) and (i0 < 0 or costs[i] < costs[i0]):
            i0 = i
    if nc == 1 and i0 < 0:  # a lone root: the refinement judges it
        i0 = 0
    if nc == 0 or i0 < 0:
        return _FALL_BACK, np.inf, 0
    R[:, :] = Rc[i0]
    t[:] = tc[i0]
    # H: J^T J at the refined pose, as information() would compute it.
    c, _ = lm_refine(side, points, meas, basis, Kp, dp, Kq, dq, mode, wt, R, t, max_iter, H)
    if not c <= accept:
        return _FALL_BACK, c, nc
    # Another root that starts within the margin solve_kernel refines
    # runner-ups by, and not in the basin just found: the answer may be
    # ambiguous, and only the full search can say.
    for i in range(nc):
        if i != i0 and costs[i] <= 25.0 * c + 1e-12 and not _same_basin(Rc[i], tc[i], R, t):
            return _FALL_BACK, c, nc
    if not _inverse_checked(H, _MAX_COND, Hinv):
        return _FALL_BACK, c, nc
    return _OK, c, nc


@njit(cache=True)
def solve_kernel(side, points, meas, bearings, frames, Kp, dp, Kq, dq, mode, wt, subsets, root_filter, n_extra,
                 n_refine, max_iter, Rc, tc, order, costs, Rbest, tbest, H, Hinv):
    """The whole estimate in one compiled call: rays from pixels (pixel
    mode), candidates of every minimal subset (after the ``n_extra`` given
    ones at the front of Rc/tc), ranking, refinement, information matrix and
    its checked inverse.

    Returns (status, index, candidates, distinct candidates, best cost);
    status 1 means the pixel ``index`` cannot be undistorted.  ``frames``
    (n, 4, 3) are the rows' ray frames in :data:`MODE_RAY` (else unused).
    """
    n = side.shape[0]
    if mode == MODE_PIXEL:
        i = bearings_kernel(side, meas, Kp, dp, Kq, dq, bearings)
        if i >= 0:
            return _UNDISTORT, i, 0, 0, np.inf
    if mode == MODE_RAY:
        basis = frames
        origins = np.ascontiguousarray(frames[:, 3, :])
    else:
        basis = np.empty((n, 3, 3))
        tangent_bases(bearings, basis)
        origins = np.zeros((n, 3))
    nc = n_extra
    if subsets.shape[0] > 0:
        nc += minimal_candidates_kernel(side, points, bearings, origins, subsets, root_filter, Rc[n_extra:],
                                        tc[n_extra:])
    # Three rays of robots whose frames are their cameras': prefer the cameras facing each other.
    nd, best = rank_refine_kernel(side, points, meas, basis, Kp, dp, Kq, dq, mode, wt, Rc, tc, nc, n_refine, max_iter,
                                  n == 3 and mode != MODE_RAY, order, costs, Rbest, tbest)
    if nd == 0 or not np.isfinite(best):
        return _NO_CANDIDATE, -1, nc, nd, best
    if not information(side, points, meas, basis, Kp, dp, Kq, dq, mode, wt, Rbest, tbest, H):
        return _BEHIND, -1, nc, nd, best
    if not _inverse_checked(H, _MAX_COND, Hinv):
        return _DEGENERATE, -1, nc, nd, best
    return _OK, -1, nc, nd, best


_NO_SUBSETS = np.empty((0, 3), dtype=np.int64)
#: ``frames`` of a problem that is not in ray mode.
NO_FRAMES = np.empty((0, 4, 3))


def estimate(obs: PairProblem, *, refine: bool = True, n_refine: int = 4, max_iter: int = 50,
             root_filter: bool = False, extra_candidates: tuple[np.ndarray, np.ndarray] | None = None,
             use_minimal: bool = True, accept: float | None = None) -> Solution:
    """The best pose T_qp for ``obs`` with all distinct candidates.

    With ``accept`` (a cost in pixels squared, e.g. the consistency test's
    threshold times sigma squared) and four or more pixel observations, one
    well-chosen minimal subset is solved first; when its best root refines
    to a cost at most ``accept`` and none of its other roots could lie in
    another basin, that optimum is returned and the other subsets are solved
    only if ``candidates`` is read.  Otherwise (or without ``accept``) every
    subset is solved.

    Raises ObservationError when a pixel cannot be undistorted,
    NoSolutionError when no candidate keeps every marker in front of the
    camera that saw it, DegenerateGeometryError when the best pose is not
    isolated (singular information matrix).
    """
    n = len(obs.side)
    if (accept is not None and refine and use_minimal and extra_candidates is None and not root_filter
            and n > 3 and (obs.pixels is not None or obs.frames is not None)):
        R = np.empty((3, 3))
        t = np.empty(3)
        H = np.empty((6, 6))
        Hinv = np.empty((6, 6))
        Rs = np.empty((PER_SUBSET, 3, 3))
        ts = np.empty((PER_SUBSET, 3))
        cs = np.empty(PER_SUBSET)
        if obs.frames is not None:
            status, c, ns = first_subset_kernel(obs.side, obs.points, np.zeros((n, 2)), obs.frames, _EYE, _NO_DIST,
                                                _EYE, _NO_DIST, MODE_RAY, obs.wt, accept, max_iter, R, t, H, Hinv,
                                                Rs, ts, cs)
        else:
            (Kp, Kq), (dp, dq) = obs.K, obs.dist
            status, c, ns = first_subset_kernel(obs.side, obs.points, obs.pixels, NO_FRAMES, Kp, dp, Kq, dq,
                                                MODE_PIXEL, obs.wt, accept, max_iter, R, t, H, Hinv, Rs, ts, cs)
        if status == _OK:
            return Solution(Pose.trusted(R, t), c, H, Hinv, None, None, n, True,
                            {"first_subset": True, "subset_roots": (Rs[:ns], ts[:ns], cs[:ns])},
                            ranked=lambda: ranked_candidates(obs))
    subsets = minimal_subsets(obs.side) if use_minimal else _NO_SUBSETS
    n_extra = 0
    size = len(subsets) * PER_SUBSET
    if extra_candidates is not None:
        Re = np.asarray(extra_candidates[0], dtype=float).reshape(-1, 3, 3)
        te = np.asarray(extra_candidates[1], dtype=float).reshape(-1, 3)
        n_extra = len(Re)
        size += n_extra
    Rc = np.empty((max(size, 1), 3, 3))
    tc = np.empty((max(size, 1), 3))
    if n_extra:
        Rc[:n_extra] = Re
        tc[:n_extra] = te
    order = np.empty(max(size, 1), dtype=np.int64)
    costs = np.empty(max(size, 1))
    Rbest = np.empty((3, 3))
    tbest = np.empty(3)
    H = np.empty((6, 6))
    Hinv = np.empty((6, 6))
    frames = NO_FRAMES
    if obs.frames is not None:
        Kp = Kq = _EYE
        dp = dq = _NO_DIST
        meas, mode, bearings, frames = np.zeros((n, 2)), MODE_RAY, obs.bearings, obs.frames
    elif obs.pixels is not None:
        (Kp, Kq), (dp, dq) = obs.K, obs.dist
        meas, mode = obs.pixels, MODE_PIXEL
        bearings = obs.bearings if obs.bearings is not None else np.empty((n, 3))
    else:
        Kp = Kq = _EYE
        dp = dq = _NO_DIST
        meas, mode, bearings = np.zeros((n, 2)), MODE_BEARING, obs.bearings
    status, index, nc, nd, best = solve_kernel(
        obs.side, obs.points, meas, bearings, frames, Kp, dp, Kq, dq, mode, obs.wt, subsets, root_filter, n_extra,
        n_refine if refine else 1, max_iter if refine else 0, Rc, tc, order, costs, Rbest, tbest, H, Hinv)
    if status == _UNDISTORT:
        u, v = meas[index]
        label = obs.labels[index] if obs.labels is not None else f"observation {index}"
        raise ObservationError(f"{label}: pixel ({u:.2f}, {v:.2f}) cannot be undistorted with this camera's "
                               "calibration")
    if status == _NO_CANDIDATE:
        raise NoSolutionError(
            "no pose explains the observations: every solution puts a marker behind a camera"
        )
    if status == _BEHIND:
        raise NoSolutionError("the refined pose puts a marker behind a camera")
    if status == _DEGENERATE:
        raise DegenerateGeometryError(
            "the observations do not determine an isolated pose (degenerate marker geometry)"
        )
    obs.bearings = bearings
    sel = order[:nd]
    return Solution(
        pose=Pose(Rbest, tbest),
        cost=float(best),
        information=H,
        information_inv=Hinv,
        candidates=Pose(Rc[sel], tc[sel]),
        candidate_costs=costs[sel],
        n_obs=n,
        refined=refine,
    )


def ranked_candidates(obs: PairProblem) -> tuple[Pose, np.ndarray]:
    """Every subset's distinct candidates, ranked as :func:`estimate` without
    ``accept`` ranks them (four or more observations: no preference for
    facing cameras)."""
    bearings = obs.ensure_bearings()
    subsets = minimal_subsets(obs.side)
    size = max(len(subsets) * PER_SUBSET, 1)
    Rc = np.empty((size, 3, 3))
    tc = np.empty((size, 3))
    nc = minimal_candidates_kernel(obs.side, obs.points, bearings, obs.origins, subsets, False, Rc, tc)
    order = np.empty(size, dtype=np.int64)
    costs = np.empty(size)
    nd, _ = rank_refine_kernel(*obs.kernel_args(), Rc, tc, nc, 0, 0, len(obs.side) == 3, order, costs,
                               np.empty((3, 3)), np.empty(3))
    sel = order[:nd]
    return Pose(Rc[sel], tc[sel]), costs[sel]
