"""One filter for a whole team: every robot's pose and velocity in the
reference robot's frame, with their correlations, updated by each camera's
observations at that camera's own capture time.

State: for each tracked robot ``i`` (not the reference, whose pose is the
identity) the pose ``T_ref_i = (R_i, t_i)`` and its velocity ``(w_i, v_i)``
-- the constant-velocity state of :mod:`mutloc.core.filter` per robot -- and one
``12k x 12k`` covariance over all ``k`` tracked robots' error states
``(dtheta, dt, dw, dv)`` (SPEC perturbations: ``R <- exp(dtheta) R``,
``t <- t + dt``).  The off-diagonal blocks are the robots' correlations:
two robots seen by one camera are known relative to each other better than
each is known in the reference's frame, and an observation of one moves the
other.

Motion: each robot's constant-velocity model, independent white-noise
accelerations (:class:`~mutloc.core.filter.MotionNoise`), plus (with
``MotionNoise.reference_angular``) the reference's own turning, one white
angular acceleration shared by all: it
turns every robot's relative pose the other way and moves its position
through its lever arm (``t_i x phi``), so far robots' predictions grow
faster and all of them move together (correlated); where robots
have odometry (:meth:`TeamFilter.set_odometry`), their increments between
the two times move the poses instead (:mod:`mutloc.core.team_odometry`).

Update: an iterated EKF on the pixel residuals of any set of observations
taken at one time (typically one camera's frame) -- "camera ``a`` saw
marker ``P`` of robot ``b``", either of them possibly the reference --
through the team solver's residuals and Jacobians
(:func:`mutloc.core.team.team_residuals`), touching only the blocks of the
robots involved (Numba kernels: :mod:`mutloc.core.team_kernels`).  Gated: the innovation's Mahalanobis
distance against the chi-square quantile with ``2n`` degrees of freedom; a
failing update is retried without each single observation (with three or
more) and exactly one passing subset drops that observation, else the
update is rejected and the state stays the prediction.  Observations of
robots not tracked are not used (the caller starts them first).

Detection noise: ``pixel_sigma`` is the stated noise
behind the reported covariance (:attr:`TeamFilter.P`) and the gate.  The
filter also measures the noise from each accepted update's residual that no
pose explains (its observations fitted on their own: the involved robots'
poses free, the reference fixed, ``2m - 6q`` degrees of freedom for ``m``
observations of ``q`` robots the record fixes); when it is clearly smaller
(:func:`~mutloc.core.filter.measured_noise`), the gain weighs the
detections by it and the filter carries, next to the stated covariance, the
gain's own (:attr:`TeamFilter.Pg`); the stated one is then the Joseph form
of the same gain under ``pixel_sigma``.

Nothing here reads files or decides statuses: the tracker does.
"""

from __future__ import annotations

import copy
import math
from collections import deque
from dataclasses import dataclass

import numpy as np

from ..errors import InputError, confidence_level, positive_number
from .consistency import DEFAULT_CONFIDENCE, Consistency, chi2_quantile
from .filter import NOISE_WINDOW, STATE_DIM, MotionNoise, measured_noise, single_outlier
from .geometry import skew
from .odometry import Odometry, OdometryIncrement
from .pose import Pose
from .team import TeamProblem
from .team_kernels import team_iekf, team_ls_residual, team_predict
from .team_odometry import odometry_predict

__all__ = ["TeamFilter", "TeamUpdate", "TeamSnapshot"]


@dataclass(frozen=True)
class TeamUpdate:
    """What one set of observations did: ``accepted`` (the state was
    updated), the gate's ``test``, the rows ``used`` and ``dropped``, each
    row's reprojection error (px) at the resulting state, and the ``reason``
    of a rejection.  ``own``: the update's observations fitted on their own
    (those ``used`` when accepted, all of them when rejected) -- ``(chi2,
    dof)``, the squared residual no pose explains over ``pixel_sigma**2``
    and its degrees of freedom (what the filter measures the noise from,
    accepted updates only; ``(nan, 0)`` without degrees of freedom): with a
    correct rig and honest noise, chi-square with ``dof`` whatever the track
    (see :mod:`mutloc.track.rig_check`)."""

    accepted: bool
    test: Consistency
    used: np.ndarray
    dropped: np.ndarray
    residuals_px: np.ndarray
    reason: str = ""
    own: tuple[float, int] = (math.nan, 0)


