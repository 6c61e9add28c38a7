"""Odometry received live (SPEC "The robots' own motion and clocks"):
``mutloc localizer --odometry NAME=ros:/TOPIC`` subscribes to a
``nav_msgs/msg/Odometry`` topic over DDS, and the team filter moves the
robot by the motion between two of its odometry poses, as ``track
--odometry`` does offline (:mod:`mutloc.core.team_odometry`).

:class:`OdometryStream` is a robot's odometry growing as its messages come:
an :class:`~mutloc.core.odometry.Odometry` (the filter asks it for the
increment between two records) whose samples are taken one at a time under
the same rules as a whole file's -- a sample not finite or not a rotation
(``invalid``), stamped at or before the last one taken
(``not_increasing``), a single outlier beyond the speed or turn-rate bounds
(``jump``) rejected; a jump the next sample confirms is a reset of the
odometry frame and a sample after more than ``max_gap`` s a gap, both taken
with no increment across them.  So the samples it takes, written to a TUM
file, give offline the same odometry (``track --odometry
NAME=DIR/odometry_NAME.tum``).

:class:`LiveOdometry` is what the localizer keeps of every robot's
odometry: each message checked before its sample is offered to the stream,
and refused and counted where it cannot be a sample of this robot's
odometry -- not decodable or not an Odometry message (``refused_malformed``),
a ``child_frame_id`` that is set and is not the robot's frame
(``refused_frame``), a quaternion that is not unit within 1e-3 or a value
that is not finite (``refused_invalid``), a stamp in the future beyond
``--max-clock-skew`` (``refused_clock``).  Every count is in
``/diagnostics`` (``odometry_received``, ``odometry_used``,
``odometry_refused``, ...); each kind of refusal is said once with its
reason (then rate-limited, as refused observations are).

A record waits for the odometry: it is fused once every robot's odometry
that is coming (a sample taken arrived in the last :data:`ODOMETRY_QUIET` s)
has a sample at or after its stamp, or :data:`ODOMETRY_WAIT` s after it
arrived; one fused before a robot's odometry covered it is counted
(``odometry_uncovered``): its motion there was the constant-velocity
model's, and that record's replay with the odometry file may differ.

Each sample taken is, exactly, the TUM line it is written as (its numbers
rounded to nine decimals, as ``track`` reads them back): the replay reads
what the localizer used.  The TUM file cannot hold the messages'
covariances: where they were given (not all zeros) the replay uses
``--odometry-noise`` instead, and the localizer's summary says so.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from types import SimpleNamespace
from typing import Any, Callable, Iterable

import numpy as np

from ..core.geometry import se3_log
from ..core.odometry import (DEFAULT_MAX_GAP, DEFAULT_MAX_SPEED, DEFAULT_MAX_TURN_RATE, Odometry, OdometryNoise)
from ..core.pose import Pose
from ..errors import OdometryError, positive_number

__all__ = ["OdometryStream", "LiveOdometry", "OdometryCounts", "ODOMETRY_WAIT", "ODOMETRY_QUIET", "KEEP_SECONDS",
           "QUATERNION_TOLERANCE", "tum_line"]

#: Seconds a record waits at most for every coming odometry to pass its stamp.
ODOMETRY_WAIT = 0.1
#: An odometry with no message for this many seconds (arrival clock) is not waited for.
ODOMETRY_QUIET = 0.5
#: Seconds of samples a stream keeps before its newest (the filter asks for the last records' intervals).
KEEP_SECONDS = 30.0
#: How far from 1 a message's quaternion norm may be (as a TUM file's: mutloc.io.trajectory).
QUATERNION_TOLERANCE = 1e-3


def tum_line(t: float, position: Iterable[float], quaternion_xyzw: Iterable[float]) -> str:
    """A sample as a TUM line (``t tx ty tz qx qy qz qw``, nine decimals, as mutloc writes TUM files)."""
    return " ".join(f"{float(x):.9f}" for x in (t, *position, *quaternion_xyzw)) + "\n"


def _from_line(line: str) -> tuple[float, np.ndarray, np.ndarray]:
    """``(t, R, t)`` of a TUM line, exactly as :func:`mutloc.io.trajectory.read_tum` reads it."""
    a = np.array([float(x) for x in line.split()], dtype=float).reshape(1, 8)
    pose = Pose.from_quaternion_xyzw(a[:, 4:8], a[:, 1:4])
    return float(a[0, 0]), pose.R[0], pose.t[0]


class OdometryStream(Odometry):
    """One robot's odometry taking its samples one at a time (:meth:`add`;
    see the module's text): the same queries as :class:`Odometry`
    (:meth:`covers`, :meth:`increment`, :meth:`pose_at`) over the samples
    taken so far (the last :data:`KEEP_SECONDS` s of them).  ``taken(t, R,
    t_vec, sample)``: called with each sample taken, in order."""

    def __init__(self, source: str, *, noise: OdometryNoise | None = None, max_speed: float = DEFAULT_MAX_SPEED,
                 max_turn_rate: float = DEFAULT_MAX_TURN_RATE, max_gap: float = DEFAULT_MAX_GAP,
                 keep: float = KEEP_SECONDS, taken: Callable[[float, np.ndarray, np.ndarray, Any], None] | None = None
                 ) -> None:
        # (Odometry.__init__ takes every sample at once: the same attributes here, grown by add())
        self.source = str(source)
        self.noise = noise if noise is not None else OdometryNoise()
        self.max_speed = positive_number(max_speed, "max_speed", OdometryError)
        self.max_turn_rate = positive_number(max_turn_rate, "max_turn_rate", OdometryError)
        self.max_gap = positive_number(max_gap, "max_gap", OdometryError)
        self.keep = positive_number(keep, "keep", OdometryError)
        self.counts = {"invalid": 0, "not_increasing": 0, "jump": 0, "gap": 0}
        #: Resets of the odometry frame (a jump the next sample confirmed).
        self.resets = 0
        self.taken = taken
        cap = 64
        self._T = np.empty(cap)
        self._R = np.empty((cap, 3, 3))
        self._t = np.empty((cap, 3))
        self._C: list[np.ndarray | None] = []
        self._brk = np.zeros(cap, dtype=bool)
        self._tw = np.empty((cap, 6))
        self._qq = np.empty((cap, 6, 6))
        self._n = 0
        #: A sample beyond the bounds, waiting for the next to say whether it is an outlier or a reset.
        self._pending: tuple | None = None

    # -- the arrays Odometry's queries read -----------------------------------------------------------

    @property
    def times(self) -> np.ndarray:  # type: ignore[override]
        return self._T[:self._n]

    @property
    def poses(self) -> Any:  # type: ignore[override]
        return SimpleNamespace(R=self._R[:self._n], t=self._t[:self._n])

    @property
    def _broken(self) -> np.ndarray:  # type: ignore[override]
        return self._brk[:self._n]

    @property
    def _twists(self) -> np.ndarray:  # type: ignore[override]
        return self._tw[:max(0, self._n - 1)]

    @property
    def _q(self) -> np.ndarray:  # type: ignore[override]
        return self._qq[:max(0, self._n - 1)]

    def covers(self, t0: float, t1: float) -> bool:
        return self._n >= 2 and super().covers(t0, t1)

    def __len__(self) -> int:
        return self._n

    def __repr__(self) -> str:
        span = f"[{self._T[0]:.3f}, {self._T[self._n - 1]:.3f}] s" if self._n else "no samples yet"
        return f"OdometryStream({self.source!r}, {self._n} samples kept over {span})"

    # -- samples in ------------------------------------------------------------------------------------

    def add(self, t: float, R: np.ndarray, tv: np.ndarray, cov: np.ndarray | None = None, sample: Any = None) -> str:
        """Offer one sample (stamp ``t``, pose ``R``, ``tv`` in the odometry
        frame, its 6x6 covariance in SPEC order or None, ``sample``: what is
        handed to ``taken`` with it); returns what became of it: ``taken``,
        ``gap`` or ``reset`` (taken, no increment across it), ``held`` (beyond
        the bounds: the next sample decides), or the reason it was rejected
        (``invalid``, ``not_increasing``)."""
        R, tv = np.asarray(R, dtype=float), np.asarray(tv, dtype=float)
        c = None if cov is None else np.asarray(cov, dtype=float)
        if not self._valid(R, tv, float(t), c):
            self.counts["invalid"] += 1
            return "invalid"
        t = float(t)
        if self._pending is not None:
            pt, pR, ptv, pc, ps = self._pending
            if not t > pt:  # (not the sample that decides: the pending one's fate first)
                self.counts["not_increasing"] += 1
                return "not_increasing"
            self._pending = None
            last = self._n - 1
            if not self._bound(t - pt, R, tv, pR, ptv) \
                    and self._bound(t - self._T[last], R, tv, self._R[last], self._t[last]):
                # the next goes on from the pending one, not from the last taken: a reset of the odometry frame
                self.resets += 1
                if pt - self._T[last] > self.max_gap:
                    self.counts["gap"] += 1
                self._append(pt, pR, ptv, pc, ps, True)
            # (else: an outlier, counted when it came; the next goes on from the last taken)
        if self._n and not t > self._T[self._n - 1]:
            self.counts["not_increasing"] += 1
            return "not_increasing"
        if self._n and self._bound(t - self._T[self._n - 1], R, tv, self._R[self._n - 1], self._t[self._n - 1]):
            self.counts["jump"] += 1
            self._pending = (t, R, tv, c, sample)
            return "held"
        gap = bool(self._n) and t - self._T[self._n - 1] > self.max_gap
        if gap:
            self.counts["gap"] += 1
        self._append(t, R, tv, c, sample, gap)
        return "gap" if gap else "taken"

    def _bound(self, dt: float, R: np.ndarray, tv: np.ndarray, R0: np.ndarray, t0: np.ndarray) -> bool:
        """Whether the motion from ``(R0, t0)`` to ``(R, tv)`` in ``dt`` s is beyond the bounds (a jump)."""
        if dt <= 0:
            return True
        dist = float(np.linalg.norm(tv - t0))
        ang = float(np.arccos(np.clip((np.trace(R0.T @ R) - 1.0) / 2.0, -1.0, 1.0)))
        return dist > self.max_speed * dt or ang > self.max_turn_rate * dt

    def _append(self, t: float, R: np.ndarray, tv: np.ndarray, c: np.ndarray | None, sample: Any, brk: bool) -> None:
        if self._n and t - self._T[0] > 2 * self.keep:
            self._forget(t - self.keep)
        if self._n == len(self._T):
            self._grow()
        n = self._n
        self._T[n], self._R[n], self._t[n], self._brk[n] = t, R, tv, brk
        self._C.append(c)
        self._n = n + 1
        if n:
            Rk = self._R[n - 1].T @ R
            self._tw[n - 1] = se3_log(Rk, self._R[n - 1].T @ (tv - self._t[n - 1]))
            self._qq[n - 1] = self._noise_of(n - 1, self._C[n - 1], c)
        if self.taken is not None:
            self.taken(t, R, tv, sample)

    def _grow(self) -> None:
        cap = 2 * len(self._T)
        for name in ("_T", "_R", "_t", "_brk", "_tw", "_qq"):
            old = getattr(self, name)
            new = np.zeros((cap, *old.shape[1:]), dtype=old.dtype)
            new[:len(old)] = old
            setattr(self, name, new)

    def _forget(self, before: float) -> None:
        """Drop the samples stamped before ``before`` (keeping two at least)."""
        k = min(int(np.searchsorted(self._T[:self._n], before)), self._n - 2)
        if k <= 0:
            return
        m = self._n - k
        for name in ("_T", "_R", "_t", "_brk"):
            a = getattr(self, name)
            a[:m] = a[k:self._n].copy()
        for name in ("_tw", "_qq"):
            a = getattr(self, name)
            a[:m - 1] = a[k:self._n - 1].copy()
        del self._C[:k]
        self._n = m


@dataclass
class OdometryCounts:
    """What one robot's odometry topic brought (its ``odometry_*`` key-values in ``/diagnostics``)."""

    received: int = 0
    used: int = 0
    refused_malformed: int = 0
    refused_frame: int = 0
    refused_invalid: int = 0
    refused_clock: int = 0
    #: Records fused before this odometry covered them (the motion model instead).
    uncovered: int = 0
    #: Whether a message's covariance was used (not all zeros): the TUM file cannot hold it.
    covariance_given: bool = False
    last_stamp: float | None = None
    last_arrival: float | None = None
    #: Arrival of its last sample taken (a record waits only for an odometry whose samples are taken).
    last_taken_arrival: float | None = None
    last_refused_at: float | None = None
    last_refusal: str = ""

    @property
    def refused(self) -> int:
        return self.refused_malformed + self.refused_frame + self.refused_invalid + self.refused_clock


