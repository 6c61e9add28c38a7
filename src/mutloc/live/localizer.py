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
"""

from __future__ import annotations

import heapq
import math
import time
from collections import deque
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Callable, Iterable, Sequence

from .._extras import require
from ..api import Estimate, load_rig
from ..core.consistency import DEFAULT_CONFIDENCE
from ..core.observations import ObservationSet
from ..core.pose import Pose
from ..core.rig import Rig
from ..errors import InputError, MutlocError, positive_number
from ..track.filtering import FilterOptions
from ..track.frames import expanded_rig
from ..track.rows import TrackRow
from ..track.status import FrameStatus
from .messages import (ERROR, OK, STALE, WARN, MessageError, RobotStatus, observations_from_message, observer_frame_ids,
                       rig_id as rig_id_of)
from .clocks import LiveClocks
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
#: Seconds between two ``/diagnostics`` messages (SPEC: at least once a second).
DIAGNOSTICS_PERIOD = 0.5
#: Seconds a robot stays WARN after its last refused message (or another localizer's pose of it).
NOTICE_HOLD = 5.0
#: Seconds between two looks for poses another localizer published on this one's topics.
FOREIGN_PERIOD = 0.25
#: Seconds between two printed lines of one cause (robot and kind of refusal): the first is printed at once.
NOTICE_PERIOD = 10.0

#: Records whose smoothing may wait for slack (``--out``); beyond them the oldest are written unsmoothed.
MAX_DEFERRED = 60
#: Seconds of smoothing done at a time when there is slack (then new messages are taken).
SMOOTH_SLICE = 0.01

#: Observation messages a robot's reader keeps until taken (a second at 100 Hz).
READER_DEPTH = 100
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


@dataclass
class RobotCounts:
    """What one robot's observation topic brought (the diagnostics' key-values)."""

    received: int = 0
    fused: int = 0
    dropped_late: int = 0
    #: Messages not fused because a newer one of the same camera waited while the localizer was behind.
    shed: int = 0
    duplicates: int = 0
    refused_rig_id: int = 0
    refused_malformed: int = 0
    refused_clock: int = 0
    poses: int = 0
    #: Its poses (or their /tf) that DDS did not take (``write`` failed).
    unsent: int = 0
    #: Newest capture time among its messages taken (None: none yet).
    last_stamp: float | None = None
    #: Stamp (ns) of its last pose on ``/tf`` (see :attr:`LivePose.tf`).
    last_tf_ns: int | None = None
    #: Its track's status at the last record (robots whose pose is published).
    status: str = ""
    #: Time of its track's last measured row (solved, unverified or partial).
    last_measured: float | None = None
    #: Whether the observations of the last ``max_coast`` s tied it to the reference at the last record
    #: (see :mod:`mutloc.live.ties`; its pose is published only then), and since when they do not.
    tied: bool = False
    untied_since: float | None = None
    #: Distinct observations tying it to other robots within the last ``max_coast`` s, at the last record.
    ties: int = 0
    #: Its rows not published because the observations of the last ``max_coast`` s did not tie it.
    untied: int = 0
    #: Its rows not published because the records kept disagreeing with the rig (see ``Localizer.rig_withheld``).
    rig_withheld: int = 0
    #: Frame numbers of its cameras' messages that never came (skipped between two that did: frames its
    #: node dropped, or messages DDS lost, e.g. overwritten in a full reader); a node restarting (its numbers
    #: going back) is not counted.
    not_received: int = 0
    #: Arrival time of its last refused message, and why it was refused (None: none refused).
    last_refused_at: float | None = None
    last_refusal: str = ""
    #: Clock time at which a message of it was last shed (None: none shed).
    last_shed_at: float | None = None
    #: Arrival time of the last pose of it that another localizer published, and who that is.
    foreign_at: float | None = None
    foreign: str = ""
    seen: set = field(default_factory=set, repr=False)
    order: deque = field(default_factory=deque, repr=False)

    @property
    def refused(self) -> int:
        return self.refused_rig_id + self.refused_malformed + self.refused_clock


@dataclass(order=True)
class _Held:
    t: float
    seq: int
    arrival: float = field(compare=False)
    ns: int = field(compare=False)
    robot: str = field(compare=False)
    observations: ObservationSet = field(compare=False)
    #: The observing camera's key (``ROBOT`` or ``ROBOT/CAMERA``): one stream of messages, delivered in order.
    key: str = field(compare=False, default="")


class _TeamEngine:
    """The team tracker (two robots: a team of two), each record one row per robot (as ``track_team_log``)."""

    def __init__(self, rig: Rig, reference: str, pixel_sigma: float, confidence: float, options: FilterOptions,
                 sink: Callable[[TrackRow, str], None] | None) -> None:
        from ..track.team import TeamTracker
        from ..track.team import RowEmitter

        self.tracker = TeamTracker(rig, reference, pixel_sigma=pixel_sigma, confidence=confidence, options=options)
        self.robots, self.reference = list(self.tracker.robots), reference

        def final(record: dict[str, TrackRow], _: Any) -> None:
            if sink is not None:
                for r, row in record.items():
                    sink(row, r)

        # rows handed to ``sink`` once final (after the smoother's lag), as track_team_log does
        self._emitter = RowEmitter(self.tracker, final)

    def step(self, t: float, obs: ObservationSet, smooth: bool = True) -> dict[str, TrackRow]:
        """The record's rows, their poses the causal filter's (published at once).  ``smooth``: the
        smoother makes final up to two of the records it may (this one's turn and one deferred);
        False: none (deferred, see :meth:`backlog`)."""
        rows = self.tracker.step(t, obs)
        live = {r: replace(row) for r, row in rows.items()}  # the smoother may revise the rows later
        self._emitter.add(rows, True)
        if smooth or self.tracker.history is None:
            self.smooth(2)
        return live

    def backlog(self) -> int:
        """Records past the smoother's lag not yet made final: their smoothing deferred (0 without it)."""
        sm = self.tracker.history
        return 0 if sm is None else max(0, len(sm) - sm.first - sm.lag - 1)

    def smooth(self, most: int, smooth: bool = True) -> int:
        """Make final at most ``most`` records, smoothed (``smooth`` False: as the causal filter gave
        them); returns how many were."""
        sm = self.tracker.history
        if sm is None:
            self._emitter.emit()
            return 0
        first = sm.first
        self._emitter.emit(most=most, smooth=smooth)
        return sm.first - first

    def involved(self, observer: str, obs: ObservationSet) -> list[str]:
        """The robots a record is about: its observer and the robots whose markers it saw."""
        owner = self.tracker.rig.owner
        seen = {observer, *(owner(m) for m in set(obs.marker) if m is not None)}
        return [r for r in self.robots if r in seen]

    def finish(self) -> None:
        self._emitter.emit(end=True)


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
        self.engine: Any = _TeamEngine(self.rig, reference, pixel_sigma, confidence, options, sink)
        #: The robots whose poses are published, and the frame they are in.
        self.tracked: list[str] = list(self.engine.robots)
        self.reference: str = self.engine.reference
        #: ``--clock-offsets estimate``: each robot's offset estimated in slack and its stamps corrected
        #: by it (:mod:`mutloc.live.clocks`); None: the stamps as sent.  (From the observations alone:
        #: the live odometry's stamps are not corrected by it yet.)
        self.clocks = None if not clock_offsets else LiveClocks(
            self.rig, self.reference, replace(self.engine.tracker.options, odometry={}), pixel_sigma, confidence,
            **(clock_offsets if isinstance(clock_offsets, dict) else {}))
        self.counts = {r: RobotCounts() for r in names}
        #: The observations of the last ``max_coast`` s that tie robots to the reference.
        self.ties = TieWindow(self.reference, self.max_coast)
        self.unattributed = 0  #: refused messages that named no robot of the rig
        self.records = 0  #: records fused
        self.records_deferred = 0  #: records fused while behind (their smoothing deferred)
        self.records_unsmoothed = 0  #: records written as the causal filter gave them (see the module docstring)
        self.fused_until = -math.inf  #: capture time of the last record fused
        self.log = log
        self._held: list[_Held] = []
        self._waiting: dict[str, int] = {}  # camera key -> its messages held
        self._stream_stamp: dict[str, float] = {}  # newest capture time of each camera's messages
        self._seq = 0
        self._first: float | None = None  # arrival of the first message held
        self._closed = False
        #: Where a line saying what is wrong goes (the CLI: stderr); each cause once, then rate-limited.
        self.notify = notify
        self._notices: dict[tuple, list] = {}  # cause -> [time printed, refused since]
        #: The last record whose rig check window disagreed: (its capture time, the test), else None.
        self.rig_flag: tuple[float, Any] | None = None
        #: Since when the poses are withheld because the records keep disagreeing with the rig (None: not):
        #: from a window that disagrees until the windows fit no worse than their mean for a window's length.
        self.rig_withheld: float | None = None
        self._rig_fits = 0  # tests in a row, while withheld, whose window fitted no worse than its mean
        self._frame_numbers: dict[str, int] = {}  # camera key -> the last frame number of its messages

    def warm_up(self) -> None:
        """Run throwaway trackers on synthetic records (the first two robots
        2 m apart, facing each other): each camera's frames at its own time
        (a start from several records), and both cameras' frames together (a
        start from one record's joint solve), so that the compiled kernels
        are loaded before the first message rather than while messages wait
        (about a second in a new process; the joint solve's alone 90 ms).
        The chi-square quantiles' library (scipy.stats) is imported here too:
        a team's first joint solve of three robots or more needs it, and its
        import took 4 s of a loaded machine inside a record, every message
        waiting."""
        from ..core.consistency import chi2_quantile

        chi2_quantile(DEFAULT_CONFIDENCE, 6)
        a, b = self.names[0], self.names[1]
        if self.rig.robot(a).is_body or self.rig.robot(b).is_body:
            T = Pose.from_rotvec([0.0, 0.0, math.pi], [2.0, 0.0, 0.0])  # bodies (z up): a ahead of b, facing it
        else:
            T = Pose.from_rotvec([0.0, math.pi, 0.0], [0.0, 0.0, 2.0])  # T_ba: a in front of b, facing it
        seen = {}
        for observer, other, to_obs in ((a, b, T.inverse()), (b, a, T)):
            robot, markers = self.rig.robot(other), list(self.rig.robot(other).markers)
            # the observer's camera that looks most towards the other robot
            cam, mount = max(self.rig.robot(observer).mounts.items(),
                             key=lambda cm: float(cm[1].pose.R[:, 2] @ to_obs.t))
            X = mount.pose.inverse().apply(to_obs.apply(robot.marker_positions(markers)))
            key = self.rig.robot(observer).observer_key(cam)
            try:
                uv = mount.camera.project(X)
                seen[observer] = ObservationSet([key] * len(markers), markers, uv)
            except (MutlocError, ValueError, FloatingPointError):
                return  # a rig this pose does not suit: the first messages pay instead
        both = ObservationSet.concatenate([seen[a], seen[b]])
        for first in (False, True):
            engine = _TeamEngine(self.rig, self.engine.reference, 1.0, DEFAULT_CONFIDENCE, FilterOptions(), None)
            try:
                if first:
                    engine.step(-1 / 60, both.with_time(-1 / 60))
                for k in range(12):
                    observer = (a, b)[k % 2]
                    engine.step(k / 60, ObservationSet.from_dict(seen[observer].to_dict(), time=k / 60))
                engine.step(0.25, both.with_time(0.25))
                engine.finish()
            except (MutlocError, ValueError, FloatingPointError):
                pass  # a rig this pose does not suit: the first messages pay instead

    # -- messages in ----------------------------------------------------------

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
        self._numbered(c, got.key, got.frame)
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
        self._stream_stamp[got.key] = max(self._stream_stamp.get(got.key, -math.inf), t)
        if t < self.fused_until:
            c.dropped_late += 1
            return "late"
        self._seq += 1
        if self._first is None:
            self._first = now
        heapq.heappush(self._held, _Held(t, self._seq, now, ns_ref, robot, obs, got.key))
        self._waiting[got.key] = self._waiting.get(got.key, 0) + 1
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
                self._numbered(c, k, h[2])
        keep = []
        for i, h in enumerate(heads):
            if h is not None and h[0] in keys and h[1] < newest[keys[h[0]]] and now - h[1] * 1e-9 > self.max_lag:
                c.received += 1
                c.shed += 1
                c.last_shed_at = now
            else:
                keep.append(i)
        return keep

    def _numbered(self, c: "RobotCounts", key: str, frame: int) -> None:
        """Camera ``key`` (of the robot counted by ``c``) sent frame number ``frame``: the numbers skipped since
        its last one are counted as not received (seen again, or going back -- a node restarted: not counted)."""
        last = self._frame_numbers.get(key)
        if last is not None and frame > last + 1:
            c.not_received += frame - last - 1
        self._frame_numbers[key] = frame

    def malformed(self, robot: str, n: int = 1, now: float | None = None) -> None:
        """Count ``n`` samples of ``robot``'s topic that could not even be decoded (arrived at ``now``)."""
        for _ in range(max(0, n)):
            self._refuse(robot if robot in self.counts else None, "refused_malformed",
                         "bytes that do not decode as an Observations message", now)

    def unsent(self, robot: str, n: int = 1) -> None:
        """Count ``n`` messages of ``robot``'s pose that could not be published."""
        self.counts[robot].unsent += n

    def _refuse(self, robot: str | None, what: str, why: str, now: float | None = None) -> str:
        why = " ".join(why.split())
        if robot is None:
            self.unattributed += 1
        else:
            c = self.counts[robot]
            c.received += 1
            setattr(c, what, getattr(c, what) + 1)
            if now is not None:
                c.last_refused_at, c.last_refusal = now, why
        if now is not None:
            self._notice((robot, what), f"{'robot ' + robot if robot else 'a message naming no robot of the rig'}: "
                         f"refused observations ({what[len('refused_'):]}): {why}", now)
        return "refused: " + why

    def _notice(self, cause: tuple, line: str, now: float, once: bool = False) -> None:
        """Print ``line`` (to :attr:`notify`) the first time of ``cause``, then at most every
        :data:`NOTICE_PERIOD` s with how many more there were (``once``: only the first time)."""
        state = self._notices.get(cause)
        if state is None:
            self._notices[cause] = [now, 0]
            if self.notify is not None:
                self.notify(line)
            return
        state[1] += 1
        if not once and now - state[0] >= NOTICE_PERIOD:
            if self.notify is not None:
                self.notify(f"{line} ({state[1]} more in the last {now - state[0]:.0f} s)")
            state[:] = [now, 0]

    def foreign(self, robot: str, topic: str, publisher: str, now: float) -> None:
        """Another localizer (``publisher``: how it names itself) published a pose of ``robot`` on ``topic``
        at ``now``: WARN in the diagnostics, a line to :attr:`notify` once per publisher."""
        c = self.counts[robot]
        c.foreign_at, c.foreign = now, f"{topic} by {publisher}"
        self._notice(("foreign", publisher), f"another localizer publishes on this domain: {c.foreign} (two "
                     "localizers double every pose: stop one, or give each its own --domain)", now, once=True)

    # -- records fused, poses out ------------------------------------------

    def _due(self, h: _Held, now: float) -> bool:
        if self.odometry is not None and not self.odometry.ready(h.t, h.arrival, now):
            return False  # (waits for the robots' odometry to pass its stamp, a while at most)
        if now >= h.arrival + self.reorder:  # (the same sum as next_due: no rounding between them)
            return True
        for key in self.keys:  # each camera's messages (one node's) come in order
            if key == h.key:
                continue
            last = self._stream_stamp.get(key)
            if last is None:
                if now - self._first > self.warn_after:
                    continue  # a camera not heard since the start is not waited for
                return False
            if now - last <= self.warn_after and last < h.t:
                return False  # (a camera gone quiet is not waited for)
        return True

    def next_due(self) -> float | None:
        """The arrival-clock time at which the oldest held message leaves the buffer at the latest."""
        if not self._held:
            return None
        due = self._held[0].arrival + self.reorder
        if self.odometry is not None:
            from .odometry import ODOMETRY_WAIT

            due = max(due, self._held[0].arrival + ODOMETRY_WAIT)
        return due

    def poll(self, now: float, clock: Callable[[], float] | None = None) -> list[LivePose]:
        """Fuse the held messages that are due, oldest first; the poses to
        publish.  ``clock``: read again before each record (fusing a backlog
        takes time), else every record is taken at ``now``.  A message of a
        record more than ``max_lag`` behind the clock is shed when a newer
        message of its camera waits (see the module docstring)."""
        out: list[LivePose] = []
        while self._held:
            if clock is not None:
                now = clock()
            if not self._due(self._held[0], now):
                break
            out += self._fuse(self._shed(self._group(), now), now)
        return out

    def _shed(self, group: list[_Held], now: float) -> list[_Held]:
        """``group`` without the messages shed at ``now``: those more than
        ``max_lag`` behind with a newer message of their camera waiting (every
        message held is as new as the group's: a held one of the same camera is newer)."""
        keep = []
        for h in group:
            if now - h.t > self.max_lag and self._waiting.get(h.key, 0) > 0:
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
        while self._held:
            out += self._fuse(self._group(), None)
        return out

    def _group(self) -> list[_Held]:
        """The oldest held message and the held messages of other cameras
        stamped within ``tolerance`` of it: one record."""
        group = [heapq.heappop(self._held)]
        while (self._held and self._held[0].t - group[0].t <= self.tolerance
               and self._held[0].key not in {h.key for h in group}):
            group.append(heapq.heappop(self._held))
        for h in group:
            self._waiting[h.key] -= 1
        return group

    def _fuse(self, group: list[_Held], now: float | None) -> list[LivePose]:
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
        self._rig_said(t)
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
        out = []
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
            if self.rig_withheld is not None:
                # the records keep disagreeing with the rig: its poses would be confident and wrong
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

    # -- diagnostics ----------------------------------------------------------

    def _rig_said(self, t: float) -> None:
        """After the record at ``t``: if the rig check's window disagrees, remember it and say the hint once."""
        test = self.engine.tracker.rig_check.last
        if test is not None and test.disagrees:
            self.rig_flag = (t, test)
            self._notice(("rig",), test.words(), t, once=True)
            if self.rig_withheld is None:
                self.rig_withheld = t
            self._rig_fits = 0
        elif self.rig_withheld is not None and test is not None and test.full:
            # published again once the window has fitted no worse than a right rig's mean (chi2 <= dof) for a
            # whole window's worth of tests in a row (a right rig's false alarm passes; a wrong rig's windows
            # dip below that now and then, not for long)
            self._rig_fits = self._rig_fits + 1 if test.chi2 <= test.dof else 0
            if self._rig_fits >= test.records:
                self.rig_withheld = None

    def level(self, robot: str, now: float) -> int:
        """OK, WARN (last observation older than ``warn_after``) or STALE (older than ``max_coast``, or none)."""
        c = self.counts[robot]
        if c.last_stamp is None:
            return STALE
        age = now - c.last_stamp
        return OK if age <= self.warn_after else WARN if age <= self.max_coast else STALE

    def diagnostics(self, now: float) -> list[RobotStatus]:
        """One :class:`~mutloc.live.messages.RobotStatus` per robot of the rig, in rig order."""
        out = []
        for r in self.names:
            c = self.counts[r]
            level = self.level(r, now)
            age = None if c.last_stamp is None else now - c.last_stamp
            track = "reference" if r == self.reference else (c.status or "none")
            if age is None:
                message = "no observations received"
            elif level == OK:
                message = f"observations {age:.2f} s old" + ("" if r == self.reference else f"; track {track}")
            elif level == WARN:
                message = f"no observations for {age:.2f} s"
            else:
                message = f"dropped: no observations for {age:.2f} s"
            if level == OK and r != self.reference and not c.tied and c.untied_since is not None:
                # observations come, but too few of them (over the last max_coast s) to fix its pose
                level = STALE
                message = (f"not published: tied by {c.ties} distinct observation(s) in the last {self.max_coast:g} s "
                           f"(three fix a pose), for {max(0.0, now - c.untied_since):.2f} s")
            if level == OK and r != self.reference and self.rig_withheld is not None and self.rig_flag is not None:
                level = ERROR
                message = (f"not published since {max(0.0, now - self.rig_withheld):.2f} s ago: "
                           + self.rig_flag[1].words())
            said = []
            if c.last_refused_at is not None and now - c.last_refused_at <= NOTICE_HOLD:
                said.append(f"refused {c.refused} observations: {c.last_refusal}")
            if c.last_shed_at is not None and now - c.last_shed_at <= NOTICE_HOLD:
                said.append(f"falling behind: shed {c.shed} of {c.received}")
            if c.foreign_at is not None and now - c.foreign_at <= NOTICE_HOLD:
                said.append(f"another localizer publishes on this domain: {c.foreign}")
            if (self.rig_flag is not None and now - self.rig_flag[0] <= NOTICE_HOLD
                    and not message.startswith("not published since")):
                said.append(self.rig_flag[1].words())
            if self.odometry is not None:
                said += self.odometry.said(r, now, NOTICE_HOLD)
            if said:
                # (none received: what was refused is the news; a robot not stale is WARN)
                message = "; ".join(said if age is None else [message, *said])
                level = WARN if age is None or level == OK else level
            values = {"status": track, "age_s": "none" if age is None else f"{age:.3f}", "received": c.received,
                      "fused": c.fused, "dropped_late": c.dropped_late, "duplicates": c.duplicates, "shed": c.shed,
                      "refused": c.refused, "refused_rig_id": c.refused_rig_id,
                      "refused_malformed": c.refused_malformed, "refused_clock": c.refused_clock,
                      "poses_published": c.poses, "poses_unsent": c.unsent, "ties": c.ties,
                      "untied_not_published": c.untied, "rig_withheld": c.rig_withheld,
                      "not_received": c.not_received}
            if self.odometry is not None:
                values.update(self.odometry.values(r, now))
            if self.clocks is not None:
                values.update(self.clocks.values(r))
            rig_test = self.engine.tracker.rig_check.last
            if rig_test is not None:
                values.update(rig_chi2=f"{rig_test.chi2:.1f}", rig_dof=rig_test.dof,
                              rig_threshold=f"{rig_test.threshold:.1f}")
            out.append(RobotStatus(r, level, message, values))
        return out

    def summary(self) -> str:
        """``612 records fused; 598 poses published; refused 3, late 0, duplicates 1, shed 0``."""
        cs = self.counts.values()
        refused = sum(c.refused for c in cs) + self.unattributed
        kinds = [f"{what} {n}" for what, n in (
            ("rig_id", sum(c.refused_rig_id for c in cs)), ("malformed", sum(c.refused_malformed for c in cs)
                                                            + self.unattributed),
            ("clock", sum(c.refused_clock for c in cs))) if n]
        return (f"{self.records} records fused; {sum(c.poses for c in cs)} poses published; refused {refused}"
                + (f" ({', '.join(kinds)})" if kinds else "")
                + f", late {sum(c.dropped_late for c in cs)}, duplicates {sum(c.duplicates for c in cs)}"
                + f", shed {sum(c.shed for c in cs)}, not received {sum(c.not_received for c in cs)}"
                + (f"; {self.records_unsmoothed} record{'s' if self.records_unsmoothed != 1 else ''} written "
                   "unsmoothed (behind)" if self.records_unsmoothed else "")
                + (f"; {self.odometry.summary()}" if self.odometry is not None else "")
                + ("" if self.clocks is None else "; " + self.clocks.summary()))


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
        live_odo, files, odo_writers = _odometry_inputs(odometry, odometry_noise, out, max_clock_skew)
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
        _serve(bus, loc, duration, ready, clock,
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


def _odometry_inputs(odometry: dict | None, noise: Any, out: Any, max_clock_skew: float) -> tuple[Any, dict, list]:
    """``(LiveOdometry or None, {robot: Odometry known beforehand}, the TUM files' writers)`` of ``odometry``."""
    from ..core.odometry import Odometry

    files = {r: s for r, s in (odometry or {}).items() if isinstance(s, Odometry)}
    topics = {r: s for r, s in (odometry or {}).items() if isinstance(s, str)}
    writers: list = []
    if not topics:
        return None, files, writers
    from ..io.streaming import LineFile
    from .odometry import LiveOdometry

    def tum(robot: str) -> Any:
        if out is None:
            return None
        w = LineFile(Path(out) / f"odometry_{robot}.tum",
                     f"# timestamp tx ty tz qx qy qz qw  (the odometry of {robot} the localizer used, from "
                     f"{topics[robot]}: replay with track --odometry {robot}=THIS_FILE)\n")
        writers.append(w)
        return w

    return LiveOdometry(topics, noise=noise, tum=tum, max_clock_skew=max_clock_skew), files, writers


def _take_odometry(readers: dict, loc: Localizer, clock: Callable[[], float], malformed: dict) -> None:
    """Give ``loc`` what each robot's odometry reader holds (and count the samples that did not decode)."""
    for r, rd in readers.items():
        for sample in rd.take():
            loc.receive_odometry(r, sample, clock())
        for _ in range(rd.malformed - malformed[r]):
            loc.receive_odometry(r, None, clock())
        malformed[r] = rd.malformed


def _take(rd: Any, robot: str, loc: Localizer, clock: Callable[[], float]) -> None:
    """Give ``loc`` what robot ``robot``'s reader holds: taken as bytes, the samples shed
    (:meth:`Localizer.select`) never decoded; each kept one decoded and received at its own time."""
    from .messages import observations_peek

    if not rd.raw:  # (a binding that decodes as it takes)
        for sample in rd.take():
            loc.receive(sample, clock(), robot)
        return
    got = rd.take_bytes()
    if not got:
        return
    for i in loc.select(robot, [observations_peek(data) for data, _ in got], clock()):
        sample = rd.decode(*got[i])
        if sample is not None:
            loc.receive(sample, clock(), robot)  # (its own arrival: taking many may take a while)


def _foreign(bus: Any, loc: Localizer, others: dict, now: float) -> None:
    """Tell ``loc`` of the poses someone else published on its topics (``others``: topic -> (robot, reader
    of the others' samples)): on a pose topic any, on ``/tf`` a transform of a tracked robot in the
    reference's frame (other nodes' transforms are /tf's everyday traffic)."""
    for topic, (robot, rd) in others.items():
        for sample in rd.take(64):  # (keep-last 10: what is left is older)
            if robot is not None:
                loc.foreign(robot, topic, bus.publisher_name(rd, sample), now)
                continue
            for tr in getattr(sample, "transforms", ()):
                child, parent = tr.child_frame_id.strip("/"), tr.header.frame_id.strip("/")
                if child in loc.tracked and parent == loc.reference:
                    loc.foreign(child, f"{topic} ({child} in {parent})", bus.publisher_name(rd, sample), now)


def _serve(bus: Any, loc: Localizer, duration: float | None, ready: Callable[[Localizer], None] | None,
           clock: Callable[[], float], names: Sequence[Any]) -> None:
    require("cyclonedds", "the localizer over DDS")
    from cyclonedds.core import InstanceState, ReadCondition, SampleState, ViewState, WaitSet

    ros_types, observations_topic, pose_topic, tf_topic, diag_topic, diagnostics_message = names
    from .messages import raw_sample

    T = ros_types()
    import os
    import socket

    # who publishes the poses, as other localizers see it in discovery (each names itself; see _foreign)
    me = f"mutloc localizer pid {os.getpid()} on {socket.gethostname()} (rig_id {loc.rig_id})".encode()
    # A second of messages kept per robot (ROS 2's default keeps 10) until the loop takes them.
    readers = {r: bus.reader(observations_topic(r), T.Observations, depth=READER_DEPTH) for r in loc.names}
    poses = {r: bus.writer(pose_topic(r, loc.reference), T.PoseWithCovarianceStamped, userdata=me)
             for r in loc.tracked}
    tf = bus.writer(tf_topic, T.TFMessage, userdata=me)
    # what others publish where this one does: another localizer's poses
    others = {pose_topic(r, loc.reference): (r, bus.reader(pose_topic(r, loc.reference), T.PoseWithCovarianceStamped,
                                                            others_only=True)) for r in loc.tracked}
    others[tf_topic] = (None, bus.reader(tf_topic, T.TFMessage, others_only=True))
    diag = bus.writer(diag_topic, T.DiagnosticArray)
    from .messages import TF_STATIC_TOPIC, static_transforms_message

    mounts = static_transforms_message(loc.rig, clock())
    static = None
    if mounts.transforms:
        # each camera's pose on its robot, once: transient-local (tf2's static QoS), so late joiners get it too
        static = bus.static_writer(TF_STATIC_TOPIC, T.TFMessage)
        static.write(mounts)
    from cyclonedds.core import DDSException
    waitset = WaitSet(bus.participant)
    mask = SampleState.Any | ViewState.Any | InstanceState.Any
    conditions = [ReadCondition(rd.native, mask) for rd in readers.values()]
    odo_readers = {} if loc.odometry is None else {
        r: bus.reader(topic, T.Odometry, depth=READER_DEPTH) for r, topic in loc.odometry.topics.items()}
    odo_malformed = {r: 0 for r in odo_readers}
    conditions += [ReadCondition(rd.native, mask) for rd in odo_readers.values()]
    for cond in conditions:
        waitset.attach(cond)
    malformed = {r: 0 for r in readers}
    start = clock()
    end = math.inf if duration is None else start + duration
    next_diag = next_foreign = start
    if ready is not None:
        ready(loc)

    def publish(out: Iterable[LivePose]) -> None:
        for p in out:
            pm, tfm = p.cdr()
            for w, sample in ((poses[p.robot], raw_sample(T.PoseWithCovarianceStamped, pm)),
                              *(((tf, raw_sample(T.TFMessage, tfm)),) if p.tf else ())):
                try:
                    w.write(sample)
                except DDSException:  # (DDS refused it or timed out: counted, the loop goes on)
                    loc.unsent(p.robot)

    def say(now: float) -> None:
        try:
            diag.write(diagnostics_message(now, loc.diagnostics(now)))
        except DDSException:
            pass  # (the next one says the same, half a second later)

    while True:
        now = clock()
        if now >= end:
            break
        due = loc.next_due()
        wake = min(end, next_diag, due if due is not None else math.inf, now + 0.1)
        if loc.deferred() or loc.clock_pending():
            wake = now  # (smoothing or clock offsets to do: only look for messages)
        waitset.wait(max(0, int((wake - now) * 1e9)))
        now = clock()
        _take_odometry(odo_readers, loc, clock, odo_malformed)  # (first: the records may wait for it)
        for r, rd in readers.items():
            _take(rd, r, loc, clock)
            loc.malformed(r, rd.malformed - malformed[r], clock())
            malformed[r] = rd.malformed
        if now >= next_foreign:  # (four times a second: what others publish needs no hurry)
            _foreign(bus, loc, others, now)
            next_foreign = now + FOREIGN_PERIOD
        now = clock()
        publish(loc.poll(now, clock))
        if loc.deferred():  # slack: some of the smoothing deferred while behind, then new messages again
            due = loc.next_due()
            loc.catch_up(clock, min(clock() + SMOOTH_SLICE, due if due is not None else math.inf))
        elif loc.clock_pending():  # slack with no smoothing waiting: the clock offsets' window, a slice of it
            due = loc.next_due()
            loc.clock_work(clock, min(clock() + SMOOTH_SLICE, due if due is not None else math.inf))
        if now >= next_diag:
            say(now)
            next_diag = max(next_diag + DIAGNOSTICS_PERIOD, now)
    publish(loc.finish())
    say(clock())
