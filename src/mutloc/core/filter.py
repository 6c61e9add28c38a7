"""Filtered tracking of one relative pose: a constant-velocity model on
SE(3) and an iterated error-state Kalman filter whose update uses each
frame's pixel observations directly (SPEC "Filtered tracking").

State: the pose ``T_qp = (R, t)`` and its velocity ``(w, v)`` -- angular
velocity (rad/s) and the rate of ``t`` (m/s), both in q's frame -- with a
12x12 covariance over the error state ``(dtheta, dt, dw, dv)``, where
``R_true = expm(skew(dtheta)) @ R`` and ``t_true = t + dt`` exactly as the
SPEC's covariance, so the top-left 6x6 block *is* the pose covariance.

Motion: ``R <- exp(w dt) R``, ``t <- t + v dt``, velocity constant up to
white-noise acceleration (spectral densities ``MotionNoise.angular**2``,
``MotionNoise.linear**2``).

Update: Gauss-Newton on the posterior (the iterated EKF) over the two-way
pixel reprojection residuals of :mod:`mutloc.core.refine`, through each
camera's ``K`` and distortion, so one or two markers update the state as well
as ten.  The update is gated: the innovation's Mahalanobis distance (the
posterior cost ``e' P^-1 e + |r|^2 / sigma^2``) against the chi-square
quantile with ``2n`` degrees of freedom at ``confidence``.  A frame that fails
is retried without each single observation (with three or more); when
exactly one such subset passes, that observation is dropped, else the frame is rejected and the
state stays the prediction.  Frames with fewer than three observations are
linearised once, at the prediction (iterating would relinearise along the
directions they cannot fix and make the track overconfident).

Detection noise: ``pixel_sigma`` is the stated noise behind every reported
covariance and the gate.  The filter also measures the noise (each accepted
frame's residual that no pose explains); when it is clearly smaller, the gain
weighs the detections by it, so that detections far better than stated do
not make the track lag, and the reported covariance is carried as that of
the same gains under ``pixel_sigma`` (:attr:`FilterState.gain_covariance`).

Nothing here reads files: the tracker (:mod:`mutloc.track.filtering`) turns
frames into :class:`~mutloc.core.estimate.PairProblem` and rows.  A team
filter is one of these per robot against the reference.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, field
from typing import Any, Callable

import numpy as np
from numba import njit

from ..errors import InputError, confidence_level, positive_number
from .consistency import DEFAULT_CONFIDENCE, Consistency, chi2_quantile
from .estimate import PairProblem
from .pose import Pose
from .refine import MODE_PIXEL, WS_SIZE, cho_solve, cholesky, normal_equations, residuals, so3_exp_left

__all__ = ["MotionNoise", "FilterState", "FilterUpdate", "ConstantVelocityFilter", "cv_predict", "cv_transition",
           "iekf_update", "measured_noise", "rts_gains", "rts_smooth", "STATE_DIM", "MovingFit", "fit_moving_pose",
           "single_outlier"]

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
    """

    angular: float = 0.5
    linear: float = 1.0
    initial_angular: float = 1.0
    initial_linear: float = 1.0

    def __post_init__(self) -> None:
        for name in ("angular", "linear", "initial_angular", "initial_linear"):
            positive_number(getattr(self, name), f"MotionNoise.{name}")


@dataclass(frozen=True)
class FilterState:
    """The filter at ``time``: pose ``T_qp``, velocity ``(w, v)`` (6,) and
    the 12x12 covariance over ``(dtheta, dt, dw, dv)`` under the stated
    detection noise ``pixel_sigma``.  ``gain_covariance`` is the filter's own
    where its gain weighed measured, smaller noise (see
    :attr:`ConstantVelocityFilter.gain_sigma`); None: the same.  The
    estimate's covariance under ``pixel_sigma`` is also at most
    ``noise_scale * gain_covariance`` (the same gains with both noises
    scaled up), which the smoother uses."""

    time: float
    pose: Pose
    velocity: np.ndarray
    covariance: np.ndarray
    gain_covariance: np.ndarray | None = None
    #: ``(pixel_sigma / gain_sigma)^2`` at the last update.
    noise_scale: float = 1.0

    @property
    def pose_covariance(self) -> np.ndarray:
        """6x6 over (left rotation vector, translation): the SPEC's covariance."""
        return self.covariance[:6, :6]

    @property
    def own_covariance(self) -> np.ndarray:
        """The covariance the gain was computed with (12x12)."""
        return self.covariance if self.gain_covariance is None else self.gain_covariance


