"""The live localizer on the wire (the ``live`` extra): the loop
:func:`~mutloc.live.localizer.run_localizer` runs (:func:`serve`) -- a
:class:`~mutloc.live.localizer.Localizer` given what the DDS readers hold,
its poses written, ``/diagnostics`` every :data:`DIAGNOSTICS_PERIOD` s, the
smoothing and the clock offsets' work done in its slack."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any, Callable, Iterable, Sequence

from .._extras import require

__all__ = ["serve", "odometry_inputs", "take_observations", "take_odometry", "take_foreign", "DIAGNOSTICS_PERIOD",
           "FOREIGN_PERIOD", "SMOOTH_SLICE", "READER_DEPTH"]

#: Seconds between two ``/diagnostics`` messages (SPEC: at least once a second).
DIAGNOSTICS_PERIOD = 0.5
#: Seconds between two looks for poses another localizer published on this one's topics.
FOREIGN_PERIOD = 0.25
#: Seconds of smoothing done at a time when there is slack (then new messages are taken).
SMOOTH_SLICE = 0.01
#: Observation messages a robot's reader keeps until taken (a second at 100 Hz).
READER_DEPTH = 100




def odometry_inputs(odometry: dict | None, noise: Any, out: Any, max_clock_skew: float) -> tuple[Any, dict, list]:
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


def take_odometry(readers: dict, loc: Any, clock: Callable[[], float], malformed: dict) -> None:
    """Give ``loc`` what each robot's odometry reader holds (and count the samples that did not decode)."""
    for r, rd in readers.items():
        for sample in rd.take():
            loc.receive_odometry(r, sample, clock())
        for _ in range(rd.malformed - malformed[r]):
            loc.receive_odometry(r, None, clock())
        malformed[r] = rd.malformed


def take_observations(rd: Any, robot: str, loc: Any, clock: Callable[[], float]) -> None:
    """Give ``loc`` what robot ``robot``'s reader holds: taken as bytes, the samples shed
    (:meth:`~mutloc.live.localizer.Localizer.select`) never decoded; each kept one decoded and received at its own time."""
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


def take_foreign(bus: Any, loc: Any, others: dict, now: float) -> None:
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


def serve(bus: Any, loc: Any, duration: float | None, ready: Callable[[Any], None] | None,
           clock: Callable[[], float], names: Sequence[Any]) -> None:
    require("cyclonedds", "the localizer over DDS")
    from cyclonedds.core import InstanceState, ReadCondition, SampleState, ViewState, WaitSet

    ros_types, observations_topic, pose_topic, tf_topic, diag_topic, diagnostics_message = names
    from .messages import raw_sample

    T = ros_types()
    import os
    import socket

    # who publishes the poses, as other localizers see it in discovery (each names itself; see take_foreign)
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

    def publish(out: Iterable[Any]) -> None:
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
        take_odometry(odo_readers, loc, clock, odo_malformed)  # (first: the records may wait for it)
        for r, rd in readers.items():
            take_observations(rd, r, loc, clock)
            loc.malformed(r, rd.malformed - malformed[r], clock())
            malformed[r] = rd.malformed
        if now >= next_foreign:  # (four times a second: what others publish needs no hurry)
            take_foreign(bus, loc, others, now)
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
