"""The constant-velocity motion model shared by the team filter
(:mod:`mutloc.core.team_filter`), its smoother and the tracker's starts
(SPEC "Filtered tracking").

State per robot: the pose ``T = (R, t)`` and its velocity ``(w, v)`` --
angular velocity (rad/s) and the rate of ``t`` (m/s) -- with a 12x12
covariance over the error state ``(dtheta, dt, dw, dv)``, where
``R_true = expm(skew(dtheta)) @ R`` and ``t_true = t + dt`` exactly as the
SPEC's covariance, so the top-left 6x6 block *is* the pose covariance.

Motion: ``R <- exp(w dt) R``, ``t <- t + v dt``, velocity constant up to
white-noise acceleration (spectral densities ``MotionNoise.angular**2``,
``MotionNoise.linear**2``); :func:`cv_transition` is its error-state
transition.

Also here: the detections' noise measured from a filter's residuals
(:func:`measured_noise`), the one observation whose leaving out makes an
update pass (:func:`single_outlier`), and a pose with its constant velocity
fitted to records taken at several times (:func:`fit_moving_pose`).
Nothing here reads files.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Callable

import numpy as np
from numba import njit

from ..errors import InputError, positive_number
from .consistency import DEFAULT_CONFIDENCE, Consistency, chi2_quantile
from .estimate import PairProblem
from .pose import Pose
from .refine import MODE_PIXEL, WS_SIZE, residuals, so3_exp_left

__all__ = ["MotionNoise", "FilterState", "cv_transition", "measured_noise", "STATE_DIM", "MovingFit",
           "fit_moving_pose", "single_outlier"]

#: Error-state dimension: rotation, translation, angular and linear velocity.
STATE_DIM = 12
#: Measured detection noise: accepted frames pooled, the degrees of freedom
#: needed before it counts, the fraction of ``pixel_sigma`` its upper bound
#: must be under to be used, and the lowest fraction of ``pixel_sigma`` it may give.
NOISE_WINDOW = 30
NOISE_MIN_DOF = 20
NOISE_CLEARLY_BELOW = 0.8
NOISE_FLOOR = 0.01


def measured_noise(chi2: float, dof: int, pixel_sigma: float, use: bool = True) -> tuple[float | None, float]:
    """The detections' pixel noise measured from pooled squared residuals
    ``chi2`` (px^2) over ``dof`` degrees of freedom (None before
    ``NOISE_MIN_DOF``), and the noise a filter's gain weighs them with:
    ``pixel_sigma``, unless ``use`` and the measured noise is clearly
    smaller (its upper two-sigma bound below ``NOISE_CLEARLY_BELOW`` of
    ``pixel_sigma``; then that bound, never below ``NOISE_FLOOR`` of it)."""
    if dof < NOISE_MIN_DOF:
        return None, pixel_sigma
    measured = math.sqrt(max(chi2, 0.0) / dof)
    if not use:
        return measured, pixel_sigma
    upper = measured * math.sqrt(1.0 + 2.0 * math.sqrt(2.0 / dof))
    if upper > NOISE_CLEARLY_BELOW * pixel_sigma:
        return measured, pixel_sigma
    return measured, max(upper, NOISE_FLOOR * pixel_sigma)


@dataclass(frozen=True)
class MotionNoise:
    """The constant-velocity model's noise (all 1-sigma, SI units).

    ``angular`` and ``linear`` are the square roots of the white-noise
    acceleration spectral densities (rad s^-2 Hz^-1/2, m s^-2 Hz^-1/2):
    over ``dt`` seconds the velocity drifts by about ``linear * sqrt(dt)``.
    The defaults suit robots at walking pace (velocity changing by about
    1 m/s and 0.5 rad/s within a second); lower them for smoother motion and
    noisier detections, raise them for agile robots.  ``initial_angular`` (rad/s) and
    ``initial_linear`` (m/s) are the velocity's sigma when the track starts
    or restarts (from rest, as far as the filter knows).

    The poses are relative to the reference, which moves too: its turning
    swings every other robot through its lever arm -- at 3 m, a reference
    turning at 75 deg/s moves a robot's relative position at 4 m/s.
    ``reference_angular`` (off by default) adds that to every prediction and
    to a started track's velocity prior (:mod:`mutloc.core.team_filter`).
    At speed (robots at 1-1.5 m/s turning at 70-80 deg/s) the walking-pace
    defaults are overconfident: ``angular=2, linear=2, reference_angular=2``
    keep coasted poses within their sigma (docs/benchmarks.md,
    "The motion model at speed").
    """

    angular: float = 0.5
    linear: float = 1.0
    initial_angular: float = 1.0
    initial_linear: float = 1.0
    #: The reference robot's own white-noise angular acceleration (rad
    #: s^-2 Hz^-1/2; 0, the default: not modelled, the relative noise above
    #: covers it).  Every pose is in the reference's frame: when the
    #: reference turns, every other robot's relative pose turns the other way
    #: and its position swings through its lever arm -- a robot ``r`` metres
    #: away moves by ``r`` times the reference's unforeseen turn.  The team
    #: filter adds this noise to every robot's prediction with that coupling
    #: (rotation ``-dphi``, translation ``t x dphi``), one noise for all
    #: robots (their predictions move together, correlated), and to a
    #: started track's velocity prior.  Off by default: on the node-outage
    #: benchmark (a static reference, one camera's two markers for seconds)
    #: it doubled the poses beyond 5 sigma (docs/benchmarks.md).
    reference_angular: float = 0.0

    def __post_init__(self) -> None:
        for name in ("angular", "linear", "initial_angular", "initial_linear"):
            positive_number(getattr(self, name), f"MotionNoise.{name}")
        ra = self.reference_angular
        if isinstance(ra, bool) or not (isinstance(ra, (int, float)) and math.isfinite(ra) and ra >= 0.0):
            raise InputError(f"MotionNoise.reference_angular must be a number >= 0, got {ra!r}")

    @property
    def reference_turn(self) -> float:
        """The reference's angular acceleration noise in use (0: not modelled)."""
        return float(self.reference_angular)


