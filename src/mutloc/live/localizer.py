"""The live localizer (SPEC "Live operation"): every robot's ``Observations``
messages in, each fused at its own capture time, a pose per tracked robot out.

:class:`Localizer` is the logic, without DDS: it is fed the messages with
their arrival (wall-clock) time and returns the poses to publish, so it is
tested and benchmarked on recorded or simulated logs.  :func:`run_localizer`
puts it on the wire (the ``live`` extra).

Each accepted message is one record of the track -- with the messages of
other robots stamped within ``tolerance`` (5 ms) of it, at their mean time,
as ``track`` pairs two cameras' frames -- fused exactly as ``track
--observations`` fuses a log's line (the team tracker of
:mod:`mutloc.track.team`, two robots a team of two); what it fuses is what it
logs (``--out DIR``: ``DIR/log.jsonl``, each observer's best candidate per
marker, SPEC "Observation logs"), so replaying the log offline gives the same
rows.  The pose published at once is the causal filter's; the trajectory
files hold the rows as ``track`` reports them (smoothed over the tracker's
lag).

Messages are refused and counted, per robot, when they cannot be taken: not
decodable or not what a node sends (``refused_malformed``: an unknown robot,
a robot on another's topic, a ``header.frame_id`` that is neither the robot
nor one of its cameras, a non-finite pixel, a marker not in the rig, a
pixel far outside the image), of another rig (``refused_rig_id``), or
stamped in the future by more than ``max_clock_skew`` (``refused_clock``).
Each refusal is also said: the robot is WARN in the diagnostics for
:data:`NOTICE_HOLD` s after its last refused message, with the count and
why (``refused 100 observations: rig_id ... is not this rig's (...)``), and
``notify`` gets a line the first time of each robot and kind, then at most
one every :data:`NOTICE_PERIOD` s with the count since.  Another localizer
publishing poses of this rig's robots on the domain (:func:`run_localizer`
reads its own topics for poses it did not write) is WARN too, and said once.
A message seen before (camera, frame and stamp) is a ``duplicate`` and
ignored.  Accepted messages wait in a short reorder buffer so that records
are fused in time order: one leaves it once every other live camera has sent
a later stamp (none of theirs can come before it: DDS delivers each
writer's messages in order) or ``reorder`` seconds after it arrived; a
message stamped before the last record fused is ``dropped_late``.  A robot
with several cameras sends each camera's messages with ``header.frame_id``
``ROBOT/CAMERA`` (SPEC "Robots with several cameras, any lens"): each camera
is a stream of its own, and messages of several cameras (of one robot or
several) stamped within ``tolerance`` make one record.

Under load the localizer sheds work instead of building a backlog: when a
record is about to be fused more than ``max_lag`` (0.1 s) after its capture
(the clock read again before each record), a message of it is dropped if a
newer message of the same camera is waiting (that camera's newest is always
fused; messages of different cameras are never coalesced), counted as
``shed`` per robot; the robot is WARN in the diagnostics ("falling behind:
shed N of M", M the messages received) for :data:`NOTICE_HOLD` s after its
last shed message.  On the wire the same rule is applied first, before any
work: the samples a reader holds are taken as bytes, each one's camera and
stamp read from its header alone (:meth:`Localizer.select`), and only those
that are not shed are decoded and checked -- a shed message costs a few
microseconds, however far behind the localizer is (its content is not
checked: a shed message is never refused).

With ``--out`` the trajectory files get the rows smoothed over the
tracker's lag (the published poses never wait for the smoother).  The
smoother is what a record costs most, so it gives way first: a record fused
more than ``max_lag`` behind its capture is not smoothed then (deferred);
the deferred records are smoothed, oldest first, when the localizer has
slack (:meth:`Localizer.catch_up`: nothing due to fuse), which gives the
same rows as smoothing them at once.  At most ``max_deferred``
(:data:`MAX_DEFERRED`) records wait so; beyond that the oldest are written
as the causal filter gave them -- the pose published for them -- and
counted (``records_unsmoothed``, in the summary "N records written
unsmoothed").  Every fused record is in ``log.jsonl`` either way: ``track
--observations DIR/log.jsonl`` gives every row smoothed after the run.

Each fused message gives a pose of every tracked robot it is about (a
record of several messages one per message, stamped with each one's capture
time; messages of one stamp, one pose): with
two robots the pair's, with a team its observer's and those of the robots
whose markers it saw (the others' rows are the motion model's prediction
alone, and a team of ten at 30 frames/s would otherwise publish 2,700 of
them a second).

With ``odometry`` (``localizer --odometry NAME=ros:/TOPIC``) the robots'
``nav_msgs/msg/Odometry`` messages move them between records, and records
wait for them: :mod:`mutloc.live.odometry`.

Observations that keep disagreeing with the rig file (the team tracker's
window test, :mod:`mutloc.track.rig_check`: markers moved since the rig was
measured) make every robot WARN, with the test's ``rig_chi2``, ``rig_dof``
and ``rig_threshold`` among the key-values (there from the first record
tested) and the hint to run ``calibrate-markers``, for :data:`NOTICE_HOLD`
s after the last record whose window disagreed; ``notify`` gets the hint
line once.

A robot whose last observation (its capture time) is older than
``warn_after`` (0.5 s) is WARN in the diagnostics, older than
``max_coast`` STALE (dropped).  A robot's pose is published only while its
track is current: the row of the fused record ``solved``, ``unverified``,
``partial``, or ``predicted`` no longer than ``max_coast`` after its last
measured row -- never a stale pose as current.  A robot that comes back is
re-acquired by its track (the tracker restarts a track it lost).

The parts: :class:`Localizer` takes the messages, fuses the records and
decides which poses go out; :mod:`mutloc.live.reorder` is the reorder
buffer, :mod:`mutloc.live.team_engine` the team tracker it runs,
:mod:`mutloc.live.rig_gate` the rule that withholds the poses for the rig
check, :mod:`mutloc.live.localizer_status` the counts, the ``/diagnostics``
statuses, the lines said and the summary, and
:mod:`mutloc.live.localizer_wire` the loop on DDS (:func:`run_localizer`).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Callable, Sequence

from ..api import Estimate, load_rig
from ..core.consistency import DEFAULT_CONFIDENCE
from ..core.observations import ObservationSet
from ..errors import InputError, MutlocError, positive_number
from ..track.filtering import FilterOptions
from ..track.frames import expanded_rig
from ..track.rows import TrackRow
from ..track.status import FrameStatus
from .messages import MessageError, RobotStatus, observations_from_message, observer_frame_ids, rig_id as rig_id_of
from .clocks import LiveClocks
from .localizer_status import NOTICE_HOLD, NOTICE_PERIOD, RobotCounts, Tally, level, robot_statuses, summary
from .localizer_wire import (DIAGNOSTICS_PERIOD, odometry_inputs, serve, take_observations as _take)  # noqa: F401
from .reorder import Held, ReorderBuffer
from .rig_gate import RigGate
from .team_engine import TeamEngine, warm_up
from .ties import TieWindow

__all__ = ["Localizer", "LivePose", "RobotCounts", "run_localizer", "LocalizerRun", "MAX_COAST", "MAX_CLOCK_SKEW",
           "WARN_AFTER", "MAX_LAG", "MAX_DEFERRED", "REORDER_WINDOW", "DIAGNOSTICS_PERIOD", "NOTICE_HOLD", "NOTICE_PERIOD"]

#: Seconds a robot's track may coast on its motion model before its pose is no longer published (``--max-coast``).
MAX_COAST = 1.0
#: Seconds a message may be stamped ahead of the localizer's clock (``--max-clock-skew``).
MAX_CLOCK_SKEW = 0.05
#: A robot whose last observation is older than this (s) is WARN.
WARN_AFTER = 0.5
#: Seconds behind its capture beyond which a message is shed when a newer one of its camera waits (``--max-lag``).
MAX_LAG = 0.1
#: Seconds a message may wait for earlier ones from the other robots (``--reorder``).
REORDER_WINDOW = 0.03
#: Messages of different robots stamped within this many seconds make one
#: record, at their mean time (as ``track`` pairs the frames of two cameras).
TOLERANCE = 0.005

#: Records whose smoothing may wait for slack (``--out``); beyond them the oldest are written unsmoothed.
MAX_DEFERRED = 60
#: Track statuses whose pose is published (``predicted`` only within ``max_coast``).
MEASURED = (FrameStatus.SOLVED, FrameStatus.UNVERIFIED, FrameStatus.PARTIAL)
#: Messages remembered per robot to recognise a duplicate.
_SEEN = 512


@dataclass(frozen=True)
class LivePose:
    """A pose to publish: ``robot`` in ``reference``'s frame at capture time ``t``."""

    robot: str
    reference: str
    t: float
    status: FrameStatus
    estimate: Estimate
    #: The fused message's stamp in nanoseconds, exactly (``t`` is it in seconds, as a float).
    stamp_ns: int | None = None
    #: Shared by the poses of one row (one estimate, several stamps): its
    #: :func:`~mutloc.live.messages.pose_cdr_body`, made by the first :meth:`cdr` (with what it is of).
    _body: list = field(default_factory=list, compare=False, repr=False)
    #: Whether its ``/tf`` goes out too: only for a stamp newer than the robot's
    #: last one on ``/tf`` (tf2 drops a transform at a stamp it has, with a
    #: TF_REPEATED_DATA warning): a message fused after another of the same
    #: stamp (it came after the reorder window) refines the pose topic only.
    tf: bool = True

    def messages(self) -> tuple[Any, Any]:
        """``(PoseWithCovarianceStamped, TFMessage)`` as ``track --bag`` writes them,
        stamped with the fused message's own stamp."""
        from .messages import pose_messages, ros_types

        pose, tf = pose_messages(self.t, self.estimate.pose, self.estimate.covariance, self.robot, self.reference)
        if self.stamp_ns is not None:
            st = ros_types().Time(sec=self.stamp_ns // 1_000_000_000, nanosec=self.stamp_ns % 1_000_000_000)
            pose.header.stamp = st
            tf.transforms[0].header.stamp = st
        return pose, tf

    def cdr(self) -> tuple[bytes, bytes]:
        """The same two messages as CDR bytes (:func:`~mutloc.live.messages.pose_cdr`: what is published)."""
        from .messages import pose_cdr, pose_cdr_body

        ns = self.stamp_ns if self.stamp_ns is not None else int(round(self.t * 1e9))
        key = (self.estimate, self.robot, self.reference)
        if not self._body or any(a is not b for a, b in zip(self._body[0], key)):  # (a copy made with replace())
            self._body[:] = [key, pose_cdr_body(self.estimate.pose, self.estimate.covariance, self.robot,
                                                self.reference)]
        return pose_cdr(ns, None, None, self.robot, self.reference, self._body[1])

class Localizer:
    """Fuses every robot's observation messages (see the module docstring).

    ``rig``: a rig file (its bytes give the expected ``rig_id``) or a
    :class:`~mutloc.core.rig.Rig` with ``rig_id`` given; ``reference``: the
    frame of the poses (two robots: the second of the rig, as ``track``;
    more: the first); ``pixel_sigma``, ``confidence``, ``filter`` as
    ``track``'s; ``sink(row, robot)``: every row once final (what
    ``TrackOutputs.write`` takes); ``log``: an
    :class:`~mutloc.io.logs.ObservationLogWriter` of every fused record.
    Times are seconds of the robots' clock (the wall clock: stamps are
    capture times).  ``odometry``: the robots' odometry received live (a
    :class:`~mutloc.live.odometry.LiveOdometry`; its messages given with
    :meth:`receive_odometry`), fused by the team filter between records; a
    record then waits for it (see :mod:`mutloc.live.odometry`).
    """

    def __init__(self, rig: Any, *, rig_id: str | None = None, reference: str | None = None,
                 pixel_sigma: float = 1.0, confidence: float = DEFAULT_CONFIDENCE,
                 filter: FilterOptions | None = None, max_coast: float = MAX_COAST,
                 max_clock_skew: float = MAX_CLOCK_SKEW, warn_after: float = WARN_AFTER,
                 reorder: float = REORDER_WINDOW, sink: Callable[[TrackRow, str], None] | None = None,
                 log: Any = None, tolerance: float = TOLERANCE, notify: Callable[[str], None] | None = None,
                 max_lag: float = MAX_LAG, max_deferred: int = MAX_DEFERRED, odometry: Any = None,
                 clock_offsets: bool | dict[str, Any] = False) -> None:
        if rig_id is None:
            if not isinstance(rig, (str, Path)):
                raise InputError("the localizer needs the rig's rig_id (or the rig file, whose bytes give it)")
            rig_id = rig_id_of(rig)
        self.rig_id = str(rig_id)
        self.rig = expanded_rig(load_rig(rig))
        #: ``{robot: {frame_id: observation key}}``: the frame_ids each robot's nodes send (a camera's key).
        self.frame_ids = observer_frame_ids(self.rig)
        #: Every camera's observation key: each a stream of messages (one node's camera), in order.
        self.keys = self.rig.observer_keys()
        names = list(self.rig.robots)
        if len(names) < 2:
            raise InputError(f"the localizer needs two robots or more; the rig has {len(names)}")
        if reference is not None and reference not in self.rig.robots:
            raise InputError(f"unknown reference robot {reference!r} (rig has {sorted(self.rig.robots)})")
        self.max_coast = positive_number(max_coast, "max_coast")
        self.max_clock_skew = _nonnegative(max_clock_skew, "max_clock_skew")
        self.warn_after = positive_number(warn_after, "warn_after")
        self.reorder = _nonnegative(reorder, "reorder")
        self.tolerance = _nonnegative(tolerance, "tolerance")
        self.max_lag = _nonnegative(max_lag, "max_lag")
        if isinstance(max_deferred, bool) or not isinstance(max_deferred, int) or max_deferred < 0:
            raise InputError(f"max_deferred must be an integer >= 0 (records), got {max_deferred!r}")
        self.max_deferred = max_deferred
        self.names = names
        if reference is None:
            # two robots: the pose of the first in the second's frame, as ``track``; more: the first's frame
            reference = self.rig.default_pair(None, None)[1] if len(names) == 2 else names[0]
        # the published poses are the causal filter's; the smoother (a pass over the filter's past,
        # never fed back) only serves the files: not run without them
        options = filter if filter is not None else FilterOptions(smooth_lag=None if sink is not None else 0)
        #: The robots' odometry received live (:class:`mutloc.live.odometry.LiveOdometry`), or None.
        self.odometry = odometry
        if odometry is not None:
            options = replace(options, odometry={**options.odometry, **odometry.streams})
        self._record_t: float | None = None  # (the last record's time: the odometry's interval)
        self.engine: Any = TeamEngine(self.rig, reference, pixel_sigma, confidence, options, sink)
        #: The robots whose poses are published, and the frame they are in.
        self.tracked: list[str] = list(self.engine.robots)
        self.reference: str = self.engine.reference
        #: ``--clock-offsets estimate``: each robot's offset estimated in slack and its stamps corrected
        #: by it (:mod:`mutloc.live.clocks`); None: the stamps as sent.  (From the observations alone:
        #: the live odometry's stamps are not corrected by it yet.)
        self.clocks = None if not clock_offsets else LiveClocks(
            self.rig, self.reference, replace(self.engine.tracker.options, odometry={}), pixel_sigma, confidence,
            **(clock_offsets if isinstance(clock_offsets, dict) else {}))
        #: What each robot's topics brought (``counts``: robot -> :class:`RobotCounts`), what was refused
        #: naming no robot, and the lines said about it (:mod:`mutloc.live.localizer_status`).
        self.tally = Tally(names, notify)
        self.counts = self.tally.robots
        #: The observations of the last ``max_coast`` s that tie robots to the reference.
        self.ties = TieWindow(self.reference, self.max_coast)
        self.records = 0  #: records fused
        self.records_deferred = 0  #: records fused while behind (their smoothing deferred)
        self.records_unsmoothed = 0  #: records written as the causal filter gave them (see the module docstring)
        self.fused_until = -math.inf  #: capture time of the last record fused
        self.log = log
        #: The accepted messages waiting to be fused in time order (:mod:`mutloc.live.reorder`).
        self.buffer = ReorderBuffer(self.keys, self.reorder, self.tolerance, self.warn_after, odometry)
        self._held = self.buffer.held  # (the same heap)
        self._closed = False
        #: Whether the poses are withheld for the rig check (:mod:`mutloc.live.rig_gate`).
        self.rig_gate = RigGate()

    def receive(self, msg: Any, now: float, topic: str | None = None) -> str:
        """Take one ``Observations`` message arrived at ``now`` on robot
        ``topic``'s observation topic (None: trust the message's robot);
        returns what became of it: ``held``, ``duplicate``, ``late``, or
        ``refused: <why>``.  Never raises for the message's content."""
        who = topic if topic in self.counts else None
        try:
            got = observations_from_message(msg, self.names, self.frame_ids)
        except MessageError as exc:
            return self._refuse(who or _robot_of(msg, self.counts), "refused_malformed", str(exc), now)
        except Exception as exc:  # noqa: BLE001 -- anything on the topic is input: counted, never raised
            return self._refuse(who or _robot_of(msg, self.counts), "refused_malformed",
                                f"not an Observations message ({type(exc).__name__})", now)
        robot = got.robot
        if topic is not None and robot != topic:
            return self._refuse(who, "refused_malformed", f"robot {robot!r} on the topic of {topic!r}", now)
        c = self.counts[robot]
        if got.rig_id != self.rig_id:
            return self._refuse(robot, "refused_rig_id", f"rig_id {_short(got.rig_id)} is not this rig's "
                                f"({_short(self.rig_id)}): its node runs with another rig file", now)
        ns = int(msg.header.stamp.sec) * 1_000_000_000 + int(msg.header.stamp.nanosec)
        # its stamp on the reference's clock (--clock-offsets estimate: corrected by the robot's offset now)
        t, ns_ref = (got.time, ns) if self.clocks is None else self.clocks.corrected(robot, got.time, ns)
        if t > now + self.max_clock_skew:
            if self.clocks is not None:  # the estimate learns from it (else such a robot is never taken)
                try:
                    self.clocks.add(got.time, _as_logged(got.observations.check(self.rig), got.time))
                except MutlocError:
                    pass  # (malformed too: refused for its stamp all the same)
            return self._refuse(robot, "refused_clock", f"stamped {t - now:.3f} s in the future (beyond "
                                f"--max-clock-skew {self.max_clock_skew:g} s): synchronize the clocks"
                                + ("" if self.clocks is None else " (stamp corrected by its clock offset "
                                   f"{self.clocks.offset(robot) * 1000:+.1f} ms)"), now)
        try:
            obs = _as_logged(got.observations.check(self.rig), got.time)
        except MutlocError as exc:
            return self._refuse(robot, "refused_malformed", str(exc), now)
        c.received += 1
        self.tally.numbered(c, got.key, got.frame)
        key = (got.key, got.frame, ns)
        if key in c.seen:
            c.duplicates += 1
            return "duplicate"
        c.seen.add(key)
        c.order.append(key)
        if len(c.order) > _SEEN:
            c.seen.discard(c.order.popleft())
        if self.clocks is not None:
            self.clocks.add(got.time, obs)  # (as stamped: the estimate shifts it by each candidate)
            if t != got.time:
                obs = obs.with_time(t)
        c.last_stamp = t if c.last_stamp is None else max(c.last_stamp, t)
        self.buffer.saw(got.key, t)
        if t < self.fused_until:
            c.dropped_late += 1
            return "late"
        self.buffer.push(t, now, ns_ref, robot, obs, got.key)
        return "held"

    def receive_odometry(self, robot: str, msg: Any, now: float) -> str:
        """Take one message of robot ``robot``'s odometry topic (``msg`` None: bytes
        that did not decode) arrived at ``now``; returns what became of it
        (:meth:`mutloc.live.odometry.LiveOdometry.receive`), a refusal said
        once per robot and kind (then rate-limited)."""
        what, why = (self.odometry.receive(robot, msg, now) if msg is not None
                     else self.odometry.malformed(robot, now))
        if why is not None:
            self._notice((robot, "odometry", what), f"robot {robot}: refused odometry "
                         f"({what[len('refused_'):]}): {why}", now)
            return f"{what}: {why}"
        return what

    def select(self, topic: str, heads: Sequence[tuple[str, int, int] | None], now: float) -> list[int]:
        """Which of the samples taken at once from robot ``topic``'s reader to
        decode (their indices): ``heads`` is each one's ``(header.frame_id,
        stamp in ns, frame number)`` (:func:`~mutloc.live.messages.observations_peek`; None:
        unreadable so, decoded).  A sample more than ``max_lag`` behind ``now``
        with a newer sample of its camera among them is shed here, before
        it is decoded (counted as received and ``shed``; the rule of
        :meth:`poll`, applied early); the others are kept."""
        keys = self.frame_ids.get(topic)
        c = self.counts.get(topic)
        if keys is None or c is None:
            return list(range(len(heads)))
        if self.clocks is not None:
            now -= self.clocks.offset(topic)  # (its stamps' lag on the reference's clock)
        newest: dict[str, int] = {}  # camera key -> its newest stamp among them
        for h in heads:
            if h is not None and h[0] in keys:
                k = keys[h[0]]
                newest[k] = max(newest.get(k, h[1]), h[1])
                self.tally.numbered(c, k, h[2])
        keep = []
        for i, h in enumerate(heads):
            if h is not None and h[0] in keys and h[1] < newest[keys[h[0]]] and now - h[1] * 1e-9 > self.max_lag:
                c.received += 1
                c.shed += 1
                c.last_shed_at = now
            else:
                keep.append(i)
        return keep

    def malformed(self, robot: str, n: int = 1, now: float | None = None) -> None:
        """Count ``n`` samples of ``robot``'s topic that could not even be decoded (arrived at ``now``)."""
        for _ in range(max(0, n)):
            self._refuse(robot if robot in self.counts else None, "refused_malformed",
                         "bytes that do not decode as an Observations message", now)

    def unsent(self, robot: str, n: int = 1) -> None:
        """Count ``n`` messages of ``robot``'s pose that could not be published."""
        self.counts[robot].unsent += n

    def _refuse(self, robot: str | None, what: str, why: str, now: float | None = None) -> str:
        return self.tally.refuse(robot, what, why, now)

    def _notice(self, cause: tuple, line: str, now: float, once: bool = False) -> None:
        self.tally.notices.say(cause, line, now, once)

    def foreign(self, robot: str, topic: str, publisher: str, now: float) -> None:
        """Another localizer (``publisher``: how it names itself) published a pose of ``robot`` on ``topic``
        at ``now``: WARN in the diagnostics, a line to :attr:`notify` once per publisher."""
        self.tally.foreign(robot, topic, publisher, now)

    # -- records fused, poses out ------------------------------------------

    def next_due(self) -> float | None:
        """The arrival-clock time at which the oldest held message leaves the buffer at the latest."""
        return self.buffer.next_due()

    def poll(self, now: float, clock: Callable[[], float] | None = None) -> list[LivePose]:
        """Fuse the held messages that are due, oldest first; the poses to
        publish.  ``clock``: read again before each record (fusing a backlog
        takes time), else every record is taken at ``now``.  A message of a
        record more than ``max_lag`` behind the clock is shed when a newer
        message of its camera waits (see the module docstring)."""
        out: list[LivePose] = []
        while self.buffer:
            if clock is not None:
                now = clock()
            if not self.buffer.due(now):
                break
            out += self._fuse(self._shed(self.buffer.group(), now), now)
        return out

    def _shed(self, group: list[Held], now: float) -> list[Held]:
        """``group`` without the messages shed at ``now``: those more than
        ``max_lag`` behind with a newer message of their camera waiting (every
        message held is as new as the group's: a held one of the same camera is newer)."""
        keep = []
        for h in group:
            if now - h.t > self.max_lag and self.buffer.waiting(h.key) > 0:
                c = self.counts[h.robot]
                c.shed += 1
                c.last_shed_at = now
            else:
                keep.append(h)
        return keep

    def clock_work(self, clock: Callable[[], float], until: float) -> int:
        """``--clock-offsets estimate``: evaluate the pending window of observations (one tracker step at
        a time) while ``clock()`` is before ``until`` (the localizer's slack); returns the steps taken
        (0: nothing to do)."""
        return 0 if self.clocks is None else self.clocks.work(clock, until)

    def clock_pending(self) -> bool:
        """Whether a window of observations waits to be evaluated for the clock offsets."""
        return self.clocks is not None and self.clocks.pending()

    def deferred(self) -> int:
        """Records fused whose smoothing waits for slack (0 without ``--out``: no smoother)."""
        return self.engine.backlog()

    def catch_up(self, clock: Callable[[], float], until: float) -> int:
        """Smooth deferred records, oldest first, while ``clock()`` is before
        ``until`` (the localizer's slack: nothing due to fuse); returns how
        many were made final."""
        done = 0
        while self.engine.backlog() > 0 and clock() < until:
            n = self.engine.smooth(1)
            if n == 0:
                break  # (held back by a track not yet confirmed: later)
            done += n
        return done

    def feed(self, msg: Any, now: float, topic: str | None = None) -> list[LivePose]:
        """:meth:`receive` then :meth:`poll`."""
        self.receive(msg, now, topic)
        return self.poll(now)

    def flush(self) -> list[LivePose]:
        """Fuse every held message now (the input ends)."""
        out: list[LivePose] = []
        while self.buffer:
            out += self._fuse(self.buffer.group(), None)
        return out

    def _fuse(self, group: list[Held], now: float | None) -> list[LivePose]:
        """Fuse one record (``now``: the clock, None at the end of the input: never behind)."""
        late = [h for h in group if h.t < self.fused_until]  # (let through too early for them)
        for h in late:
            self.counts[h.robot].dropped_late += 1
        group = [h for h in group if h not in late]
        if not group:
            return []
        if len(group) == 1:
            t, obs = group[0].t, group[0].observations
        else:
            t = sum(h.t for h in group) / len(group)
            obs = ObservationSet.concatenate([h.observations for h in group]).with_time(t)  # one record, one time
        behind = now is not None and now - t > self.max_lag
        if self.odometry is not None:
            self.odometry.fused(self._record_t, t)
        check = self.engine.tracker.rig_check
        tests = check.records
        try:
            rows = self.engine.step(t, obs, smooth=not behind)
        except (MutlocError, ArithmeticError, ValueError):
            # Input the checks let through and the tracker cannot take: refused, never a stop.
            for h in group:
                self.counts[h.robot].refused_malformed += 1
            return []
        self._record_t = t
        if self.log is not None:
            self.log.write(t, obs)
        self.fused_until = max(h.t for h in group)
        self.records += 1
        if self.rig_gate.update(t, check.last, tested=check.records > tests):
            self._notice(("rig",), self.rig_gate.flag[1].words(), t, once=True)
        self.records_deferred += behind
        over = self.engine.backlog() - self.max_deferred
        if over > 0:  # (the smoother too far behind: the oldest deferred written as the filter gave them)
            self.records_unsmoothed += self.engine.smooth(over, smooth=False)
        stamps = list({h.ns: h for h in sorted(group, key=lambda h: h.ns)}.values())  # one message per stamp
        involved: set[str] = set()
        owner = self.rig.owner
        for h in group:
            self.counts[h.robot].fused += 1
            involved.update(self.engine.involved(h.robot, h.observations))
            self.ties.add(h.t, h.robot, h.key or h.robot,
                          [(m, owner(m)) for m in set(h.observations.marker) if m is not None])
        self.ties.forget_before(t)
        counts = self.ties.counts(t)  # (once per record: every robot's ties below)
        tied = self.ties.tied(t, counts)
        out: list[LivePose] = []
        waited = False  # (a pose held back by the wait for the rig check alone)
        for robot, row in rows.items():
            rc = self.counts[robot]
            rc.status = str(row.status)
            rc.ties = self.ties.ties_of(robot, t, counts)
            if robot in tied:
                rc.tied, rc.untied_since = True, None
            elif rc.tied or rc.untied_since is None:
                rc.tied, rc.untied_since = False, row.t
            e = row.estimate
            if e is None or robot not in involved:
                continue
            if row.status in MEASURED:
                rc.last_measured = row.t
            elif row.status != FrameStatus.PREDICTED:
                continue
            if robot not in tied:
                # the observations of the last max_coast s do not fix it (any more, or yet): not published
                rc.untied += 1
                continue
            if self.rig_gate.withholding:
                # the rig not tested yet, or the records keep disagreeing with it: its poses may be confident and wrong
                if self.rig_gate.waiting:
                    rc.rig_waiting += 1
                    waited = True
                else:
                    rc.rig_withheld += 1
                continue
            # one pose per message fused, stamped with its capture time (messages of one stamp: one pose)
            body: list = []  # (their bytes but the stamp: made once)
            for h in stamps:
                rc.poses += 1
                tf = rc.last_tf_ns is None or h.ns > rc.last_tf_ns
                if tf:
                    rc.last_tf_ns = h.ns
                out.append(LivePose(robot, self.reference, h.t, row.status, e, h.ns, body, tf=tf))
        if waited and self.rig_gate.held_back(t):
            self._notice(("rig", "not running"), f"the rig check got no test in {self.rig_gate.untested_limit} "
                         "records in a row: poses are published with each record's own gate as the only test "
                         "of the rig", t, once=True)
        return out

    def finish(self) -> list[LivePose]:
        """The run ends: every held message fused, every row made final (to ``sink``); the last poses."""
        if self._closed:
            return []
        out = self.flush()
        self.engine.finish()
        if self.clocks is not None:
            self.clocks.work()  # (the window collected last: one window's work at most)
        self._closed = True
        return out

    def warm_up(self) -> None:
        """Load the compiled kernels before the first message (:func:`mutloc.live.team_engine.warm_up`)."""
        warm_up(self.rig, self.names, self.engine.reference)

    # -- diagnostics ----------------------------------------------------------

    @property
    def notify(self) -> Callable[[str], None] | None:
        """Where a line saying what is wrong goes (the CLI: stderr); each cause once, then rate-limited."""
        return self.tally.notices.notify

    @property
    def unattributed(self) -> int:
        """Refused messages that named no robot of the rig."""
        return self.tally.unattributed

    @property
    def rig_flag(self) -> tuple[float, Any] | None:
        """The last record whose rig check window disagreed: (its capture time, the test), else None."""
        return self.rig_gate.flag

    @property
    def rig_withheld(self) -> float | None:
        """Since when the poses are withheld because the records keep disagreeing with the rig (None: not)."""
        return self.rig_gate.withheld

    def level(self, robot: str, now: float) -> int:
        """OK, WARN (last observation older than ``warn_after``) or STALE (older than ``max_coast``, or none)."""
        return level(self.counts[robot], now, self.warn_after, self.max_coast)

    def diagnostics(self, now: float) -> list[RobotStatus]:
        """One :class:`~mutloc.live.messages.RobotStatus` per robot of the rig, in rig order
        (:mod:`mutloc.live.localizer_status`)."""
        return robot_statuses(self, now)

    def summary(self) -> str:
        """``612 records fused; 598 poses published; refused 3, late 0, duplicates 1, shed 0``."""
        return summary(self)



def _short(rig_id: str) -> str:
    """A rig_id as people compare them (at most its first 16 characters: all of a SPEC rig_id)."""
    rig_id = str(rig_id)
    return rig_id if len(rig_id) <= 20 else rig_id[:16] + "..."


def _robot_of(msg: Any, counts: dict) -> str | None:
    robot = getattr(msg, "robot", None)
    return robot if isinstance(robot, str) and robot in counts else None


def _as_logged(obs: ObservationSet, t: float) -> ObservationSet:
    """The record as an observation log holds it (SPEC "Observation logs":
    each observer's best candidate per marker; an observer's unnamed
    detections only when it named none): what the localizer fuses is what
    replaying its log fuses."""
    if all(m is not None for m in obs.marker) and len(set(zip(obs.observer, obs.marker))) == len(obs):
        # One entry per named marker: the log's form already (ObservationSet.from_dict builds the same).
        return ObservationSet.trusted(obs.observer, obs.marker, obs.uv, time=t)
    best = obs.best()
    keep = [i for i, (o, m) in enumerate(zip(best.observer, best.marker))
            if m is not None or all(n is None for p, n in zip(best.observer, best.marker) if p == o)]
    if len(keep) < len(best):
        best = best.take(keep)
    return ObservationSet.from_dict(best.to_dict(), time=t)


def _nonnegative(x: Any, what: str) -> float:
    if isinstance(x, bool) or not isinstance(x, (int, float)) or not (math.isfinite(x) and x >= 0):
        raise InputError(f"{what} must be a number of seconds >= 0, got {x!r}")
    return float(x)


# -- on the wire ----------------------------------------------------------------


@dataclass
class LocalizerRun:
    """What :func:`run_localizer` did: the localizer (its counts) and the files written."""

    localizer: Localizer
    paths: list[Path]
    interrupted: bool = False

    def summary(self) -> str:
        """The localizer's :meth:`~Localizer.summary` and the files written (those that exist: the
        trajectory files are opened with their first row)."""
        written = [str(p) for p in self.paths if p.exists()]
        return self.localizer.summary() + (f"; wrote {', '.join(written)}" if written else "; no files written")


def run_localizer(rig: str | Path, *, reference: str | None = None, domain: int = 0, out: str | Path | None = None,
                  max_coast: float = MAX_COAST, max_clock_skew: float = MAX_CLOCK_SKEW,
                  reorder: float = REORDER_WINDOW, tolerance: float = TOLERANCE, max_lag: float = MAX_LAG,
                  pixel_sigma: float = 1.0,
                  confidence: float = DEFAULT_CONFIDENCE, loopback: bool = False, duration: float | None = None,
                  ready: Callable[[Localizer], None] | None = None, clock: Callable[[], float] = time.time,
                  notify: Callable[[str], None] | None = None, odometry: dict | None = None,
                  odometry_noise: Any = None, clock_offsets: bool = False) -> LocalizerRun:
    """Run the localizer on DDS domain ``domain`` until ``duration`` seconds
    passed (None: until Ctrl-C, which ends it like the end of ``duration``
    and is raised on after the files are complete: ``KeyboardInterrupt`` with
    the run as its argument).  Subscribes to ``/mutloc/NAME/observations`` of
    every robot of the rig; publishes ``/mutloc/NAME_in_REF``, ``/tf`` and
    ``/diagnostics`` (every :data:`DIAGNOSTICS_PERIOD` s), and, for robots with
    several cameras, each camera's pose on its robot once on ``/tf_static``
    (:func:`~mutloc.live.messages.static_transforms_message`, transient-local).  ``out``: a folder
    for the trajectory files and ``log.jsonl`` (see the module docstring).
    ``notify``: takes a line saying what is wrong (messages refused, another
    localizer on the domain), each cause once and then rate-limited (the CLI:
    stderr); the same is WARN in ``/diagnostics``.  ``odometry``: ``{robot:
    SOURCE}``, a ``nav_msgs/msg/Odometry`` topic received over DDS (a str:
    :mod:`mutloc.live.odometry`, its noise ``odometry_noise`` where the
    messages carry no covariance; with ``out`` the samples used are written to
    ``DIR/odometry_NAME.tum``) or an :class:`~mutloc.core.odometry.Odometry`
    known beforehand (a TUM file, for a replay).  ``clock_offsets``: ``--clock-offsets
    estimate`` (:mod:`mutloc.live.clocks`; with ``out``, ``OUT/clock_offsets.json`` written at the end)."""
    from .dds import Bus
    from .messages import DIAGNOSTICS_TOPIC, TF_TOPIC, diagnostics_message, observations_topic, pose_topic, ros_types

    outputs: Any = None
    log: Any = None
    load_rig(rig)  # a wrong rig refused before anything is joined or written
    if out is not None:
        from ..io import writable_path
        from ..io.logs import ObservationLogWriter
        from ..track.outputs import TrackOutputs

        out = writable_path(out, "--out", folder=True)
    bus = Bus(domain, loopback=loopback)
    run = None
    odo_writers: list = []
    try:
        if out is not None:
            log = ObservationLogWriter(Path(out) / "log.jsonl")
        live_odo, files, odo_writers = odometry_inputs(odometry, odometry_noise, out, max_clock_skew)
        odo_paths = [w.path for w in odo_writers]
        loc = Localizer(rig, reference=reference, pixel_sigma=pixel_sigma, confidence=confidence,
                        max_coast=max_coast, max_clock_skew=max_clock_skew, reorder=reorder, tolerance=tolerance,
                        max_lag=max_lag, sink=None if out is None else (lambda row, robot: outputs.write(row, robot)), log=log,
                        notify=notify, odometry=live_odo, clock_offsets=clock_offsets,
                        filter=FilterOptions(smooth_lag=None if out is not None else 0, odometry=files)
                        if files else None)
        if out is not None:
            outputs = TrackOutputs(out, loc.tracked[0] if len(loc.names) == 2 else loc.tracked, loc.reference)
        run = LocalizerRun(loc, [] if outputs is None else [*outputs.paths, log.path, *odo_paths]
                           + ([Path(out) / "clock_offsets.json"] if out is not None and loc.clocks is not None else []))
        loc.warm_up()
        serve(bus, loc, duration, ready, clock,
              (ros_types, observations_topic, pose_topic, TF_TOPIC, DIAGNOSTICS_TOPIC, diagnostics_message))
    except KeyboardInterrupt:
        if run is None:
            raise
        run.interrupted = True
    finally:
        try:
            if run is not None:
                run.localizer.finish()
                if out is not None and run.localizer.clocks is not None:
                    run.localizer.clocks.write(out)
        finally:
            for w in (outputs, log, *odo_writers):
                if w is not None:
                    w.close()
            bus.close()
    if run.interrupted:
        raise KeyboardInterrupt(run)
    return run