@dataclass(frozen=True)
class TeamSnapshot:
    """The filter's state at one time, kept for smoothing: ``tracked`` the
    robots' indices in state order, ``serial`` each one's track (a robot
    started again is a new track), their poses ``R``/``t`` and velocities
    ``vel`` (one row each, in state order) and the joint covariance ``P``
    under the stated noise; ``Pg`` the gain's own where it weighed measured,
    smaller noise (None: the same) and ``noise_scale`` ``(pixel_sigma /
    gain sigma)^2`` at the last update (see :class:`TeamFilter`)."""

    time: float
    tracked: tuple[int, ...]
    serial: tuple[int, ...]
    R: np.ndarray
    t: np.ndarray
    vel: np.ndarray
    P: np.ndarray
    Pg: np.ndarray | None = None
    noise_scale: float = 1.0
    #: The transition of the prediction to this time where odometry moved
    #: it (k x 12 x 12, state order); None: each robot's constant velocity.
    F: np.ndarray | None = None

    @property
    def own(self) -> np.ndarray:
        """The covariance the gain was computed with."""
        return self.P if self.Pg is None else self.Pg

    def position(self, robot: int) -> int:
        """``robot``'s place in the state (-1: not tracked)."""
        return self.tracked.index(robot) if robot in self.tracked else -1