@dataclass(frozen=True)
class FilterState:
    """A pose ``T_qp`` at ``time`` with its velocity ``(w, v)`` (6,) and the
    12x12 covariance over ``(dtheta, dt, dw, dv)`` (what
    :func:`fit_moving_pose` fits and a track starts from)."""

    time: float
    pose: Pose
    velocity: np.ndarray
    covariance: np.ndarray

    @property
    def pose_covariance(self) -> np.ndarray:
        """6x6 over (left rotation vector, translation): the SPEC's covariance."""
        return self.covariance[:6, :6]


@njit(cache=True)
def _left_jacobian(phi, out):
    """SO(3) left Jacobian J_l(phi) into out (3, 3)."""
    th2 = phi[0] * phi[0] + phi[1] * phi[1] + phi[2] * phi[2]
    th = np.sqrt(th2)
    if th < 1e-6:
        a = 0.5 - th2 / 24.0
        b = 1.0 / 6.0 - th2 / 120.0
    else:
        a = (1.0 - np.cos(th)) / th2
        b = (th - np.sin(th)) / (th2 * th)
    x, y, z = phi[0], phi[1], phi[2]
    # I + a [phi]x + b [phi]x^2, with [phi]x^2 = phi phi^T - th2 I
    out[0, 0] = 1.0 + b * (x * x - th2)
    out[1, 1] = 1.0 + b * (y * y - th2)
    out[2, 2] = 1.0 + b * (z * z - th2)
    out[0, 1] = -a * z + b * x * y
    out[1, 0] = a * z + b * x * y
    out[0, 2] = a * y + b * x * z
    out[2, 0] = -a * y + b * x * z
    out[1, 2] = -a * x + b * y * z
    out[2, 1] = a * x + b * y * z