@dataclass(frozen=True)
class FilterUpdate:
    """What one frame's observations did.

    ``accepted``: the state was updated (``state`` is the posterior); else
    ``state`` is the prediction.  ``test`` is the gate on the observations
    used (or, when rejected, on all of them); ``used`` and ``dropped`` index
    the problem's rows; ``residuals_px`` are each row's reprojection error at
    ``state``; ``reason`` says why a frame was rejected.
    """

    accepted: bool
    state: FilterState
    test: Consistency
    used: np.ndarray
    dropped: np.ndarray
    residuals_px: np.ndarray
    reason: str = ""
    iterations: int = 0
    extra: dict = field(default_factory=dict)

    @property
    def rms_px(self) -> float:
        """Reprojection RMS (pixels) of the observations used."""
        r = self.residuals_px[self.used] if self.accepted else self.residuals_px
        return float(np.sqrt(np.mean(r**2))) if len(r) else 0.0


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


@njit(cache=True)
def cv_predict(R, t, vel, P, dt, q_ang, q_lin, R_out, t_out, P_out):
    """Constant-velocity prediction over ``dt`` seconds (``q_ang``, ``q_lin``:
    acceleration spectral densities); the velocity is unchanged."""
    phi = np.empty(3)
    for k in range(3):
        phi[k] = vel[k] * dt
        t_out[k] = t[k] + vel[3 + k] * dt
    so3_exp_left(phi, R, R_out)
    F = np.empty((STATE_DIM, STATE_DIM))
    cv_transition(vel, dt, F)
    FP = F @ P
    P_out[:, :] = FP @ F.T
    # Integrated white-noise acceleration, per axis: q [[dt^3/3, dt^2/2], [dt^2/2, dt]].
    d3 = dt * dt * dt / 3.0
    d2 = dt * dt / 2.0
    for i in range(6):
        q = q_ang if i < 3 else q_lin
        v = i + 6
        P_out[i, i] += q * d3
        P_out[i, v] += q * d2
        P_out[v, i] += q * d2
        P_out[v, v] += q * dt
    for i in range(STATE_DIM):
        for j in range(i):
            s = 0.5 * (P_out[i, j] + P_out[j, i])
            P_out[i, j] = s
            P_out[j, i] = s


@njit(cache=True)
def _symmetrize(P):
    for i in range(P.shape[0]):
        for j in range(i):
            s = 0.5 * (P[i, j] + P[j, i])
            P[i, j] = s
            P[j, i] = s


@njit(cache=True)
def _mahalanobis2(S, v, L, y):
    """``v' S^-1 v`` (inf if ``S`` is not positive definite); ``L`` gets S's
    Cholesky factor and ``y`` = ``S^-1 v``."""
    if not cholesky(S, L):
        return np.inf
    cho_solve(L, v, y)
    out = 0.0
    for k in range(v.shape[0]):
        out += v[k] * y[k]
    return out


