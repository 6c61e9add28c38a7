"""``mutloc track``: two image streams in, a trajectory of T_qp out.

Every camera frame is fused at its own capture time: frames of the two
cameras within a tolerance of each other make one record, any other frame
is a record of its own camera (cameras need not be synchronized).  Every
record gets a status; a record with too few markers or a corrupt image is
reported as such and never guessed.  What was computed is kept whatever
happens later in the files.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, Callable, Iterable, Iterator, Mapping

import numpy as np
from tqdm import tqdm

from ..api import load_rig
from ..core.consistency import DEFAULT_CONFIDENCE
from ..core.observations import ObservationSet
from ..core.pose import Pose, sandwich_covariance
from ..core.rig import MarkerKind, Rig
from ..detect.base import DetectionResult
from ..errors import InputError
from ..io import writable_path
from ..io.logs import ObservationLogWriter
from ..io.trajectory import write_trajectory_csv, write_tum
from .annotate import Annotator
from .filtering import FilterOptions, PairTracker
from .frames import check_streams, detect_markers, expanded_rig, observations_of, prepare_pair
from .second_look import look_again
from .sources import Frame
from .rows import TrackRow
from .status import FrameStatus

__all__ = ["TrackRow", "Trajectory", "pair_streams", "track", "track_log", "RecordStepper", "check_streams", "frame_rate", "DEFAULT_FPS",
           "CSV_EXTRA", "ObserverDetector"]

#: Frame rate assumed when neither the caller nor the streams say.
DEFAULT_FPS = 30.0


@dataclass
class Trajectory:
    """Every frame of a track, in time order; ``T_qp`` of ``source`` in ``target``'s frame."""

    source: str
    target: str
    rows: list[TrackRow]
    fps: float | None = None
    frames: str = "camera"  # "camera": optical frames (SPEC); "base": the robots' base frames

    @property
    def solved(self) -> list[TrackRow]:
        """The rows with a pose."""
        return [r for r in self.rows if r.estimate is not None]

    def summary(self) -> str:
        """``60 frames: 52 solved, 3 unverified, 5 rejected`` (statuses in their order)."""
        counts = {st: sum(r.status == st for r in self.rows) for st in FrameStatus}
        parts = [f"{n} {st.value}" for st, n in counts.items() if n]
        return f"{len(self.rows)} frames: {', '.join(parts) or 'none'}"

    @property
    def poses(self) -> Pose:
        """A stack with every row's pose (NaN where a row has none)."""
        R = np.full((len(self.rows), 3, 3), np.nan)
        t = np.full((len(self.rows), 3), np.nan)
        for i, r in enumerate(self.rows):
            if r.estimate is not None:
                R[i], t[i] = r.estimate.R, r.estimate.t
        return Pose(R, t)

    @property
    def times(self) -> np.ndarray:
        return np.array([r.t for r in self.rows], dtype=float)

    def write_tum(self, path: str | Path) -> None:
        """TUM format: ``timestamp tx ty tz qx qy qz qw`` of the rows with a pose."""
        write_tum(path, self.times, self.poses, comment=tum_comment(self.source, self.target, self.frames))

    def in_base_frames(self, rig: Any) -> "Trajectory":
        """The same track between the robots' base frames (``base_from_camera``
        in the rig): ``T = B_q @ T_qp @ inv(B_p)`` with its covariance; the
        robots are then named ``NAME_base``."""
        to_base = BaseFrames(rig, self.source, self.target)
        return Trajectory(to_base.source, to_base.target, [to_base(r) for r in self.rows], self.fps, frames="base")

    @property
    def covariances(self) -> np.ndarray:
        """(n, 6, 6): every row's pose covariance, SPEC order (NaN where a row has none)."""
        out = np.full((len(self.rows), 6, 6), np.nan)
        for i, r in enumerate(self.rows):
            if r.estimate is not None:
                out[i] = r.estimate.covariance
        return out

    def write_ros(self, bag: str | Path | None = None, mcap: str | Path | None = None) -> None:
        """The poses with their covariances as ROS 2 messages (PoseWithCovarianceStamped and /tf):
        a rosbag2 folder ``bag`` and/or an MCAP file ``mcap`` (see :mod:`mutloc.io.ros`)."""
        from ..io.ros import write_mcap, write_ros2_bag

        args = (self.times, self.poses, self.covariances, self.source, self.target)
        if bag is not None:
            write_ros2_bag(bag, *args)
        if mcap is not None:
            write_mcap(mcap, *args)

    def write_csv(self, path: str | Path) -> None:
        """SPEC's ``trajectory.csv``: every frame with its status, pose and sigmas."""
        write_trajectory_csv(path, (csv_row(r) for r in self.rows), extra=CSV_EXTRA)