@njit(cache=True)
def cv_transition(vel, dt, F):
    """The error-state transition (12x12) of the constant-velocity motion over ``dt``."""
    phi = np.empty(3)
    for k in range(3):
        phi[k] = vel[k] * dt
    F[:, :] = np.eye(STATE_DIM)
    E = np.empty((3, 3))
    so3_exp_left(phi, np.eye(3), E)
    Jl = np.empty((3, 3))
    _left_jacobian(phi, Jl)
    for i in range(3):
        for j in range(3):
            F[i, j] = E[i, j]
            F[i, 6 + j] = Jl[i, j] * dt
        F[3 + i, 9 + i] = dt


def single_outlier(attempt: Callable[[np.ndarray], Any], rows: np.ndarray) -> tuple[int, np.ndarray, Any] | None:
    """The one observation whose leaving out makes an update pass: ``attempt(kept
    rows)`` gives a result whose ``[1]`` is its test (or None); returns
    ``(row left out, kept rows, result)`` when exactly one row does, else None.
    Only with three or more rows: one observation left is no evidence that the
    other was wrong -- two pixels fit almost any broad prediction (measured: a
    single camera's two markers, one dropped a frame, led a track metres away)."""
    if len(rows) < 3:
        return None
    passing = []
    for k in range(len(rows)):
        keep = np.delete(rows, k)
        alt = attempt(keep)
        if alt is not None and alt[1].passed:
            passing.append((rows[k], keep, alt))
    return passing[0] if len(passing) == 1 else None


@dataclass(frozen=True)
class MovingFit:
    """A pose and its velocity fitted to observations taken at several
    times (:func:`fit_moving_pose`): ``state`` at the reference time with
    its 12x12 covariance (under ``sigma``), the least-squares ``test`` with
    ``2n - 12`` degrees of freedom, each row's residual (px) at its own
    time, and ``times`` the span of the records used."""

    state: FilterState
    test: Consistency
    residuals_px: np.ndarray
    iterations: int


def _pixel_args(problem: PairProblem) -> tuple:
    """A pixel problem's arrays as the residual kernel takes them (InputError
    without pixels and cameras)."""
    if problem.pixels is None or problem.K is None or problem.dist is None:
        raise InputError("fit_moving_pose needs pixel observations with their cameras")
    return (np.ascontiguousarray(problem.side, dtype=np.int64), np.ascontiguousarray(problem.points, float),
            np.ascontiguousarray(problem.pixels, float), problem.K[0], problem.dist[0], problem.K[1],
            problem.dist[1], np.ascontiguousarray(problem.wt, float))