@njit(cache=True)
def iekf_update(side, pts, meas, Kp, dp, Kq, dq, wt, sigma, R0, t0, vel0, P0, max_iter, R, t, vel, P, res_px,
                sigma_report, Pr0, Pr):
    """Iterated EKF update of the prior ``(R0, t0, vel0, P0)`` with pixel
    observations (``side``/``pts``/``meas``/cameras as in
    :func:`mutloc.core.refine.residuals`, ``wt`` each one's weight) of noise ``sigma``; posterior into
    ``R, t, vel, P`` and each observation's reprojection error (px) at it
    into ``res_px``.

    ``Pr0`` is the prior's covariance were the noise ``sigma_report`` (>=
    ``sigma``); ``Pr`` gets the posterior's, for the gain used (Joseph form),
    and the gate is under it.  With ``sigma_report == sigma`` they are ``P0``
    and ``P``.

    Returns ``(chi2, iterations, ls_chi2)``: the innovation's Mahalanobis
    distance squared under ``sigma_report`` (``2n`` degrees of freedom), inf
    if a marker falls behind the camera seeing it or the innovation
    covariance is not positive definite; ``ls_chi2`` is the squared pixel residual (px^2) of the
    observations fitted on their own (no prior) at the last linearisation,
    ``2n - 6`` degrees of freedom (NaN when ``2n <= 6``): a measure of the
    detections' noise whatever the prior.
    """
    n = side.shape[0]
    m = 2 * n
    basis = np.zeros((n, 3, 3))
    ws = np.empty(WS_SIZE)
    r = np.empty(m)
    J = np.empty((m, 6))
    e = np.zeros(STATE_DIM)
    e_new = np.empty(STATE_DIM)
    innov = np.empty(m)
    y = np.empty(m)
    S = np.empty((m, m))
    L = np.empty((m, m))
    PH = np.empty((STATE_DIM, m))
    s2 = sigma * sigma
    R[:, :] = R0
    t[:] = t0
    chi2 = np.inf
    it = 0
    for it in range(1, max_iter + 1):
        if not residuals(side, pts, meas, basis, Kp, dp, Kq, dq, MODE_PIXEL, wt, R, t, r, J, True, ws):
            return np.inf, it, np.nan
        # PH = P0[:, :6] J^T, S = J P0[:6, :6] J^T + s2 I  (H = [J 0])
        for i in range(STATE_DIM):
            for k in range(m):
                s = 0.0
                for c in range(6):
                    s += P0[i, c] * J[k, c]
                PH[i, k] = s
        for a in range(m):
            for b in range(a + 1):
                s = 0.0
                for c in range(6):
                    s += J[a, c] * PH[c, b]
                S[a, b] = s
                S[b, a] = s
            S[a, a] += s2
        for k in range(m):
            s = -r[k]
            for c in range(6):
                s += J[k, c] * e[c]
            innov[k] = s
        chi2 = _mahalanobis2(S, innov, L, y)
        if not math.isfinite(chi2):
            return np.inf, it, np.nan
        step = 0.0
        for i in range(STATE_DIM):
            s = 0.0
            for k in range(m):
                s += PH[i, k] * y[k]
            e_new[i] = s
            step += (s - e[i]) ** 2
        e[:] = e_new
        so3_exp_left(e[:3], R0, R)
        for k in range(3):
            t[k] = t0[k] + e[3 + k]
        if step < 1e-18:
            break
    for k in range(6):
        vel[k] = vel0[k] + e[6 + k]
    # The observations on their own: |r|^2 - r'J (J'J)^-1 J'r, the part of
    # the residual no pose explains.
    ls_chi2 = np.nan
    if m > 6:
        JtJ = np.empty((6, 6))
        Jtr = np.empty(6)
        normal_equations(J, r, JtJ, Jtr)
        L6 = np.empty((6, 6))
        x6 = np.empty(6)
        if cholesky(JtJ, L6):
            cho_solve(L6, Jtr, x6)
            ls_chi2 = 0.0
            for k in range(m):
                ls_chi2 += r[k] * r[k]
            for a in range(6):
                ls_chi2 -= Jtr[a] * x6[a]
            ls_chi2 = max(ls_chi2, 0.0)
    # Joseph form with the last linearisation: P = (I - K H) P0 (I - K H)^T + s2 K K^T, K = PH S^-1.
    Kg = np.empty((STATE_DIM, m))
    col = np.empty(m)
    row = np.empty(m)
    for i in range(STATE_DIM):
        for k in range(m):
            row[k] = PH[i, k]
        cho_solve(L, row, col)
        for k in range(m):
            Kg[i, k] = col[k]
    A = np.eye(STATE_DIM)
    for i in range(STATE_DIM):
        for c in range(6):
            s = 0.0
            for k in range(m):
                s += Kg[i, k] * J[k, c]
            A[i, c] -= s
    KK = Kg @ Kg.T
    P[:, :] = A @ P0 @ A.T + s2 * KK
    _symmetrize(P)
    if sigma_report == sigma:
        Pr[:, :] = P
    else:
        # The same gain, the stated noise: innovation covariance, gate and posterior.
        Ls = np.empty((m, m))
        for a in range(m):
            for b in range(a + 1):
                s = 0.0
                for c in range(6):
                    for d in range(6):
                        s += J[a, c] * Pr0[c, d] * J[b, d]
                S[a, b] = s
                S[b, a] = s
            S[a, a] += sigma_report * sigma_report
        chi2 = _mahalanobis2(S, innov, Ls, y)
        if not math.isfinite(chi2):
            return np.inf, it, np.nan
        Pr[:, :] = A @ Pr0 @ A.T + sigma_report * sigma_report * KK
        _symmetrize(Pr)
    if not residuals(side, pts, meas, basis, Kp, dp, Kq, dq, MODE_PIXEL, wt, R, t, r, J, False, ws):
        return np.inf, it, np.nan
    for i in range(n):
        res_px[i] = np.sqrt(r[2 * i] ** 2 + r[2 * i + 1] ** 2)
    return chi2, it, ls_chi2


