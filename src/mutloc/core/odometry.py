"""A robot's own odometry: the motion between two of its stamps, with a covariance.

An odometry source gives the robot frame's pose in the robot's own odometry
frame at a sequence of stamps on the robot's clock (SPEC "The robots' own
motion and clocks").  An odometry frame drifts, so only the motion between
two stamps is used: :meth:`Odometry.increment` gives ``D = T(t0)^-1 T(t1)``,
the robot frame at ``t1`` in the robot frame at ``t0``, and its 6x6
covariance in the SPEC's convention (rotation vector on the left, then
translation: ``R_true = expm(skew(dtheta)) @ R``, ``t_true = t + dt``,
both in the robot frame at ``t0``).  Between two samples the pose moves on
the SE(3) geodesic (constant twist, :func:`~mutloc.core.geometry.se3_exp`).

Noise.  Each sample interval contributes its own independent error (a
random walk: the covariance of ``D`` is the same however the interval from
``t0`` to ``t1`` is split, which is what a filter composing increments
needs), carried to the robot frame at ``t0`` through the motion after it
(a heading error early swings the later path).  An interval's error is

- the growth of the message's covariance over it, where the samples carry
  covariances (ROS ``nav_msgs/Odometry``: the pose's covariance in the
  odometry frame, which grows as the odometry drifts) and it grows;
- else :class:`OdometryNoise` (a publisher whose covariance is all zeros or
  constant -- e.g. a fixed diagonal -- says nothing about the motion).

Bad samples are rejected and counted in :attr:`Odometry.counts`: not finite
or not a rotation (``invalid``), a stamp not after the last accepted one
(``not_increasing``), a speed or turn rate beyond the bounds (``jump``: a
single outlier is dropped; a jump the next sample confirms is a reset of the
odometry frame, after which the samples are used again, never an increment
across it).  An interval longer than ``max_gap`` is never used either
(``gap``).  Input that leaves fewer than two samples is an
:class:`~mutloc.errors.OdometryError`.

No I/O here: the readers (TUM files, bags) are :mod:`mutloc.track.odometry`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..errors import OdometryError, positive_number
from .geometry import se3_exp, se3_log, skew
from .pose import Pose

__all__ = ["Odometry", "OdometryNoise", "OdometryIncrement", "DEFAULT_MAX_SPEED", "DEFAULT_MAX_TURN_RATE",
           "DEFAULT_MAX_GAP"]

#: Samples farther apart than this speed (m/s) or turn rate (rad/s) are a jump.
DEFAULT_MAX_SPEED = 5.0
DEFAULT_MAX_TURN_RATE = 2.0 * math.pi
#: An interval between samples longer than this (s) is not used (the odometry stopped).
DEFAULT_MAX_GAP = 0.5


@dataclass(frozen=True)
class OdometryNoise:
    """The odometry's error where its messages give none: a random walk in
    the distance travelled, the angle turned and the time elapsed.  Over a
    stretch of ``d`` metres, ``a`` radians turned and ``s`` seconds, each
    axis of the robot frame gets, independently,

    - translation variance ``distance**2 * d + floor_m**2 * s`` (m^2),
    - rotation variance ``radians(deg_per_m)**2 * d + turn**2 * a + radians(floor_deg)**2 * s`` (rad^2).

    The defaults are twice a typical wheeled robot's drift (1 % of the
    distance, 0.3 deg per metre, 1 % of the angle turned; a standstill
    drifting 1 mm and 0.05 deg per square-root second), so that an
    uncalibrated odometry is not trusted beyond what it gives: its increments
    err on the side of a larger covariance.
    """

    #: Translation sigma (m) per axis after 1 m travelled.
    distance: float = 0.02
    #: Rotation sigma (degrees) per axis after 1 m travelled.
    deg_per_m: float = 1.0
    #: Rotation sigma (rad) per axis after 1 rad turned.
    turn: float = 0.02
    #: Translation sigma (m) per axis after 1 s, moving or not.
    floor_m: float = 0.001
    #: Rotation sigma (degrees) per axis after 1 s, moving or not.
    floor_deg: float = 0.05

    def __post_init__(self) -> None:
        for name in ("distance", "deg_per_m", "turn", "floor_m", "floor_deg"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not (math.isfinite(v) and v >= 0):
                raise OdometryError(f"odometry noise {name} must be a finite number >= 0, got {v!r}")
        if self.floor_m == 0 or self.floor_deg == 0:
            raise OdometryError("odometry noise floor_m and floor_deg must be > 0 (a robot standing still "
                                "still drifts)")

    def covariance(self, distance: float, angle: float, duration: float) -> np.ndarray:
        """The 6x6 covariance (SPEC order) of a stretch of ``distance`` m, ``angle`` rad, ``duration`` s."""
        rot = math.radians(self.deg_per_m) ** 2 * distance + self.turn**2 * angle \
            + math.radians(self.floor_deg) ** 2 * duration
        lin = self.distance**2 * distance + self.floor_m**2 * duration
        return np.diag([rot, rot, rot, lin, lin, lin])


@dataclass(frozen=True)
class OdometryIncrement:
    """The robot's motion from ``t0`` to ``t1`` (its own clock): ``pose`` maps
    the robot frame at ``t1`` to the robot frame at ``t0``; ``covariance``
    6x6 in the SPEC's convention and order."""

    t0: float
    t1: float
    pose: Pose
    covariance: np.ndarray


