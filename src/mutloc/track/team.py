"""Team tracking: one trajectory per robot, in the reference robot's frame
(SPEC "Filtered tracking": with more than two robots one
``trajectory_NAME.csv`` / ``trajectory_NAME.tum`` per robot).

One joint filter of the whole team (:class:`mutloc.core.team_filter.
TeamFilter`: every tracked robot's pose and velocity relative to the
reference, with their correlations) takes every record at its own time:
the frames of the cameras within ``tolerance`` of each other make one
record, any other frame is a record of its own camera (cameras need not be
synchronized); a log's record may hold any subset of the robots' cameras.
Per record and robot (not the reference):

- a robot not tracked starts when the record's joint solve
  (:func:`mutloc.localize_team`, in the reference's frame or in that of a
  tracked robot the record observes) places it with four or more
  observations and passes its chi-square test: it enters the filter with a
  wide prior about that pose and the record's observations of it update
  the filter (its covariance and correlations are theirs); ``solved``.
  Placed by exactly three (which fit any one bad detection exactly), or
  started from several records solved together (see below), its track
  starts tentatively: its rows are ``unverified`` (``partial`` with fewer
  than three observations) until a later record confirms it -- three or
  more observations, every one accepted by the gate, at least one of them
  not among those that started it and predicted sharply (within
  ``CONFIRM_SPREAD`` pixel sigmas: where a wrong start could have missed
  it); a record tying it to one robot by four or more that does not
  confirm it restarts it from that record's joint solve.  Every new track is
  tentative until a later record's observations of it are accepted: a
  record that contradicts it first drops it (and may start it again).
  While tentative (started on three, or bridged) a row reports what its
  record shows on its own: ``unverified`` with three or more observations;
  with fewer, nothing after a start on three (``too_few``), the filter's
  ``partial``/``predicted`` after a bridged start.  With smoothing, once
  confirmed, the tentative records within the lag before the confirming one
  are reported as the confirmed track reports them ("confirmed in
  hindsight"), going back from it while each record of three or more is
  verified by a filter run backward in time over the records after it
  (independent of it: it must predict every observation sharply, agree with
  them and with the forward prediction); the record that started the track
  is checked the same way, and unless it is verified the others report the
  backward filter's pose.
- a tracked robot whose observations the filter accepts is ``solved`` when
  the record's observations tie it to the reference on their own (a chain
  of robots each pair tied by three or more), else ``partial``;
  ``predicted`` without observations (until its predicted sigma passes the
  options' ``lost_sigma_t``/``lost_sigma_r_deg``: the track is lost);
  ``rejected`` when its observations fail the gate (the row carries the
  filter's pose, the update made without them: when a record's
  observations fail the gate, the robot whose observations left out let the
  rest pass is the one rejected; a single camera's view that nothing
  separates, its observer).  Rejections are counted per camera: after
  ``reinit_after`` records of one camera in a row inconsistent with the
  track, a record whose joint solve places the robot restarts it; after
  twice that many the track is dropped -- unless another camera's record
  solved the robot (placed it on its own, consistent with the track) since
  that camera's first rejection: then that camera is the one at odds, and
  its records of the robot keep being rejected.

With the options' ``smooth_lag`` (default as for a pair) each row's pose,
covariance and velocity are then replaced by the fixed-lag smoothed ones of
the joint state (:mod:`mutloc.core.team_smoother`) once the ``smooth_lag``
records after it have come (:meth:`TeamTracker.finalize`); statuses and
reasons are the causal filter's.

``filter="none"``: every record's joint estimate on its own.

The tracker (:class:`TeamTracker`, :mod:`mutloc.track.team_tracker`) in its
parts: a track's states and the rules that move it
(:mod:`mutloc.track.lifecycle`), the three ways a track starts
(:mod:`mutloc.track.starts`), hindsight -- confirmation reported back, undo
(:mod:`mutloc.track.hindsight`) -- and the record and its rows
(:mod:`mutloc.track.records`).  Here: the public functions and their inputs.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Iterable, Iterator, Mapping

import numpy as np
from tqdm import tqdm

from ..api import load_rig
from ..core.consistency import DEFAULT_CONFIDENCE
from ..core.observations import ObservationSet
from ..core.rig import Rig
from ..errors import ObservationError
from ..io.logs import ObservationLogWriter
from .records import join
from .team_tracker import TeamTracker
from .filtering import FilterOptions
from .frames import DEFAULT_FPS, ObserverDetector, expanded_rig, frame_rate, image_keys, observations_of
from .sources import Frame
from .status import FrameStatus
from .tag_look import look_where_tracked
from .rows import TrackRow
from .trajectory import Trajectory

__all__ = ["TeamTrajectory", "TeamTracker", "track_team", "track_team_log", "sync_streams", "team_file_names",
           "require_streams", "unused_cameras", "camera_sizes", "RowEmitter"]


def team_file_names(robot: str) -> tuple[str, str]:
    """The SPEC's per-robot file names: ``trajectory_NAME.csv``, ``trajectory_NAME.tum``."""
    return f"trajectory_{robot}.csv", f"trajectory_{robot}.tum"