class ConstantVelocityFilter:
    """One relative pose tracked over time (see the module docstring).

    ``reset`` starts (or restarts) the track from a pose and its 6x6
    covariance, ``predict`` moves it to a later time, ``update`` folds in
    one frame's observations (a :class:`PairProblem` with pixels; any number
    of rows) and says whether they were consistent with the track.
    """

    def __init__(self, noise: MotionNoise | None = None, pixel_sigma: float = 1.0,
                 confidence: float = DEFAULT_CONFIDENCE, max_iter: int = 5, measure_noise: bool = True) -> None:
        self.noise = noise if noise is not None else MotionNoise()
        self.pixel_sigma = positive_number(pixel_sigma, "pixel_sigma")
        self.confidence = confidence_level(confidence)
        self.max_iter = int(max_iter)
        self.measure_noise = bool(measure_noise)
        self.state: FilterState | None = None
        # (squared residual, degrees of freedom) of the last accepted frames
        # with four or more markers fitted on their own: the detections' noise.
        self._noise_window: deque[tuple[float, int]] = deque()
        self._noise_sum = [0.0, 0]

    @property
    def detection_sigma(self) -> float | None:
        """The detections' pixel noise measured over the last accepted frames
        (their residuals fitted on their own, pooled), or None before
        ``NOISE_MIN_DOF`` degrees of freedom."""
        return measured_noise(*self._noise_sum, self.pixel_sigma, True)[0]

    @property
    def gain_sigma(self) -> float:
        """The noise the gain weighs the detections with (see :func:`measured_noise`).
        Detections far better than stated then update the track almost as a
        frame on its own would, instead of lagging behind the motion."""
        return measured_noise(*self._noise_sum, self.pixel_sigma, self.measure_noise)[1]

    # -- the track ----------------------------------------------------------

    def reset(self, time: float, pose: Pose, covariance: np.ndarray, velocity: np.ndarray | None = None) -> FilterState:
        """Start the track at ``pose`` (6x6 ``covariance``), velocity zero with
        the noise's initial sigmas unless given."""
        P = np.zeros((STATE_DIM, STATE_DIM))
        P[:6, :6] = np.asarray(covariance, dtype=float)
        n = self.noise
        P[6:9, 6:9] = np.eye(3) * n.initial_angular**2
        P[9:12, 9:12] = np.eye(3) * n.initial_linear**2
        vel = np.zeros(6) if velocity is None else np.asarray(velocity, dtype=float).copy()
        # The start's own covariance, were the noise the measured one: the frame's scaled.
        Pg = P.copy()
        Pg[:6, :6] *= (self.gain_sigma / self.pixel_sigma) ** 2
        self.state = FilterState(float(time), Pose(pose.R.copy(), pose.t.copy()), vel, P,
                                 None if self.gain_sigma == self.pixel_sigma else Pg,
                                 (self.pixel_sigma / self.gain_sigma) ** 2)
        return self.state

    def start(self, state: FilterState) -> FilterState:
        """Start the track from a full state (pose, velocity and their 12x12
        covariance under ``pixel_sigma``, e.g. :func:`fit_moving_pose`'s)."""
        scale = (self.gain_sigma / self.pixel_sigma) ** 2
        P = np.array(state.covariance, dtype=float)
        self.state = FilterState(float(state.time), Pose(state.pose.R.copy(), state.pose.t.copy()),
                                 np.array(state.velocity, dtype=float), P, None if scale == 1.0 else P * scale,
                                 1.0 / scale)
        return self.state

    def predict(self, time: float) -> FilterState:
        """Move the state to ``time`` (no earlier than the state's) by the motion model."""
        s = self._require()
        dt = float(time) - s.time
        if dt < 0.0:
            raise InputError(f"time goes back: {time} after {s.time}")
        R = np.empty((3, 3))
        t = np.empty(3)
        P = np.empty((STATE_DIM, STATE_DIM))
        qa, ql = self.noise.angular**2, self.noise.linear**2
        cv_predict(s.pose.R, s.pose.t, s.velocity, s.covariance, dt, qa, ql, R, t, P)
        Pg = None
        if s.gain_covariance is not None:
            Pg = np.empty((STATE_DIM, STATE_DIM))
            cv_predict(s.pose.R, s.pose.t, s.velocity, s.gain_covariance, dt, qa, ql, R, t, Pg)
        self.state = FilterState(float(time), Pose(R, t), s.velocity, P, Pg, s.noise_scale)
        return self.state

    def update(self, problem: PairProblem) -> FilterUpdate:
        """Fold in one frame's pixel observations (at the state's time; call
        :meth:`predict` first).  Gated; see the module docstring."""
        prior = self._require()
        n = len(problem.side)
        all_rows = np.arange(n)
        first = self._try(problem, all_rows)
        if first is None:
            return self._rejected(prior, n, "a marker would be behind the camera seeing it at the predicted pose")
        state, test, res, iters, ls = first
        if test.passed is not False:
            self._accept(state, ls, n)
            return FilterUpdate(True, state, test, all_rows, np.empty(0, np.int64), res, iterations=iters)
        single = single_outlier(lambda keep: self._try(problem, keep), all_rows)
        if single is not None:
            k, keep, (state, alt_test, res, iters, ls) = single
            self._accept(state, ls, n - 1)
            return FilterUpdate(True, state, alt_test, keep, np.array([k]), res, iterations=iters)
        worst = int(np.argmax(first[2])) if n else -1
        label = problem.labels[worst] if problem.labels is not None and worst >= 0 else f"observation {worst}"
        reason = (f"inconsistent with the track: chi2 {test.chi2:.1f} over {test.dof} degrees of freedom, above "
                  f"{test.threshold:.1f} at {100 * test.confidence:g}%; worst {label} off by "
                  f"{first[2][worst]:.1f} px from the filtered pose")
        return FilterUpdate(False, prior, test, np.empty(0, np.int64), all_rows, self.residuals(problem, prior.pose),
                            reason, iters)

    def update_pose(self, pose: Pose, covariance: np.ndarray) -> FilterUpdate:
        """Fold in a measured pose (e.g. a team's joint estimate of this
        robot) with its 6x6 covariance (SPEC order), at the state's time.

        Linear Kalman update with ``H = [I 0]`` on the error state; the
        innovation is ``(log(R_z R^T), t_z - t)``.  Gated like
        :meth:`update`: its Mahalanobis distance against the chi-square
        quantile with 6 degrees of freedom; a failing pose leaves the
        prediction (``accepted`` False).  ``used`` is ``[0]`` when accepted."""
        from .geometry import so3_exp, so3_log

        s = self._require()
        C = np.asarray(covariance, dtype=float)
        e = np.r_[so3_log(pose.R @ s.pose.R.T), pose.t - s.pose.t]
        S = s.covariance[:6, :6] + C
        L = np.empty((6, 6))
        test_dof = 6
        thr = chi2_quantile(self.confidence, test_dof) if self.confidence < 1.0 else math.inf
        if not cholesky(0.5 * (S + S.T), L):
            test = Consistency(math.inf, test_dof, self.confidence, thr)
            return FilterUpdate(False, s, test, np.empty(0, np.int64), np.array([0]), np.empty(0),
                                "the pose's covariance is not positive definite")
        y = np.empty(6)
        cho_solve(L, e, y)
        test = Consistency(float(e @ y), test_dof, self.confidence, thr)
        if test.passed is False:
            return FilterUpdate(False, s, test, np.empty(0, np.int64), np.array([0]), np.empty(0),
                                f"pose inconsistent with the track: chi2 {test.chi2:.1f} over 6 degrees of freedom, "
                                f"above {thr:.1f} at {100 * self.confidence:g}%")
        PH = s.covariance[:, :6]
        Kg = np.linalg.solve(S, PH.T).T  # P H^T S^-1 (S symmetric)
        dx = Kg @ e
        A = np.eye(STATE_DIM)
        A[:, :6] -= Kg
        P = A @ s.covariance @ A.T + Kg @ C @ Kg.T  # Joseph form
        new = FilterState(s.time, Pose(so3_exp(dx[:3]) @ s.pose.R, s.pose.t + dx[3:6]), s.velocity + dx[6:],
                          0.5 * (P + P.T))
        self.state = new
        return FilterUpdate(True, new, test, np.array([0]), np.empty(0, np.int64), np.empty(0))

    def residuals(self, problem: PairProblem, pose: Pose) -> np.ndarray:
        """Each row's reprojection error (px) at ``pose`` (inf behind a camera)."""
        n = len(problem.side)
        out = np.empty(n)
        r = np.empty(2 * n)
        J = np.empty((1, 6))
        ws = np.empty(WS_SIZE)
        side, pts, meas, Kp, dp, Kq, dq, wt = self._arrays(problem)
        basis = np.zeros((n, 3, 3))
        if not residuals(side, pts, meas, basis, Kp, dp, Kq, dq, MODE_PIXEL, wt, pose.R, pose.t, r, J, False, ws):
            out[:] = np.inf
            return out
        return np.hypot(r[0::2], r[1::2])

    # -- internals ------------------------------------------------------------

    def _accept(self, state: FilterState, ls_chi2: float, n: int) -> None:
        self.state = state
        if math.isfinite(ls_chi2):
            self._noise_window.append((ls_chi2, 2 * n - 6))
            self._noise_sum[0] += ls_chi2
            self._noise_sum[1] += 2 * n - 6
            if len(self._noise_window) > NOISE_WINDOW:
                c, d = self._noise_window.popleft()
                self._noise_sum[0] -= c
                self._noise_sum[1] -= d

    def _require(self) -> FilterState:
        if self.state is None:
            raise InputError("the filter has no state yet: reset() it from a pose first")
        return self.state

    @staticmethod
    def _arrays(problem: PairProblem) -> tuple:
        if problem.pixels is None or problem.K is None or problem.dist is None:
            raise InputError("the filter's update needs pixel observations with their cameras")
        return (np.ascontiguousarray(problem.side, dtype=np.int64), np.ascontiguousarray(problem.points, float),
                np.ascontiguousarray(problem.pixels, float), problem.K[0], problem.dist[0], problem.K[1],
                problem.dist[1], np.ascontiguousarray(problem.wt, float))

    def _try(self, problem: PairProblem, rows: np.ndarray):
        """Posterior, test and residuals from the observations ``rows``, or None."""
        s = self.state
        side, pts, meas, Kp, dp, Kq, dq, wt = self._arrays(problem)
        if len(rows) != len(side):
            side, pts, meas, wt = side[rows], pts[rows], meas[rows], wt[rows]
        n = len(side)
        R = np.empty((3, 3))
        t = np.empty(3)
        vel = np.empty(6)
        Pg = np.empty((STATE_DIM, STATE_DIM))
        P = np.empty((STATE_DIM, STATE_DIM))
        res = np.empty(n)
        sigma = self.gain_sigma
        # Fewer than three markers leave directions the frame cannot fix:
        # relinearising there (iterating) would read information into them
        # that the frame does not hold, and the track grows overconfident
        # (measured: 80 cm off at 10 cm sigma after a second of two markers).
        iters_max = self.max_iter if n >= 3 else 1
        chi2, iters, ls = iekf_update(side, pts, meas, Kp, dp, Kq, dq, wt, sigma, s.pose.R, s.pose.t, s.velocity,
                                      s.own_covariance, iters_max, R, t, vel, Pg, res, self.pixel_sigma,
                                      s.covariance, P)
        if not math.isfinite(chi2):
            return None
        dof = 2 * n
        test = Consistency(float(chi2), dof, self.confidence,
                           chi2_quantile(self.confidence, dof) if self.confidence < 1.0 else math.inf)
        full = np.full(len(problem.side), np.nan)
        full[rows] = res
        if len(rows) != len(problem.side):
            full = self.residuals(problem, Pose(R, t))
        # Back at the stated noise, the reported covariance is the gain's own again.
        own = None if sigma == self.pixel_sigma else Pg
        return (FilterState(s.time, Pose(R, t), vel, P, own, (self.pixel_sigma / sigma) ** 2), test, full, int(iters),
                float(ls))

    def _rejected(self, prior: FilterState, n: int, reason: str) -> FilterUpdate:
        test = Consistency(math.inf, 2 * n, self.confidence, chi2_quantile(self.confidence, max(2 * n, 1)))
        return FilterUpdate(False, prior, test, np.empty(0, np.int64), np.arange(n), np.full(n, np.inf), reason)


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