#: The stream's rejections, as they are named among the counts.
_REJECTED = ("not_increasing", "jump")


class LiveOdometry:
    """Every robot's live odometry for the localizer: ``topics`` is ``{robot:
    topic}`` (what is subscribed to); ``noise`` and ``bounds`` are
    :class:`~mutloc.core.odometry.Odometry`'s; ``tum(robot)``: a writer of
    the robot's TUM file (an object with ``write(text)``), or None.  See the
    module's text."""

    def __init__(self, topics: dict[str, str], *, noise: OdometryNoise | None = None,
                 tum: Callable[[str], Any] | None = None, max_clock_skew: float = 0.05, **bounds: Any) -> None:
        self.topics = dict(topics)
        self.max_clock_skew = float(max_clock_skew)
        self.counts = {r: OdometryCounts() for r in self.topics}
        self.writers = {r: (tum(r) if tum is not None else None) for r in self.topics}
        self.streams: dict[str, OdometryStream] = {
            r: OdometryStream(f"ros:{topic}", noise=noise, taken=self._taken(r), **bounds)
            for r, topic in self.topics.items()}

    def _taken(self, robot: str) -> Callable[[float, np.ndarray, np.ndarray, Any], None]:
        def taken(t: float, R: np.ndarray, tv: np.ndarray, line: Any) -> None:
            self.counts[robot].used += 1
            w = self.writers[robot]
            if w is not None and line is not None:
                w.write(line)
        return taken

    # -- messages in -------------------------------------------------------------------------------------

    def receive(self, robot: str, msg: Any, now: float) -> tuple[str, str | None]:
        """Take one message of ``robot``'s odometry topic arrived at ``now``:
        ``(what, why)``, ``what`` one of ``taken``, ``gap``, ``held``, ``rejected_not_increasing``, ``refused_malformed``,
        ``refused_frame``, ``refused_invalid``, ``refused_clock``; ``why`` the
        reason of a refusal in words (None otherwise).  Never raises for the
        message's content."""
        from ..io.ros import odometry_sample

        c = self.counts[robot]
        c.received += 1
        c.last_arrival = now
        try:
            t, pose, cov, child = odometry_sample(msg)
            o = msg.pose.pose.orientation
            q = [float(o.x), float(o.y), float(o.z), float(o.w)]
        except Exception as exc:  # noqa: BLE001 -- anything on the topic is input: counted, never raised
            return self._refuse(robot, "refused_malformed", f"not a nav_msgs/msg/Odometry message "
                                f"({type(exc).__name__})", now)
        frame = str(child).strip().strip("/")
        if frame and frame != robot:
            return self._refuse(robot, "refused_frame", f"child_frame_id {child!r} is not robot {robot!r}'s frame "
                                f"(the odometry must give the pose of the robot frame, {robot!r})", now)
        norm = math.sqrt(sum(x * x for x in q)) if all(math.isfinite(x) for x in q) else math.nan
        values = [t, *pose.t, *q]
        if not all(math.isfinite(x) for x in values) or not np.all(np.isfinite(cov)):
            return self._refuse(robot, "refused_invalid", f"a value that is not finite at stamp {t:.9f}", now)
        if abs(norm - 1.0) > QUATERNION_TOLERANCE:
            return self._refuse(robot, "refused_invalid", f"quaternion of norm {norm:.6g} at stamp {t:.9f}, "
                                f"not 1 within {QUATERNION_TOLERANCE:g}", now)
        if t > now + self.max_clock_skew:
            return self._refuse(robot, "refused_clock", f"stamped {t - now:.3f} s in the future (beyond "
                                f"--max-clock-skew {self.max_clock_skew:g} s): synchronize the clocks", now)
        line = tum_line(t, pose.t, q)
        ts, R, tv = _from_line(line)  # (what the TUM file holds, exactly)
        given = bool(np.any(cov))
        c.covariance_given |= given
        what = self.streams[robot].add(ts, R, tv, cov if given else None, line)
        if what in ("taken", "gap"):
            c.last_stamp = ts if c.last_stamp is None else max(c.last_stamp, ts)
            c.last_taken_arrival = now
            return what, None
        if what == "held":  # (beyond the bounds: the next sample says whether it is taken)
            return what, None
        if what == "invalid":  # (a rotation the checks above let through: not orthonormal once parsed)
            return self._refuse(robot, "refused_invalid", f"not a rotation at stamp {t:.9f}", now)
        return "rejected_" + what, None

    def malformed(self, robot: str, now: float) -> tuple[str, str | None]:
        """Count one sample of ``robot``'s odometry topic that could not even be decoded."""
        c = self.counts[robot]
        c.received += 1
        c.last_arrival = now
        return self._refuse(robot, "refused_malformed", "bytes that do not decode as a nav_msgs/msg/Odometry", now)

    def _refuse(self, robot: str, what: str, why: str, now: float) -> tuple[str, str]:
        c = self.counts[robot]
        setattr(c, what, getattr(c, what) + 1)
        c.last_refused_at, c.last_refusal = now, why
        return what, why

    # -- records ---------------------------------------------------------------------------------------

    def coming(self, now: float) -> list[str]:
        """The robots whose odometry is coming: a sample taken arrived in the last :data:`ODOMETRY_QUIET` s
        (an odometry whose messages are all refused is not waited for)."""
        return [r for r, c in self.counts.items() if c.last_taken_arrival is not None
                and now - c.last_taken_arrival <= ODOMETRY_QUIET]

    def ready(self, t: float, arrival: float, now: float) -> bool:
        """Whether a record stamped ``t`` (its message arrived at ``arrival``) may be fused at ``now``:
        every coming odometry has a sample at or after ``t``, or it waited :data:`ODOMETRY_WAIT` s."""
        if now >= arrival + ODOMETRY_WAIT:
            return True
        return all(self.counts[r].last_stamp is not None and self.counts[r].last_stamp >= t
                   for r in self.coming(now))

    def fused(self, t0: float | None, t1: float) -> None:
        """A record at ``t1`` was fused after one at ``t0``: count the odometry that did not cover it."""
        if t0 is None or not t1 > t0:
            return
        for r, s in self.streams.items():
            c = self.counts[r]
            if c.last_arrival is not None and not s.covers(t0, t1):
                c.uncovered += 1

    # -- what is said ----------------------------------------------------------------------------------

    def values(self, robot: str, now: float) -> dict[str, Any]:
        """``robot``'s ``odometry_*`` key-values for ``/diagnostics`` (empty: no odometry for it)."""
        c = self.counts.get(robot)
        if c is None:
            return {}
        s = self.streams[robot]
        return {"odometry_topic": self.topics[robot], "odometry_received": c.received, "odometry_used": c.used,
                "odometry_age_s": "none" if c.last_stamp is None else f"{now - c.last_stamp:.3f}",
                "odometry_refused": c.refused, "odometry_refused_malformed": c.refused_malformed,
                "odometry_refused_frame": c.refused_frame, "odometry_refused_invalid": c.refused_invalid,
                "odometry_refused_clock": c.refused_clock,
                "odometry_rejected_not_increasing": s.counts["not_increasing"],
                "odometry_rejected_jump": s.counts["jump"] - s.resets, "odometry_resets": s.resets,
                "odometry_gaps": s.counts["gap"], "odometry_uncovered": c.uncovered}

    def said(self, robot: str, now: float, hold: float) -> list[str]:
        """What is wrong with ``robot``'s odometry, for its diagnostics' message (refusals in the last ``hold`` s)."""
        c = self.counts.get(robot)
        if c is None or c.last_refused_at is None or now - c.last_refused_at > hold:
            return []
        return [f"refused {c.refused} odometry messages: {c.last_refusal}"]

    def summary(self) -> str:
        """``odometry p 250 used (refused 3, rejected 1)``, one part per robot; the replay's caveat."""
        parts = []
        for r, c in self.counts.items():
            s = self.streams[r]
            rej = s.counts["not_increasing"] + s.counts["jump"] - s.resets
            bits = [f"refused {c.refused}" if c.refused else "", f"rejected {rej}" if rej else "",
                    f"{c.uncovered} records before it" if c.uncovered else ""]
            bits = [b for b in bits if b]
            parts.append(f"odometry {r} {c.used} used" + (f" ({', '.join(bits)})" if bits else ""))
        given = [r for r, c in self.counts.items() if c.covariance_given]
        if given:
            parts.append(f"odometry covariances of {', '.join(given)} used (the TUM files cannot hold them: a "
                         "replay uses --odometry-noise)")
        return "; ".join(parts)