#: Columns ``trajectory.csv`` adds after the SPEC's.
CSV_EXTRA = ("reason", "t_source", "t_target", "reprojection_rms_px", "markers_used")


def csv_row(r: TrackRow) -> dict[str, Any]:
    """A row of ``trajectory.csv`` (:func:`mutloc.io.trajectory.write_trajectory_csv`'s form)."""
    e = r.estimate
    return {"t": r.t, "status": r.status, "pose": None if e is None else e.pose,
            "covariance": None if e is None else e.covariance, "reason": r.reason,
            "t_source": r.t_source, "t_target": r.t_target,
            "reprojection_rms_px": None if e is None else e.reprojection_rms_px,
            "markers_used": None if e is None else " ".join(e.markers_used)}


def tum_comment(source: str, target: str, frames: str = "camera") -> str:
    """The comment line of a track's TUM file."""
    return f"mutloc: pose of {source} in {target}'s {frames} frame (T_qp)"


class BaseFrames:
    """A row's pose (and covariance) between the robots' base frames
    (``base_from_camera`` in the rig): ``T = B_q @ T_qp @ inv(B_p)``; the
    robots are then named ``NAME_base``.  Called on a row, returns a copy."""

    def __init__(self, rig: Any, source: str, target: str) -> None:
        rig = load_rig(rig)
        B = {}
        for r in (source, target):
            B[r] = rig.robot(r).base_from_camera
            if B[r] is None:
                raise InputError(f"base frames asked for, but robot {r!r} has no base_from_camera in the rig")
        self.A, self.C = B[target], B[source].inverse()
        self.source, self.target = f"{source}_base", f"{target}_base"

    def __call__(self, row: TrackRow) -> TrackRow:
        new = replace(row)
        e = row.estimate
        if e is not None:
            A, C = self.A, self.C
            new.estimate = replace(e, source=self.source, target=self.target, pose=A @ e.pose @ C,
                                   covariance=sandwich_covariance(A, e.pose, C, e.covariance),
                                   candidates=A @ e.candidates @ C)
        return new


class _Emitter:
    """Hands each row to ``sink(row, payload)`` in input order once its
    report is final (see :meth:`PairTracker.finalize`): outputs written as
    the track runs."""

    def __init__(self, tracker: PairTracker, sink: Callable[[TrackRow, Any], None]) -> None:
        self.tracker, self.sink = tracker, sink
        self.queue: deque[tuple[TrackRow, bool, Any]] = deque()
        self.done = 0  # filtered rows handed on

    def add(self, row: TrackRow, filtered: bool, payload: Any = None) -> None:
        self.queue.append((row, filtered, payload))

    def emit(self, end: bool = False) -> None:
        final = math.inf if self.tracker.history is None else self.tracker.finalize(end)
        while self.queue:
            row, filtered, payload = self.queue[0]
            if filtered and self.done >= final:
                break
            self.queue.popleft()
            self.done += filtered
            self.sink(row, payload)