def rts_gains(priors: list[FilterState], posteriors: list[FilterState]) -> list[np.ndarray]:
    """The RTS smoother's gains ``G_k = P_k F_k' (P_k+1^-)^-1`` (12x12) of a
    track, ``k = 0 .. n-2``, from the filter's own covariances: they depend on
    the filter alone, so a fixed-lag smoother computes each once."""
    F = np.empty((STATE_DIM, STATE_DIM))
    out = []
    for post, prior_next in zip(posteriors[:-1], priors[1:]):
        cv_transition(post.velocity, prior_next.time - post.time, F)
        out.append(np.linalg.solve(prior_next.own_covariance, F @ post.own_covariance).T)
    return out


def rts_smooth(priors: list[FilterState], posteriors: list[FilterState],
               gains: list[np.ndarray] | None = None) -> list[FilterState]:
    """Rauch-Tung-Striebel smoothing of one uninterrupted track.

    ``priors[k]`` is the prediction to frame k (``priors[0]`` unused) and
    ``posteriors[k]`` the filter's state after frame k (its prediction when
    the frame was rejected or empty); ``gains``: :func:`rts_gains` of them,
    if already known.  Returns the smoothed states.
    """
    from .geometry import so3_exp, so3_log

    n = len(posteriors)
    if gains is None:
        gains = rts_gains(priors, posteriors)
    out: list[FilterState] = [posteriors[-1]] * n
    for k in range(n - 2, -1, -1):
        post, prior_next, smooth_next = posteriors[k], priors[k + 1], out[k + 1]
        # The gain from the filter's own covariances.  Where those assumed
        # measured noise below the stated, the reported covariance is the
        # smaller (by trace) of two bounds: the filter's, and the smoothed own
        # one scaled by noise_scale (this gain is not the stated noise's RTS gain).
        G = gains[k]
        d = np.r_[so3_log(smooth_next.pose.R @ prior_next.pose.R.T), smooth_next.pose.t - prior_next.pose.t,
                  smooth_next.velocity - prior_next.velocity]
        e = G @ d
        Pg = post.own_covariance + G @ (smooth_next.own_covariance - prior_next.own_covariance) @ G.T
        if post.gain_covariance is None and prior_next.gain_covariance is None and smooth_next.gain_covariance is None:
            P, Pg = Pg, None
        else:
            Pg = 0.5 * (Pg + Pg.T)
            scaled = post.noise_scale * Pg
            P = scaled if np.trace(scaled[:6, :6]) < np.trace(post.covariance[:6, :6]) else post.covariance
        pose = Pose(so3_exp(e[:3]) @ post.pose.R, post.pose.t + e[3:6])
        out[k] = FilterState(post.time, pose, post.velocity + e[6:], 0.5 * (P + P.T), Pg, post.noise_scale)
    return out


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
            side, pts, meas, Kp, dp, Kq, dq, wt = ConstantVelocityFilter._arrays(prob)
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