@dataclass
class TeamTrajectory:
    """Every robot's track (a :class:`~mutloc.track.tracker.Trajectory` of
    ``T_ref_r``, one row per input frame) in the frame of ``reference``."""

    reference: str
    tracks: dict[str, Trajectory]
    fps: float | None = None
    #: One line each, for people: what the track found wrong beyond its rows (the rig check's hint).
    notes: list[str] = field(default_factory=list)

    @property
    def robots(self) -> list[str]:
        return list(self.tracks)

    def summary(self) -> str:
        """One line per robot: ``r1: 60 frames: 58 solved, 2 partial``."""
        return "; ".join(f"{r}: {tr.summary()}" for r, tr in self.tracks.items())

    def write(self, out: str | Path) -> list[Path]:
        """``trajectory_NAME.csv`` and ``trajectory_NAME.tum`` per robot into folder ``out``."""
        out = Path(out).expanduser()
        written = []
        for r, tr in self.tracks.items():
            csv_name, tum_name = team_file_names(r)
            tr.write_csv(out / csv_name)
            tr.write_tum(out / tum_name)
            written += [out / csv_name, out / tum_name]
        return written

    def in_base_frames(self, rig: Any) -> "TeamTrajectory":
        """Every track between the robots' base frames (``base_from_camera``
        of each robot and of the reference; see
        :meth:`~mutloc.track.tracker.Trajectory.in_base_frames`); still keyed
        by robot name (files ``trajectory_NAME.*``)."""
        return TeamTrajectory(self.reference, {r: tr.in_base_frames(rig) for r, tr in self.tracks.items()}, self.fps,
                              list(self.notes))

    def write_rerun(self, path: str | Path) -> None:
        """A Rerun recording (``.rrd``) of every robot's track in the
        reference's frame (see :mod:`mutloc.io.rrd`; poses, covariance
        ellipsoids, trajectories and statuses; no images)."""
        from ..io.rrd import RerunWriter

        with RerunWriter(path, None, self.reference) as viz:
            for r, tr in self.tracks.items():
                for row in tr.rows:
                    e = row.estimate
                    viz.frame(row.t, str(row.status), row.reason, None if e is None else e.pose,
                              None if e is None else e.covariance, robot=r)

    def write_ros(self, bag: str | Path | None = None, mcap: str | Path | None = None) -> None:
        """Every robot's poses as ROS 2 messages, one pose topic per robot
        (``/mutloc/NAME_in_REFERENCE``) and ``/tf`` with one child frame per robot."""
        from ..io.ros import write_mcap, write_ros2_bag

        tracks = [(tr.times, tr.poses, tr.covariances, tr.source, tr.target) for tr in self.tracks.values()]
        if bag is not None:
            write_ros2_bag(bag, tracks=tracks)
        if mcap is not None:
            write_mcap(mcap, tracks=tracks)


def close_all(*outputs: Any) -> None:
    """Close every output of a track that was asked for (None: it was not)."""
    for out in outputs:
        if out is not None:
            out.close()