class RecordStepper:
    """Records fed one at a time to a :class:`PairTracker`, as
    :func:`track_log` feeds a log's lines (the live localizer feeds its
    messages the same way): :meth:`step` makes the record's row (its pose
    the causal filter's at once) and hands every row to ``sink(row)`` in
    input order once its report is final; :meth:`finish` when the input ends."""

    def __init__(self, tracker: PairTracker, sink: Callable[[TrackRow], None] | None = None) -> None:
        self.tracker = tracker
        self._emitter = _Emitter(tracker, lambda row, _: None if sink is None else sink(row))

    def step(self, t: float, observations: ObservationSet) -> TrackRow:
        """The row of one record at time ``t`` (not before the previous record's)."""
        row = TrackRow(t, t, t, FrameStatus.SOLVED, observations=observations)
        before = self.tracker.rows_filtered
        self.tracker.step(row)
        self._emitter.add(row, self.tracker.rows_filtered > before)
        self._emitter.emit()
        return row

    def finish(self) -> None:
        """The input ended: every row still held is final and handed on."""
        self._emitter.emit(end=True)


def pair_streams(a: Iterator[Frame], b: Iterator[Frame], tolerance: float) -> Iterator[tuple[Frame | None, Frame | None]]:
    """Merge two time-ordered streams: pairs within ``tolerance`` seconds,
    and each frame left without a partner on its own."""
    fa = next(a, None)
    fb = next(b, None)
    while fa is not None or fb is not None:
        if fa is None:
            yield None, fb
            fb = next(b, None)
        elif fb is None:
            yield fa, None
            fa = next(a, None)
        elif abs(fa.t - fb.t) <= tolerance:
            # Prefer the closest partner when the next frame of either is closer.
            na = next(a, None)
            if na is not None and abs(na.t - fb.t) < abs(fa.t - fb.t):
                yield fa, None
                fa = na
                continue
            yield fa, fb
            fa, fb = na, next(b, None)
        elif fa.t < fb.t:
            yield fa, None
            fa = next(a, None)
        else:
            yield None, fb
            fb = next(b, None)


class _Detector:
    """Per-observer detection, keeping blinking-light trackers across frames.
    ``other``: the robot (or, for a team, the robots) whose markers are looked for."""

    def __init__(self, rig: Rig, observer: str, other: str | list[str], fps: float):
        self.rig, self.observer = rig, observer
        self.others = [other] if isinstance(other, str) else list(other)
        markers = {n: m for o in self.others for n, m in rig.robot(o).markers.items()}
        self.blink = None
        lights = {n: m for n, m in markers.items() if m.kind == MarkerKind.LIGHT}
        if lights:
            from ..detect.blink import BlinkTracker

            # The observer's camera: a light's sphere images off its centre's projection.
            self.blink = BlinkTracker(lights, fps, camera=rig.robot(observer).camera)
        self.last_blink: DetectionResult | None = None

    def feed(self, frame: Frame) -> None:
        """Every frame of the stream, paired or not, drives the light tracker."""
        if self.blink is not None and frame.image is not None:
            self.last_blink = self.blink.update(frame.image, frame.t)

    def detect(self, frame: Frame) -> DetectionResult:
        res = detect_markers(self.rig, self.observer, frame.image, targets=self.others)
        if self.last_blink is not None:
            res.detections.update(self.last_blink.detections)
            res.missing = [m for m in res.missing if m not in self.last_blink.detections]
        return res


#: Public name of the per-observer detector (teams use it with several robots to look for).
ObserverDetector = _Detector
#: Public name of the emitter of final rows (teams hand it each record's rows, one per robot).
RowEmitter = _Emitter


def frame_rate(streams: Mapping[str, Any], fps: float | None) -> float | None:
    """The frame rate to use: the one given, else the streams' own (the
    slowest of them, since pairs come at the slower rate), else None."""
    if fps is not None:
        return float(fps)
    rates = [float(r) for r in (getattr(s, "fps", None) for s in streams.values()) if r]
    return min(rates) if rates else None