def fit_moving_pose(problems: list[PairProblem], times: list[float], time: float, pose: Pose, *,
                    sigma: float = 1.0, confidence: float = DEFAULT_CONFIDENCE, max_iter: int = 15,
                    velocity: np.ndarray | None = None, noise: MotionNoise | None = None) -> MovingFit | None:
    """The pose at ``time`` and its constant velocity (the filter's motion
    model: ``R(t_i) = exp(w (t_i - time)) R``, ``t(t_i) = t + v (t_i - time)``)
    that best explain ``problems[i]``'s pixel observations (or rays, for robots with several cameras:
    ``PairProblem.frames``) taken at
    ``times[i]`` -- observations of several cameras, each at its own capture
    time, bridged by the motion.  Gauss-Newton from ``pose`` (and
    ``velocity``, default at rest) on the pixel residuals of every row at its
    own time, with the filter's error-state transition as the chain rule.

    ``noise``: the motion model's acceleration noise; a record ``dt``
    seconds from ``time`` then also carries the pose's drift from constant
    velocity over ``dt`` (``q dt^3 / 3`` per axis), projected into its
    pixels, so that the fit neither trusts far records as if the motion were
    exactly constant nor fails its test for that (None: exact constant
    velocity).

    Returns None when a marker falls behind its camera or the normal
    equations are singular (the observations do not fix pose and velocity).
    The test has ``2n - 12`` degrees of freedom; with fewer than one it
    cannot be tested (``passed`` None).
    """
    from .geometry import so3_exp

    if len(problems) != len(times):
        raise InputError("fit_moving_pose: one time per problem")
    sigma = positive_number(sigma, "sigma")
    groups = []
    for prob, ti in zip(problems, times):
        if prob.frames is not None:  # rays of robots with several cameras, any lens (pixels to first order)
            side, pts, meas, basis, Kp, dp, Kq, dq, mode, wt = prob.kernel_args()
        else:
            side, pts, meas, Kp, dp, Kq, dq, wt = _pixel_args(prob)
            basis, mode = np.zeros((len(side), 3, 3)), MODE_PIXEL
        groups.append((float(ti) - float(time), side, pts, meas, basis, mode, Kp, dp, Kq, dq, wt))
    n = sum(len(g[1]) for g in groups)
    R = np.array(pose.R, dtype=float)
    t = np.array(pose.t, dtype=float)
    vel = np.zeros(6) if velocity is None else np.array(velocity, dtype=float)
    ws = np.empty(WS_SIZE)
    F = np.empty((STATE_DIM, STATE_DIM))

    def linearize(R, t, vel, want):
        H = np.zeros((STATE_DIM, STATE_DIM))
        g = np.zeros(STATE_DIM)
        res = np.empty(n)
        cost = 0.0
        k = 0
        Ri, ti = np.empty((3, 3)), np.empty(3)
        for dt, side, pts, meas, basis, mode, Kp, dp, Kq, dq, wt in groups:
            m = len(side)
            so3_exp_left(vel[:3] * dt, R, Ri)
            ti[:] = t + vel[3:] * dt
            r = np.empty(2 * m)
            J = np.empty((2 * m, 6))
            if not residuals(side, pts, meas, basis, Kp, dp, Kq, dq, mode, wt, Ri, ti, r, J, want,
                             ws):
                return None
            res[k:k + m] = np.hypot(r[0::2], r[1::2])
            k += m
            if noise is not None:
                if not want:
                    residuals(side, pts, meas, basis, Kp, dp, Kq, dq, mode, wt, Ri, ti, r, J, True,
                              ws)
                d3 = abs(dt) ** 3 / 3.0
                Q = np.diag([noise.angular**2 * d3] * 3 + [noise.linear**2 * d3] * 3)
                W = np.linalg.cholesky(np.eye(2 * m) + (J @ Q @ J.T) / sigma**2)
                r = np.linalg.solve(W, r)
                J = np.linalg.solve(W, J)
            cost += float(r @ r)
            if want:
                cv_transition(vel, dt, F)
                Jx = J @ F[:6, :]
                H += Jx.T @ Jx
                g += Jx.T @ r
        return cost, H, g, res

    lin = linearize(R, t, vel, True)
    if lin is None:
        return None
    iters = 0
    lam = 1e-6
    for iters in range(1, max_iter + 1):
        cost, H, g, _ = lin
        D = np.diag(np.diag(H)) + 1e-12 * np.eye(STATE_DIM)
        try:
            dx = -np.linalg.solve(H + lam * D, g)
        except np.linalg.LinAlgError:
            return None
        Rn = so3_exp(dx[:3]) @ R
        tn, vn = t + dx[3:6], vel + dx[6:]
        trial = linearize(Rn, tn, vn, True)
        if trial is not None and trial[0] <= cost:
            R, t, vel, lin = Rn, tn, vn, trial
            lam = max(lam / 10.0, 1e-9)
            if np.max(np.abs(dx)) < 1e-10 or cost - trial[0] < 1e-12 * max(cost, 1.0):
                break
        else:
            lam *= 10.0
            if lam > 1e6:
                break
    cost, H, _, res = lin
    try:
        P = np.linalg.inv(H) * sigma**2
    except np.linalg.LinAlgError:
        return None
    if not np.all(np.isfinite(P)) or np.min(np.linalg.eigvalsh(0.5 * (P + P.T))) <= 0.0:
        return None
    dof = 2 * n - STATE_DIM
    chi2 = cost / sigma**2
    thr = chi2_quantile(confidence, dof) if dof >= 1 and confidence < 1.0 else math.inf
    test = Consistency(float(chi2), dof, confidence, thr)
    state = FilterState(float(time), Pose(R, t), vel, 0.5 * (P + P.T))
    return MovingFit(state, test, res, iters)