class RowEmitter:
    """Hands each item (a record's rows, or a pair's row) to ``sink(item,
    payload)`` in input order once final (see :meth:`TeamTracker.finalize`):
    outputs written as the track runs.  ``filtered``: the item is one of the
    tracker's records (items that are not -- an unreadable frame -- go out
    in their turn)."""

    def __init__(self, tracker: "TeamTracker", sink: Callable[[Any, Any], None]) -> None:
        self.tracker, self.sink = tracker, sink
        self.queue: deque[tuple[Any, bool, Any]] = deque()
        self.done = 0  # filtered items handed on

    def add(self, item: Any, filtered: bool, payload: Any = None) -> None:
        self.queue.append((item, filtered, payload))

    def emit(self, end: bool = False, *, most: int | None = None, smooth: bool = True) -> None:
        """Hand on the items final now (``most``, ``smooth``: as :meth:`TeamTracker.finalize`'s)."""
        final = math.inf if self.tracker.history is None else self.tracker.finalize(end, most=most, smooth=smooth)
        while self.queue:
            item, filtered, payload = self.queue[0]
            if filtered and self.done >= final:
                break
            self.queue.popleft()
            self.done += filtered
            self.sink(item, payload)


# -- inputs -------------------------------------------------------------------


def sync_streams(streams: Mapping[str, Iterable[Frame]], tolerance: float) -> Iterator[dict[str, Frame]]:
    """Group time-ordered streams into frames of the team: each group holds,
    per robot, its next frame if it lies within ``tolerance`` seconds of the
    earliest pending frame (robots without one are left out of the group)."""
    its = {r: iter(s) for r, s in streams.items()}
    heads = {r: next(it, None) for r, it in its.items()}
    while any(f is not None for f in heads.values()):
        t0 = min(f.t for f in heads.values() if f is not None)
        group = {r: f for r, f in heads.items() if f is not None and f.t - t0 <= tolerance}
        for r in group:
            heads[r] = next(its[r], None)
        yield group


def _team_setup(rig: Any, reference: str | None, names: Iterable[str], what: str) -> tuple[Rig, str]:
    rig = expanded_rig(load_rig(rig))
    image_keys(rig, {n: None for n in names}, what)  # ROBOT or ROBOT/CAMERA, each a camera of the rig
    if reference is not None and (not isinstance(reference, str) or reference not in rig.robots):
        raise ObservationError(f"unknown reference robot {reference!r} (rig has {sorted(rig.robots)})")
    return rig, reference if reference is not None else next(iter(rig.robots))


def require_streams(rig: Rig, names: Iterable[str]) -> list[str]:
    """ObservationError unless every name is a camera of the rig (``ROBOT``, or ``ROBOT/CAMERA`` for a robot
    with several cameras: :func:`~mutloc.track.frames.image_keys`) and every robot has a stream.  Returns the
    cameras of robots with several that have none (unused: a robot needs one camera's stream at least)."""
    keys = image_keys(rig, {n: None for n in names}, "stream")
    missing = [r for r in rig.robots if r not in keys.values()]
    if missing:
        raise ObservationError(f"no stream for robot{'s' if len(missing) > 1 else ''} {', '.join(map(repr, missing))} "
                               "(a team track needs one stream per robot of the rig)")
    return unused_cameras(rig, keys)


def unused_cameras(rig: Rig, keys: Iterable[str]) -> list[str]:
    """The cameras (``ROBOT/CAMERA``) of the robots of ``keys`` that no key names."""
    given = {rig.observer(k) for k in keys}
    robots = {r for r, _ in given}
    return [k for k in rig.observer_keys() if rig.observer(k)[0] in robots and rig.observer(k) not in given]