def track(rig: Any, streams: Mapping[str, Iterable[Frame]], source: str | None = None, target: str | None = None, *,
          tolerance: float = 0.005, pixel_sigma: float = 1.0, confidence: float = DEFAULT_CONFIDENCE,
          fps: float | None = None, annotate: str | Path | None = None,
          observations_out: str | Path | None = None, progress: bool = True, total: int | None = None,
          filter: str | FilterOptions = "cv", rerun: str | Path | None = None,
          sink: Callable[[TrackRow], None] | None = None) -> Trajectory:
    """Localize over two streams (``{robot: frames}``).

    ``sink`` is called with every row, in input order, as soon as its report
    is final (after the smoother's lag; see
    :meth:`~mutloc.track.filtering.PairTracker.finalize`): write outputs
    there to have them as the track runs (:class:`mutloc.track.outputs.TrackOutputs`).
    The annotated video and the Rerun recording are written the same way.
    On Ctrl-C (``KeyboardInterrupt``) every frame finished so far is
    reported, as if the input ended there, before the exception goes on.

    ``rerun`` writes a Rerun recording (``.rrd``: images with detections,
    the robots' frames with covariance ellipsoids, the trajectory; see
    :mod:`mutloc.io.rrd`).

    ``filter``: ``"cv"`` (default; the constant-velocity filter of SPEC
    "Filtered tracking"), ``"none"`` (every frame on its own) or
    :class:`~mutloc.track.filtering.FilterOptions`.

    The frame rate (for blinking lights and the annotated video) is ``fps``,
    else the streams' own (``stream.fps``), else 30 frames/s.
    ``observations_out`` writes every paired frame's detections as an
    observation log (JSON Lines, SPEC "Observation logs").
    """
    rig, source, target = prepare_pair(rig, streams, source, target, "stream")
    tracker = PairTracker(rig, source, target, pixel_sigma=pixel_sigma, confidence=confidence,
                          options=_options(filter))
    rate = frame_rate(streams, fps)
    dets = {source: _Detector(rig, source, target, rate or DEFAULT_FPS),
            target: _Detector(rig, target, source, rate or DEFAULT_FPS)}
    writer = Annotator(annotate, fps=rate or DEFAULT_FPS) if annotate else None
    log = ObservationLogWriter(observations_out) if observations_out else None
    viz = _rerun_writer(rerun, source, target)

    def final(row: TrackRow, images: tuple[dict, dict]) -> None:
        shown, both = images
        if viz is not None:
            _rerun_row(viz, row, {r: (img, {n: d.uv for n, d in row.detections[r].detections.items()})
                                  for r, img in shown.items() if r in row.detections})
        if writer is not None and both:
            writer.write(both[source], both[target], row, source, target)
        if sink is not None:
            sink(row)

    emitter = _Emitter(tracker, final)
    rows: list[TrackRow] = []
    checked = False
    last: dict[str, np.ndarray] = {}  # each robot's latest image (the annotated video shows both)
    pairs = pair_streams(iter(streams[source]), iter(streams[target]), tolerance)
    bar = tqdm(pairs, total=total, unit="frame", disable=not progress, desc="track")
    try:
        for fs, ft in bar:
            present = {r: f for r, f in ((source, fs), (target, ft)) if f is not None}
            for robot, fr in present.items():
                dets[robot].feed(fr)
            # Frames within the tolerance are one record; any other frame is a record of its own camera,
            # fused at its own time (cameras need not be synchronized).
            t = float(np.mean([f.t for f in present.values()]))
            row = TrackRow(t, fs.t if fs else None, ft.t if ft else None, FrameStatus.SOLVED)
            images = {r: f.image for r, f in present.items() if f.image is not None}
            last.update(images)
            if len(images) < len(present):
                # An unreadable image is reported as such, never guessed around (the other
                # camera's frame of the record is not fused either).
                row.status = FrameStatus.CORRUPT
                row.reason = "; ".join(f.status for f in present.values() if f.image is None)
            else:
                if not checked and len(last) == 2:
                    check_streams(rig, source, target, last[source], last[target])
                    checked = True
                row.detections = {r: dets[r].detect(present[r]) for r in images}
                if len(images) == 2:
                    # Partly hidden balls measured again where a verified pose puts them (see .second_look).
                    row.detections, notes = look_again(rig, images, row.detections, source, target,
                                                       pixel_sigma=pixel_sigma, confidence=confidence)
                else:
                    notes = []
                row.observations = observations_of(row.detections, row.t)
                if log is not None:
                    log.write(row.t, row.observations)
                before = tracker.rows_filtered
                tracker.step(row)
                filtered = tracker.rows_filtered > before
                if notes:
                    row.reason = "; ".join([row.reason, *notes] if row.reason else notes)
            rows.append(row)
            shown = images if (viz is not None or writer is not None) else {}
            emitter.add(row, filtered if row.observations is not None else False,
                        (shown, dict(last) if writer is not None and images and len(last) == 2 else {}))
            emitter.emit()
        emitter.emit(end=True)
    except KeyboardInterrupt:
        emitter.emit(end=True)  # every frame finished so far, reported as if the input ended here
        raise
    finally:
        bar.close()
        if writer is not None:
            writer.close()
        if log is not None:
            log.close()
        if viz is not None:
            viz.close()
    return Trajectory(source, target, rows, rate)