class TeamFilter:
    """The joint filter of a team (see the module docstring).

    ``robots``: every robot's name in the order of the
    :class:`~mutloc.core.team.TeamProblem` indices the updates use;
    ``reference``: the one whose frame the poses are in.  Robots enter the
    state with :meth:`add` (or :meth:`reset`) and leave it with :meth:`drop`.
    ``measure_noise``: the gain may weigh the detections by their measured
    noise (see the module docstring).
    """

    def __init__(self, robots: list[str], reference: str, noise: MotionNoise | None = None,
                 pixel_sigma: float = 1.0, confidence: float = DEFAULT_CONFIDENCE, max_iter: int = 5,
                 measure_noise: bool = True) -> None:
        if reference not in robots:
            raise InputError(f"reference {reference!r} is not among the robots {robots}")
        self.robots = list(robots)
        self.reference = reference
        self.noise = noise if noise is not None else MotionNoise()
        self.pixel_sigma = positive_number(pixel_sigma, "pixel_sigma")
        self.confidence = confidence_level(confidence)
        self.max_iter = int(max_iter)
        self.measure_noise = bool(measure_noise)
        self.time: float | None = None
        n = len(self.robots)
        #: Every robot's pose (the reference's and untracked robots' are the identity / unused).
        self.R = np.tile(np.eye(3), (n, 1, 1))
        self.t = np.zeros((n, 3))
        self.vel = np.zeros((n, 6))
        #: Tracked robots' indices, in state order, and the joint covariance (under ``pixel_sigma``).
        self.tracked: list[int] = []
        self.P = np.zeros((0, 0))
        #: The gain's own joint covariance (None: ``P``) and ``(pixel_sigma / gain sigma)^2`` at the last update.
        self.Pg: np.ndarray | None = None
        self.noise_scale = 1.0
        # (squared residual, degrees of freedom) of the last accepted updates
        # fitted on their own: the detections' noise.
        self._noise_window: deque[tuple[float, int]] = deque()
        self._noise_sum = [0.0, 0]
        #: Each robot's track: a new number whenever it enters the state (see :class:`TeamSnapshot`).
        self.serial = np.zeros(n, np.int64)
        self._serials = 0
        #: Each robot's odometry (by index) and its clock's offset to the
        #: reference's (s, added to its stamps), see :meth:`set_odometry`.
        self.odometry: dict[int, tuple[Odometry, float]] = {}
        #: The last prediction's transition where odometry moved it (:attr:`TeamSnapshot.F`).
        self.transition: np.ndarray | None = None

    def set_odometry(self, name: str, odometry: Odometry | None, clock_offset: float = 0.0) -> None:
        """``name``'s odometry (None: none) for the predictions from now on,
        its stamps on a clock ``clock_offset`` s behind the filter's (the
        offset added to them puts them on the filter's clock).  An interval
        its odometry does not cover falls back to the constant-velocity model."""
        i = self.index(name)
        if odometry is None:
            self.odometry.pop(i, None)
            return
        if not isinstance(odometry, Odometry):
            raise InputError(f"odometry of {name!r} must be an Odometry, got {type(odometry).__name__}")
        off = float(clock_offset)
        if not math.isfinite(off):
            raise InputError(f"clock offset of {name!r} must be finite, got {clock_offset!r}")
        self.odometry[i] = (odometry, off)

    def _increment(self, i: int, t0: float, t1: float) -> OdometryIncrement | None:
        """Robot ``i``'s odometry increment from ``t0`` to ``t1`` (the filter's clock), or None."""
        if i not in self.odometry:
            return None
        odo, off = self.odometry[i]
        if not odo.covers(t0 - off, t1 - off):
            return None
        return odo.increment(t0 - off, t1 - off)

    # -- the state ----------------------------------------------------------

    @property
    def detection_sigma(self) -> float | None:
        """The detections' pixel noise measured over the last accepted
        updates (their residuals fitted on their own, pooled), or None before
        enough degrees of freedom."""
        return measured_noise(*self._noise_sum, self.pixel_sigma)[0]

    @property
    def gain_sigma(self) -> float:
        """The noise the gain weighs the detections with (see :func:`~mutloc.core.filter.measured_noise`)."""
        return measured_noise(*self._noise_sum, self.pixel_sigma, self.measure_noise)[1]

    @property
    def own_covariance(self) -> np.ndarray:
        """The joint covariance the gain is computed with (``Pg``, else ``P``)."""
        return self.P if self.Pg is None else self.Pg

    def index(self, name: str) -> int:
        try:
            return self.robots.index(name)
        except ValueError:
            raise InputError(f"unknown robot {name!r} (the filter has {self.robots})") from None

    def is_tracked(self, name: str) -> bool:
        return self.index(name) in self.tracked

    def pose(self, name: str) -> Pose:
        """``T_ref_name`` now."""
        i = self.index(name)
        return Pose(self.R[i].copy(), self.t[i].copy())

    def velocity(self, name: str) -> np.ndarray:
        return self.vel[self.index(name)].copy()

    def _block(self, name: str) -> slice:
        i = self.index(name)
        if i not in self.tracked:
            raise InputError(f"robot {name!r} is not tracked")
        k = self.tracked.index(i)
        return slice(STATE_DIM * k, STATE_DIM * (k + 1))

    def covariance(self, name: str) -> np.ndarray:
        """6x6 pose covariance of ``T_ref_name`` (SPEC order)."""
        b = self._block(name)
        return self.P[b, b][:6, :6].copy()

    def state_covariance(self, a: str, b: str | None = None) -> np.ndarray:
        """The 12x12 block of robots ``a`` and ``b`` (default ``a``) of the joint covariance."""
        return self.P[self._block(a), self._block(b or a)].copy()

    def relative(self, a: str, b: str) -> tuple[Pose, np.ndarray]:
        """``T_b_a`` (robot ``a`` in ``b``'s frame) and its 6x6 covariance,
        from the joint covariance (their correlation included)."""
        from .team import relative_jacobian

        ia, ib = self.index(a), self.index(b)
        Ja, Jb = relative_jacobian(self.R[ia], self.t[ia], self.R[ib], self.t[ib])
        pose = Pose(self.R[ib].T @ self.R[ia], self.R[ib].T @ (self.t[ia] - self.t[ib]))
        return pose, self.pose_sandwich([(a, Ja), (b, Jb)])

    def pose_sandwich(self, terms: list[tuple[str, np.ndarray]]) -> np.ndarray:
        """``sum J_a P_ab J_b^T`` over the robots' pose blocks of the joint
        covariance, for ``terms`` ``(robot, J)`` (``J``: k x 6 Jacobians with
        respect to that robot's pose; the reference's term is zero): the
        covariance of a function of several robots' poses, correlations
        included.  Symmetric (k x k)."""
        live = [(self._block(name), np.asarray(J, float)) for name, J in terms if name != self.reference]
        k = np.asarray(terms[0][1]).shape[0]
        C = np.zeros((k, k))
        for s1, J1 in live:
            for s2, J2 in live:
                C += J1 @ self.P[s1, s2][:6, :6] @ J2.T
        return 0.5 * (C + C.T)

    def add(self, name: str, pose: Pose, covariance: np.ndarray, velocity: np.ndarray | None = None,
            velocity_covariance: np.ndarray | None = None, state_covariance: np.ndarray | None = None) -> None:
        """Start tracking ``name`` at ``pose`` (6x6 ``covariance``; velocity
        zero with :meth:`start_velocity_covariance` unless given), uncorrelated with
        the robots already tracked; ``state_covariance``: instead, the full
        12x12 covariance of pose and velocity (with their correlation)."""
        i = self.index(name)
        if name == self.reference:
            raise InputError("the reference's pose is the identity: it is not tracked")
        if i in self.tracked:
            self.drop(name)
        B = np.zeros((STATE_DIM, STATE_DIM))
        B[:6, :6] = np.asarray(covariance, float)
        B[6:, 6:] = (np.asarray(velocity_covariance, float) if velocity_covariance is not None else
                     self.start_velocity_covariance(pose))
        # The start's own covariance, were the noise the measured one: the
        # measured part scaled (the pose's; all of a full state's).
        scale = (self.gain_sigma / self.pixel_sigma) ** 2
        Bg = B.copy()
        Bg[:6, :6] *= scale
        if state_covariance is not None:
            B = np.array(state_covariance, float).reshape(STATE_DIM, STATE_DIM)
            Bg = B * scale
        if scale != 1.0 or self.Pg is not None:
            if self.Pg is None:
                self.noise_scale = 1.0 / scale
            self.Pg = self._grown(self.own_covariance, Bg)
        self.P = self._grown(self.P, B)
        self.tracked.append(i)
        self._serials += 1
        self.serial[i] = self._serials
        self.R[i], self.t[i] = pose.R, pose.t
        self.vel[i] = 0.0 if velocity is None else np.asarray(velocity, float)

    def start_velocity_covariance(self, pose: Pose) -> np.ndarray:
        """The 6x6 covariance of a robot's velocity ``(w, v)`` in the
        reference's frame when its track starts at ``pose`` knowing nothing of
        it: its own (the noise's ``initial_angular`` / ``initial_linear``
        sigmas) and, with :attr:`MotionNoise.reference_angular`, the
        reference's unknown turning (``initial_angular`` too), which turns the
        robot the other way and sweeps it sideways at ``|t|`` times that rate."""
        n = self.noise
        C = np.diag([n.initial_angular**2] * 3 + [n.initial_linear**2] * 3)
        if n.reference_turn > 0.0:
            B = np.vstack([-np.eye(3), skew(np.asarray(pose.t, float))])
            C = C + n.initial_angular**2 * (B @ B.T)
        return C

    @staticmethod
    def _grown(P: np.ndarray, B: np.ndarray) -> np.ndarray:
        """``P`` with the block ``B`` appended, uncorrelated."""
        k = P.shape[0]
        out = np.zeros((k + STATE_DIM,) * 2)
        out[:k, :k] = P
        out[k:, k:] = B
        return out

    def drop(self, name: str) -> None:
        """Stop tracking ``name`` (its block and correlations go)."""
        b = self._block(name)
        keep = np.r_[np.arange(0, b.start), np.arange(b.stop, self.P.shape[0])]
        self.P = self.P[np.ix_(keep, keep)]
        if self.Pg is not None:
            self.Pg = self.Pg[np.ix_(keep, keep)]
        self.tracked.remove(self.index(name))

    def reset(self, time: float, poses: dict[str, Pose], covariance: np.ndarray) -> None:
        """Start the filter at ``time`` from a joint estimate: ``poses`` of
        robots (not the reference) with their ``6k x 6k`` joint
        ``covariance`` in that order (what
        :attr:`mutloc.TeamEstimate.joint_covariance` gives); velocities zero
        with the noise's initial sigmas."""
        names = list(poses)
        C = np.asarray(covariance, float)
        if C.shape != (6 * len(names), 6 * len(names)):
            raise InputError(f"covariance must be {6 * len(names)} square for {len(names)} robots, got {C.shape}")
        self.tracked, self.P, self.Pg, self.time = [], np.zeros((0, 0)), None, float(time)
        scale = (self.gain_sigma / self.pixel_sigma) ** 2
        self.noise_scale = 1.0 / scale
        for name in names:
            self.add(name, poses[name], np.eye(6))
        for x, a in enumerate(names):
            for y, b in enumerate(names):
                sa, sb = self._block(a), self._block(b)
                block = C[6 * x:6 * x + 6, 6 * y:6 * y + 6]
                self.P[sa.start:sa.start + 6, sb.start:sb.start + 6] = block
                if self.Pg is not None:
                    self.Pg[sa.start:sa.start + 6, sb.start:sb.start + 6] = scale * block

    def copy(self) -> "TeamFilter":
        """An independent copy of the filter, as cheap as it can be: the
        poses, velocities and bookkeeping copied, the covariances shared --
        the filter never writes into a covariance array once another may
        hold it (predict, add, drop and updates make new ones)."""
        new = copy.copy(self)
        new.R, new.t, new.vel, new.serial = self.R.copy(), self.t.copy(), self.vel.copy(), self.serial.copy()
        new.tracked = list(self.tracked)
        new._noise_window, new._noise_sum = deque(self._noise_window), list(self._noise_sum)
        return new

    def snapshot(self) -> TeamSnapshot:
        """A copy of the state now (see :class:`TeamSnapshot`)."""
        idx = np.asarray(self.tracked, np.int64)
        return TeamSnapshot(-math.inf if self.time is None else self.time, tuple(self.tracked),
                            tuple(int(s) for s in self.serial[idx]), self.R[idx].copy(), self.t[idx].copy(),
                            self.vel[idx].copy(), self.P.copy(), None if self.Pg is None else self.Pg.copy(),
                            self.noise_scale, None if self.transition is None else self.transition.copy())

    # -- motion ---------------------------------------------------------------

    def predict(self, time: float) -> None:
        """Every tracked robot moved to ``time`` by its motion model (its
        odometry and the reference's where they cover the interval, see
        :mod:`mutloc.core.team_odometry`)."""
        self.transition = None
        if self.time is None:
            self.time = float(time)
            return
        dt = float(time) - self.time
        if dt < 0.0:
            raise InputError(f"time goes back: {time} after {self.time}")
        t0, self.time = self.time, float(time)
        if dt == 0.0 or not self.tracked:
            return
        tracked = np.asarray(self.tracked, np.int64)
        qa, ql = self.noise.angular**2, self.noise.linear**2
        if self.odometry:
            ref = self._increment(self.index(self.reference), t0, self.time)
            own = {i: inc for i in self.tracked if (inc := self._increment(i, t0, self.time)) is not None}
            if ref is not None or own:
                covs = [self.P] + ([self.Pg] if self.Pg is not None else [])
                out, self.transition = odometry_predict(self.R, self.t, self.vel, self.tracked, covs, dt, qa, ql,
                                                        own, ref)
                self.P = out[0]
                if self.Pg is not None:
                    self.Pg = out[1]
                if ref is None:
                    self._reference_turn(dt)
                return
        if self.Pg is not None:  # (the poses move once: with the stated covariance below)
            Pg = np.array(self.Pg, dtype=float, order="C")
            team_predict(tracked, self.R.copy(), self.t.copy(), self.vel, Pg, dt, qa, ql)
            self.Pg = Pg
        P = np.array(self.P, dtype=float, order="C")  # a new array: results handed out before stay as they were
        team_predict(tracked, self.R, self.t, self.vel, P, dt, qa, ql)
        self.P = P
        self._reference_turn(dt)

    def _reference_turn(self, dt: float) -> None:
        """Add the reference's own unforeseen turning over ``dt`` to the
        predicted covariances (:attr:`MotionNoise.reference_angular`): its
        rotation ``phi`` (white angular acceleration, integrated twice) moves
        robot ``i``'s error state by ``(-phi, t_i x phi)`` and its velocity by
        the rate of that -- the same ``phi`` for every robot, so the added
        noise ``L L^T`` (``L``: ``12k x 6``) correlates them."""
        q = self.noise.reference_turn
        if q == 0.0 or not self.tracked:
            return
        d3, d2 = dt**3 / 3.0, dt**2 / 2.0
        c00 = math.sqrt(d3)  # the Cholesky factor of q [[dt^3/3, dt^2/2], [dt^2/2, dt]]
        c10 = d2 / c00
        c11 = math.sqrt(max(dt - c10 * c10, 0.0))
        L = np.zeros((STATE_DIM * len(self.tracked), 6))
        for x, i in enumerate(self.tracked):
            o = STATE_DIM * x
            B = np.vstack([-np.eye(3), skew(self.t[i])])  # (dtheta, dt) of robot i per unit phi
            L[o:o + 6, :3] = c00 * B
            L[o + 6:o + 12, :3] = c10 * B
            L[o + 6:o + 12, 3:] = c11 * B
        L *= q
        Q = L @ L.T
        self.P = self.P + Q
        if self.Pg is not None:
            self.Pg = self.Pg + Q

    # -- observations -------------------------------------------------------

    def update(self, problem: TeamProblem) -> TeamUpdate:
        """Fold in observations taken at the filter's time (call
        :meth:`predict` first); rows involving an untracked robot (other
        than the reference) are ignored.  Gated (see the module docstring)."""
        ref = self.index(self.reference)
        known = self._positions() >= 0
        known[ref] = True
        rows = np.flatnonzero(known[problem.cam] & known[problem.own])
        n = len(rows)
        if n == 0:
            return TeamUpdate(False, Consistency(0.0, 0, self.confidence, math.inf), rows, rows, np.empty(0),
                              "no observation of tracked robots")
        first = self._try(problem, rows)
        if first is not None and first[1].passed is not False:
            own = self._accept(first)
            return TeamUpdate(True, first[1], rows, np.empty(0, np.int64), first[2], own=own)
        single = single_outlier(lambda keep: self._try(problem, keep), rows)
        if single is not None:
            j, keep, alt = single
            own = self._accept(alt)
            return TeamUpdate(True, alt[1], keep, np.array([j]), alt[2], own=own)
        test = first[1] if first is not None else Consistency(math.inf, 2 * n, self.confidence,
                                                              chi2_quantile(self.confidence, 2 * n))
        res = first[2] if first is not None else np.full(n, np.inf)
        reason = (f"inconsistent with the track: chi2 {test.chi2:.1f} over {test.dof} degrees of freedom, above "
                  f"{test.threshold:.1f} at {100 * test.confidence:g}%")
        own = self._own(first[3]) if first is not None else (math.nan, 0)
        return TeamUpdate(False, test, np.empty(0, np.int64), rows, res, reason, own=own)

    def _try(self, problem: TeamProblem, rows: np.ndarray):
        """The iterated update with observations ``rows``: ``(state, test,
        residuals_px, linearisation)`` or None (a marker behind its camera,
        or no positive definite innovation covariance).  The gain weighs
        the detections by :attr:`gain_sigma`; the state's covariance and the
        gate are under ``pixel_sigma``."""
        if len(rows) == len(problem.cam):
            cam, own, pts, meas, wt, fr = problem.cam, problem.own, problem.points, problem.uv, problem.wt, problem.fr
        else:
            cam, own, pts, meas, wt = (problem.cam[rows], problem.own[rows], problem.points[rows], problem.uv[rows],
                                       problem.wt[rows])
            fr = problem.fr if problem.frames is None else np.ascontiguousarray(problem.frames[rows])
        m = len(rows)
        ref = self.index(self.reference)
        pos = self._positions()
        robots = np.unique(np.r_[cam, own])
        robots = robots[robots != ref]
        cols = (STATE_DIM * pos[robots][:, None] + np.arange(6)).ravel()
        Rs, ts, vel = np.empty_like(self.R), np.empty_like(self.t), np.empty_like(self.vel)
        Pg = np.empty_like(self.P)
        res = np.empty(m)
        H, r, innov = np.empty((2 * m, len(cols))), np.empty(2 * m), np.empty(2 * m)
        sigma = self.gain_sigma
        ok, chi2 = team_iekf(cam, own, pts, meas, wt, problem.K, problem.dist, fr, pos, ref, self.R, self.t, self.vel,
                             self.own_covariance, sigma**2, self.max_iter, Rs, ts, vel, Pg, res, H, r, innov)
        if not ok:
            return None
        if sigma == self.pixel_sigma:
            # Back at the stated noise, the reported covariance is the gain's own again.
            P, Pg = Pg, None
        else:
            stated = self._stated(H, cols, innov, sigma)
            if stated is None:
                return None
            P, chi2 = stated
        dof = 2 * m
        test = Consistency(chi2, dof, self.confidence,
                           chi2_quantile(self.confidence, dof) if self.confidence < 1.0 else math.inf)
        blocks = np.searchsorted(robots, np.c_[cam, own])  # each observation's column blocks (-1: the reference)
        blocks[np.c_[cam, own] == ref] = -1
        return (Rs, ts, vel, P, Pg, (self.pixel_sigma / sigma) ** 2), test, res, (H, r, blocks)

    def _stated(self, H: np.ndarray, cols: np.ndarray, innov: np.ndarray, sigma: float):
        """The posterior covariance under ``pixel_sigma`` of the gain computed
        with the own covariance and noise ``sigma`` (Joseph form, ``H`` the
        Jacobian on the pose columns ``cols`` at the last linearisation), and
        the innovation's Mahalanobis distance under ``pixel_sigma``; None if
        its covariance is not positive definite.

        With ``A = P_own[:, cols]``, ``B = P[:, cols]``, the gain ``K = A Z``
        (``Z = H^T S_own^-1``) and ``S = H B[cols] H^T + s^2 I``: ``(I - K H) P
        (I - K H)^T + s^2 K K^T = P + Y + Y^T``, ``Y = (K S / 2 - B H^T) K^T``,
        or, with fewer columns than rows, ``Y = (A T / 2 - B Q^T) A^T``
        (``T = Z S Z^T``, ``Q = Z H``): one product of rank ``min(2m, 6q)``."""
        A, B = self.own_covariance[:, cols], self.P[:, cols]
        eye = np.eye(H.shape[0])
        S = H @ B[cols] @ H.T + self.pixel_sigma**2 * eye
        try:
            L = np.linalg.cholesky(0.5 * (S + S.T))
        except np.linalg.LinAlgError:
            return None
        w = np.linalg.solve(L, innov)
        Z = np.linalg.solve(H @ A[cols] @ H.T + sigma**2 * eye, H).T
        if H.shape[0] <= H.shape[1]:
            K = A @ Z
            Y = (K @ (0.5 * S) - B @ H.T) @ K.T
        else:
            Y = (A @ (0.5 * (Z @ S @ Z.T)) - B @ (Z @ H).T) @ A.T
        out = Y + Y.T
        out += self.P
        return out, float(w @ w)

    def _positions(self) -> np.ndarray:
        """Each robot's state block (-1: not tracked)."""
        pos = np.full(len(self.robots), -1, np.int64)
        pos[np.asarray(self.tracked, np.int64)] = np.arange(len(self.tracked))
        return pos

    def _accept(self, result) -> tuple[float, int]:
        """Take ``result`` (of :meth:`_try`) as the state; its observations'
        own residual (``TeamUpdate.own``) joins the noise's window."""
        (self.R, self.t, self.vel, self.P, self.Pg, self.noise_scale), _, _, (H, r, blocks) = result
        chi2, dof = team_ls_residual(H, r, blocks)
        if dof <= 0:
            return math.nan, 0
        self._noise_window.append((chi2, dof))
        self._noise_sum[0] += chi2
        self._noise_sum[1] += dof
        if len(self._noise_window) > NOISE_WINDOW:
            c, d = self._noise_window.popleft()
            self._noise_sum[0] -= c
            self._noise_sum[1] -= d
        return float(chi2) / self.pixel_sigma**2, int(dof)

    def _own(self, linearisation) -> tuple[float, int]:
        """``TeamUpdate.own`` of an update's observations (its last linearisation ``(H, r, blocks)``)."""
        chi2, dof = team_ls_residual(*linearisation)
        return (float(chi2) / self.pixel_sigma**2, int(dof)) if dof > 0 else (math.nan, 0)