def track_team_log(rig: Any, frames: Iterable[tuple[float, ObservationSet]], reference: str | None = None, *,
                   pixel_sigma: float = 1.0, confidence: float = DEFAULT_CONFIDENCE, progress: bool = True,
                   total: int | None = None, filter: str | FilterOptions = "cv",
                   sink: Callable[[TrackRow, str], None] | None = None) -> TeamTrajectory:
    """Track a team over an observation log (``(time, ObservationSet)`` per
    frame, as :func:`mutloc.io.logs.iter_observation_log` yields them);
    ``sink(row, robot)`` gets every robot's row, in input order, as soon as
    it is final (after the smoother's lag; see :meth:`TeamTracker.finalize`).
    On Ctrl-C (``KeyboardInterrupt``) every record finished so far is
    reported, as if the input ended there, before the exception goes on."""
    rig, reference = _team_setup(rig, reference, (), "log")
    tracker = TeamTracker(rig, reference, pixel_sigma=pixel_sigma, confidence=confidence, options=_options(filter))
    rows: dict[str, list[TrackRow]] = {r: [] for r in tracker.robots}

    def final(record: dict[str, TrackRow], _: Any) -> None:
        if sink is not None:
            for r, row in record.items():
                sink(row, r)

    emitter = RowEmitter(tracker, final)
    try:
        for t, obs in tqdm(frames, total=total, unit="frame", disable=not progress, desc="track team"):
            record = tracker.step(float(t), obs)
            for r, row in record.items():
                rows[r].append(row)
            emitter.add(record, True)
            emitter.emit()
        emitter.emit(end=True)
    except KeyboardInterrupt:
        emitter.emit(end=True)  # every record finished so far, reported as if the input ended here
        raise
    return _noted(TeamTrajectory(reference, {r: Trajectory(r, reference, rows[r]) for r in tracker.robots}), tracker)


def track_team(rig: Any, streams: Mapping[str, Iterable[Frame]], reference: str | None = None, *,
               tolerance: float = 0.005, pixel_sigma: float = 1.0, confidence: float = DEFAULT_CONFIDENCE,
               fps: float | None = None, observations_out: str | Path | None = None, progress: bool = True,
               total: int | None = None, filter: str | FilterOptions = "cv", annotate: str | Path | None = None,
               sink: Callable[[TrackRow, str], None] | None = None) -> TeamTrajectory:
    """Track a team from one image stream per camera (``{key: frames}``, keyed as observations are: ``ROBOT``
    for a robot with one camera, ``ROBOT/CAMERA`` for each camera of a robot with several; every robot of
    the rig needs one stream at least, a camera without one is not used).  Frames are grouped by timestamp
    (:func:`sync_streams`); each robot's image is searched for every other
    robot's markers and the group localized jointly (see the module
    docstring).  ``sink`` and Ctrl-C as :func:`track_team_log`.
    ``annotate``: an mp4 of every record as it becomes final, every robot's
    camera tiled (its latest image; the detections of those in the record)
    with one status line per robot (:func:`mutloc.track.annotate.draw_team`)."""
    rig, reference = _team_setup(rig, reference, streams, "stream")
    require_streams(rig, streams)
    tracker = TeamTracker(rig, reference, pixel_sigma=pixel_sigma, confidence=confidence, options=_options(filter))
    rate = frame_rate(streams, fps)
    robot_of = image_keys(rig, streams, "stream")  # each camera's robot
    dets = {k: ObserverDetector(rig, k, [o for o in rig.robots if o != r], rate or DEFAULT_FPS)
            for k, r in robot_of.items()}
    log = ObservationLogWriter(observations_out) if observations_out else None
    writer = None
    if annotate:
        from .annotate import Annotator

        writer = Annotator(annotate, fps=rate or DEFAULT_FPS)
    sizes: dict[str, tuple[int, int]] = {}
    last: dict[str, tuple[np.ndarray | None, float | None]] = {}  # each camera's latest image and its time

    def final(record: dict[str, TrackRow], images: dict) -> None:
        if writer is not None:
            writer.write_team(images, record, reference, camera_sizes(rig, images, sizes, list(streams)))
        if sink is not None:
            for r, row in record.items():
                sink(row, r)

    emitter = RowEmitter(tracker, final)
    rows: dict[str, list[TrackRow]] = {r: [] for r in tracker.robots}
    bar = tqdm(sync_streams(streams, tolerance), total=total, unit="frame", disable=not progress, desc="track team")
    try:
        for group in bar:
            for r, fr in group.items():
                dets[r].feed(fr)
            t = float(np.mean([f.t for f in group.values()]))
            problems: dict[str, tuple[FrameStatus, str]] = {}
            detections = {}
            for k in streams:
                fr = group.get(k)
                if fr is None:
                    continue  # a record of the other cameras: fused at its own time
                elif fr.image is None:
                    problems[robot_of[k]] = (FrameStatus.CORRUPT, join(problems.get(robot_of[k], (None, ""))[1],
                                                                        fr.status))
                else:
                    detections[k] = dets[k].detect(fr)
                    if writer is not None:
                        last[k] = (fr.image, fr.t)
            # Tags missed looked for where the track expects them (see .tag_look).
            detections, looked = look_where_tracked(rig, {r: group[r].image for r in detections}, detections,
                                                    lambda: tracker.predicted(t))
            # What the log (and a live node's message) holds: pixels, each weighed alike, so that a
            # track from its log, or a live run, gives the same poses.
            obs = observations_of(detections, t).with_sigma_scale(None) if detections else None
            if log is not None and obs is not None:
                log.write(t, obs)
            times: dict[str, float] = {}  # each robot's frame time (the mean of its cameras' in the record)
            for r in dict.fromkeys(robot_of[k] for k in group):
                times[r] = float(np.mean([f.t for k, f in group.items() if robot_of[k] == r]))
            out = tracker.step(t, obs, times, {r: p for r, p in problems.items() if r != reference})
            if reference in problems:
                for row in out.values():
                    row.reason = join(row.reason, f"reference {problems[reference][1]}")
            for r, row in out.items():
                if r not in times:
                    row.reason = join(row.reason, f"no {r} frame in this record")
                for robot, text in looked:
                    if robot == r:
                        row.reason = join(row.reason, text)
                row.detections = {o: d for o, d in detections.items()}
                rows[r].append(row)
            emitter.add(out, True, dict(last) if writer is not None else None)
            emitter.emit()
        emitter.emit(end=True)
    except KeyboardInterrupt:
        emitter.emit(end=True)  # every record finished so far, reported as if the input ended here
        raise
    finally:
        close_all(bar, writer, log)
    return _noted(TeamTrajectory(reference, {r: Trajectory(r, reference, rows[r], rate) for r in tracker.robots}, rate),
                  tracker)