def track_log(rig: Any, frames: Iterable[ObservationSet | tuple[float, ObservationSet]], source: str | None = None,
              target: str | None = None, *, pixel_sigma: float = 1.0, confidence: float = DEFAULT_CONFIDENCE,
              progress: bool = True, total: int | None = None, filter: str | FilterOptions = "cv",
              rerun: str | Path | None = None, sink: Callable[[TrackRow], None] | None = None) -> Trajectory:
    """Track over an observation log: ``frames`` are ``(time, ObservationSet)``
    as :func:`mutloc.io.logs.iter_observation_log` yields them (or
    ObservationSets stamped with their time); ``filter``, ``rerun`` and
    ``sink`` (rows as they become final) as :func:`track`."""
    rig = expanded_rig(load_rig(rig))
    source, target = rig.default_pair(source, target)
    if rerun is not None:
        writable_path(rerun, "rerun")  # before the work, not after it
    tracker = PairTracker(rig, source, target, pixel_sigma=pixel_sigma, confidence=confidence,
                          options=_options(filter))
    viz = _rerun_writer(rerun, source, target)

    def final(row: TrackRow) -> None:
        if viz is not None:
            _rerun_row(viz, row)
        if sink is not None:
            sink(row)

    stepper = RecordStepper(tracker, final)
    rows: list[TrackRow] = []
    try:
        for item in tqdm(frames, total=total, unit="frame", disable=not progress, desc="track"):
            if isinstance(item, ObservationSet):
                times = item.times
                t, obs = (float(times[0]) if len(times) else (rows[-1].t if rows else 0.0)), item
            else:
                t, obs = float(item[0]), item[1]
            rows.append(stepper.step(t, obs))
        stepper.finish()
    except KeyboardInterrupt:
        stepper.finish()
        raise
    finally:
        if viz is not None:
            viz.close()
    return Trajectory(source, target, rows, None)


def _rerun_writer(path: str | Path | None, source: str, target: str) -> Any:
    if path is None:
        return None
    from ..io.rrd import RerunWriter

    return RerunWriter(path, source, target)


def _rerun_row(viz: Any, row: TrackRow, images: Mapping[str, Any] | None = None) -> None:
    e = row.estimate
    viz.frame(row.t, str(row.status), row.reason, None if e is None else e.pose, None if e is None else e.covariance,
              images)


def _options(filter: str | FilterOptions) -> FilterOptions:
    return filter if isinstance(filter, FilterOptions) else FilterOptions(kind=filter)