def _interval_twists(R: np.ndarray, t: np.ndarray) -> np.ndarray:
    """The twist of each interval's relative pose ``T_k^-1 T_{k+1}`` (n-1, 6)."""
    out = np.empty((len(R) - 1, 6))
    for k in range(len(R) - 1):
        Rk = R[k].T @ R[k + 1]
        tk = R[k].T @ (t[k + 1] - t[k])
        out[k] = se3_log(Rk, tk)
    return out


class Odometry:
    """One robot's odometry: ``times`` (s, its own clock), ``poses`` (a stack
    of the robot frame's pose in the odometry frame) and, optionally,
    ``covariances`` (n, 6, 6), each the pose's covariance in the odometry
    frame in the SPEC's convention and order (ROS messages' are converted by
    :func:`mutloc.io.ros.spec_covariance`).  ``source`` names the input in
    errors.  See the module's text for the noise and the samples rejected."""

    def __init__(self, times: Any, poses: Pose, covariances: Any = None, *, source: str = "odometry",
                 noise: OdometryNoise | None = None, max_speed: float = DEFAULT_MAX_SPEED,
                 max_turn_rate: float = DEFAULT_MAX_TURN_RATE, max_gap: float = DEFAULT_MAX_GAP) -> None:
        self.source = str(source)
        self.noise = noise if noise is not None else OdometryNoise()
        self.max_speed = positive_number(max_speed, "max_speed", OdometryError)
        self.max_turn_rate = positive_number(max_turn_rate, "max_turn_rate", OdometryError)
        self.max_gap = positive_number(max_gap, "max_gap", OdometryError)
        times = np.asarray(times, dtype=float).reshape(-1)
        if not isinstance(poses, Pose) or poses.single or poses.R.ndim != 3 or len(poses) != len(times):
            raise OdometryError(f"{self.source}: {len(times)} stamps need a stack of as many poses")
        cov = None
        if covariances is not None:
            cov = np.asarray(covariances, dtype=float)
            if cov.shape != (len(times), 6, 6):
                raise OdometryError(f"{self.source}: covariances must be ({len(times)}, 6, 6), got {cov.shape}")
        #: Samples rejected, by reason (see the module's text).
        self.counts = {"invalid": 0, "not_increasing": 0, "jump": 0, "gap": 0}
        ok = [self._valid(poses.R[i], poses.t[i], times[i], None if cov is None else cov[i])
              for i in range(len(times))]
        keep: list[int] = []
        broken: list[bool] = []  # broken[j]: the interval ending at keep[j] is not used
        for i in range(len(times)):
            if not ok[i]:
                self.counts["invalid"] += 1
                continue
            if keep and not times[i] > times[keep[-1]]:
                self.counts["not_increasing"] += 1
                continue
            brk = False
            if keep and self._jump(poses, times, keep[-1], i):
                self.counts["jump"] += 1
                nxt = next((j for j in range(i + 1, len(times)) if ok[j] and times[j] > times[i]), None)
                if nxt is None or self._jump(poses, times, i, nxt) or not self._jump(poses, times, keep[-1], nxt):
                    continue  # an outlier: the next sample goes on from the last accepted one
                brk = True  # a reset: the odometry frame moved, go on from here
            if keep and times[i] - times[keep[-1]] > self.max_gap:
                self.counts["gap"] += 1
                brk = True
            keep.append(i)
            broken.append(brk)
        if len(keep) < 2:
            raise OdometryError(f"{self.source}: {len(times)} odometry samples, fewer than 2 usable "
                                f"({self._rejected() or 'need at least two'})")
        idx = np.array(keep)
        #: The accepted samples' stamps and poses.
        self.times = times[idx]
        self.poses = Pose(poses.R[idx].copy(), poses.t[idx].copy())
        self._broken = np.array(broken, dtype=bool)
        self._twists = _interval_twists(self.poses.R, self.poses.t)
        self._q = self._interval_noise(None if cov is None else cov[idx])

    # -- acceptance ---------------------------------------------------------------------------------------

    @staticmethod
    def _valid(R: np.ndarray, t: np.ndarray, time: float, cov: np.ndarray | None) -> bool:
        if not (np.all(np.isfinite(R)) and np.all(np.isfinite(t)) and math.isfinite(time)):
            return False
        if np.abs(R.T @ R - np.eye(3)).max() > 1e-6 or np.linalg.det(R) < 0:
            return False
        return cov is None or bool(np.all(np.isfinite(cov)))

    def _jump(self, poses: Pose, times: np.ndarray, a: int, b: int) -> bool:
        dt = times[b] - times[a]
        if dt <= 0:
            return True
        dist = float(np.linalg.norm(poses.t[b] - poses.t[a]))
        c = (np.trace(poses.R[a].T @ poses.R[b]) - 1.0) / 2.0
        ang = float(np.arccos(np.clip(c, -1.0, 1.0)))
        return dist > self.max_speed * dt or ang > self.max_turn_rate * dt

    def _rejected(self) -> str:
        return ", ".join(f"{n} {k.replace('_', ' ')}" for k, n in self.counts.items() if n)

    # -- noise --------------------------------------------------------------------------------------------

    def _interval_noise(self, cov: np.ndarray | None) -> np.ndarray:
        """Each interval's error covariance (n-1, 6, 6), in the robot frame at its start."""
        n = len(self.times)
        q = np.empty((n - 1, 6, 6))
        for k in range(n - 1):
            q[k] = self._noise_of(k, None if cov is None else cov[k], None if cov is None else cov[k + 1])
        return q

    def _noise_of(self, k: int, c0: np.ndarray | None, c1: np.ndarray | None) -> np.ndarray:
        """Interval ``k``'s error covariance (its samples' pose covariances ``c0``, ``c1``; None: not given)."""
        if c0 is not None and c1 is not None:
            g = c1 - c0
            g = 0.5 * (g + g.T)
            w, V = np.linalg.eigh(g)
            if w.max() > 0 and np.any(c1):
                g = (V * np.clip(w, 0.0, None)) @ V.T
                Rt = self.poses.R[k].T
                J = np.zeros((6, 6))
                J[:3, :3] = Rt
                J[3:, 3:] = Rt
                return J @ g @ J.T
        xi = self._twists[k]
        dist = float(np.linalg.norm(self.poses.t[k + 1] - self.poses.t[k]))
        return self.noise.covariance(dist, float(np.linalg.norm(xi[:3])), float(self.times[k + 1] - self.times[k]))

    # -- queries ------------------------------------------------------------------------------------------

    @property
    def start(self) -> float:
        """The first accepted stamp."""
        return float(self.times[0])

    @property
    def end(self) -> float:
        """The last accepted stamp."""
        return float(self.times[-1])

    def _locate(self, t: float, end: bool = False) -> tuple[int, float]:
        """The interval ``k`` holding ``t`` and the fraction of it before ``t``
        (``end``: a stamp on a sample ends the interval before it)."""
        k = int(np.searchsorted(self.times, t, side="left" if end else "right")) - 1
        k = min(max(k, 0), len(self.times) - 2)
        s = (t - self.times[k]) / (self.times[k + 1] - self.times[k])
        return k, float(min(max(s, 0.0), 1.0))

    def _check(self, t: float) -> float:
        t = float(t)
        if not (math.isfinite(t) and self.times[0] <= t <= self.times[-1]):
            raise OdometryError(f"{self.source}: stamp {t:.9g} outside the odometry's "
                                f"[{self.times[0]:.9g}, {self.times[-1]:.9g}]")
        return t

    def _partial(self, k: int, s0: float, s1: float) -> tuple[np.ndarray, np.ndarray]:
        """The relative pose from fraction ``s0`` to ``s1`` of interval ``k``."""
        R, t = se3_exp((s1 - s0) * self._twists[k])
        return R, t

    def pose_at(self, t: float) -> Pose:
        """The robot frame's pose in the odometry frame at ``t`` (geodesic between the samples)."""
        k, s = self._locate(self._check(t))
        R, d = self._partial(k, 0.0, s)
        return Pose(self.poses.R[k] @ R, self.poses.R[k] @ d + self.poses.t[k])

    def covers(self, t0: float, t1: float) -> bool:
        """Whether :meth:`increment` has the motion from ``t0`` to ``t1``: both
        within the samples, ``t0 <= t1`` and no reset or gap between them."""
        if not (math.isfinite(t0) and math.isfinite(t1) and self.times[0] <= t0 <= t1 <= self.times[-1]):
            return False
        k0, _ = self._locate(t0)
        k1, _ = self._locate(t1, end=True)
        return not bool(np.any(self._broken[k0 + 1:k1 + 2]))

    def increment(self, t0: float, t1: float) -> OdometryIncrement:
        """The motion from ``t0`` to ``t1`` (``T(t0)^-1 T(t1)``) with its covariance;
        OdometryError naming the source and the stamps where the odometry
        does not cover it (:meth:`covers`)."""
        t0, t1 = self._check(t0), self._check(t1)
        if t1 < t0:
            raise OdometryError(f"{self.source}: increment from {t0:.9g} back to {t1:.9g}")
        if not self.covers(t0, t1):
            raise OdometryError(f"{self.source}: no odometry from {t0:.9g} to {t1:.9g} (a reset or a gap of "
                                f"more than {self.max_gap:g} s between)")
        k0, s0 = self._locate(t0)
        k1, s1 = self._locate(t1, end=True)
        R, t = np.eye(3), np.zeros(3)
        P = np.zeros((6, 6))
        for k in range(k0, k1 + 1):
            a = s0 if k == k0 else 0.0
            b = s1 if k == k1 else 1.0
            Rb, tb = self._partial(k, a, b)
            # D <- D o d: the error so far carried through d, then d's own error rotated into D's frame
            JA = np.eye(6)
            JA[3:, :3] = -skew(R @ tb)
            JB = np.zeros((6, 6))
            JB[:3, :3] = R
            JB[3:, 3:] = R
            P = JA @ P @ JA.T + (b - a) * (JB @ self._q[k] @ JB.T)
            t = R @ tb + t
            R = R @ Rb
        return OdometryIncrement(t0, t1, Pose(R, t), 0.5 * (P + P.T))

    def __len__(self) -> int:
        return len(self.times)

    def __repr__(self) -> str:
        rej = self._rejected()
        return (f"Odometry({self.source!r}, {len(self.times)} samples over [{self.start:.3f}, {self.end:.3f}] s"
                + (f"; rejected: {rej}" if rej else "") + ")")