def _noted(traj: TeamTrajectory, tracker: TeamTracker) -> TeamTrajectory:
    """The trajectory with the track's notes (the rig check's hint, when its window disagreed)."""
    note = tracker.rig_check.summary()
    if note:
        traj.notes.append(note)
    return traj


def camera_sizes(rig: Rig, images: Mapping[str, tuple[Any, Any]], sizes: dict[str, tuple[int, int]],
                  cameras: list[str] | None = None) -> dict[str, tuple[int, int]]:
    """Each camera's tile ``(width, height)`` in the annotated video, fixed
    with its first frame: the rig's camera size, else its first image's,
    else (no image yet) the largest known.  ``sizes`` is filled in place.
    ``cameras``: the streams' keys (default the robots, one camera each)."""
    keys = cameras if cameras is not None else list(rig.robots)
    if len(sizes) < len(keys):
        for r in keys:
            if r in sizes:
                continue
            size = rig.mount(r).camera.size
            img = images.get(r, (None, None))[0]
            if size is None and img is not None:
                size = (int(img.shape[1]), int(img.shape[0]))
            if size is not None:
                sizes[r] = (int(size[0]), int(size[1]))
        known = list(sizes.values()) or [(640, 480)]
        fill = (max(s[0] for s in known), max(s[1] for s in known))
        for r in keys:
            sizes.setdefault(r, fill)
    return {r: sizes[r] for r in keys}


def _options(filter: str | FilterOptions) -> FilterOptions:
    return filter if isinstance(filter, FilterOptions) else FilterOptions(kind=filter)
