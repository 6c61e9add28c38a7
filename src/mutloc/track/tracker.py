"""``mutloc track``: two image streams in, a trajectory of T_qp out.

A pair is a team of two: the track is :class:`~mutloc.track.team.TeamTracker`'s
(the joint filter, its trust rules and smoother) with the target robot as
the reference, each row the source robot's.
Every camera frame is fused at its own capture time: frames of the two
cameras within a tolerance of each other make one record, any other frame
is a record of its own camera (cameras need not be synchronized).  Every
record gets a status; a record with too few markers or a corrupt image is
reported as such and never guessed.  What was computed is kept whatever
happens later in the files.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Callable, Iterable, Iterator, Mapping

import numpy as np
from tqdm import tqdm

from ..api import load_rig
from ..core.consistency import DEFAULT_CONFIDENCE
from ..core.observations import ObservationSet
from ..core.rig import Rig
from ..errors import MutlocError
from ..io import writable_path
from ..io.logs import ObservationLogWriter
from .annotate import Annotator
from .filtering import FilterOptions
from .frames import DEFAULT_FPS, ObserverDetector, check_streams, expanded_rig, frame_rate, image_keys, \
    observations_of, prepare_pair
from .second_look import look_again
from .tag_look import look_where_tracked
from .sources import Frame
from .rows import TrackRow
from .status import FrameStatus
from .team import RowEmitter, TeamTracker, camera_sizes, close_all, sync_streams
from .trajectory import CSV_EXTRA, BaseFrames, Trajectory, csv_row, tum_comment

__all__ = ["TrackRow", "Trajectory", "pair_streams", "track", "track_log", "PairTrack", "check_streams",
           "frame_rate", "DEFAULT_FPS", "CSV_EXTRA", "ObserverDetector", "RowEmitter", "BaseFrames", "csv_row",
           "tum_comment"]


class PairTrack:
    """A pair's track: the team tracker of the two robots (``target`` the
    reference), each record's row the source robot's.  :meth:`step` fills a
    row from its observations (``t``, ``t_source``, ``t_target``);
    ``team``: the tracker (its :meth:`~mutloc.track.team.TeamTracker.finalize`
    says which rows are final)."""

    def __init__(self, rig: Rig, source: str, target: str, *, pixel_sigma: float = 1.0,
                 confidence: float = DEFAULT_CONFIDENCE, options: FilterOptions | None = None) -> None:
        self.rig, self.source, self.target = rig, source, target
        pair = rig if set(rig.robots) == {source, target} else \
            Rig({target: rig.robot(target), source: rig.robot(source)})
        self.team = TeamTracker(pair, target, pixel_sigma=pixel_sigma, confidence=confidence, options=options)
        self._others = len(rig.robots) > 2
        self.pixel_sigma = pixel_sigma

    def step(self, row: TrackRow) -> bool:
        """Fill ``row``; rows without observations (unpaired, corrupt) are
        left alone.  Returns whether the row is one of the tracker's records."""
        if row.observations is None:
            return False
        obs = self._pair_only(row.observations) if self._others else row.observations
        self.team.step(row.t, obs, {self.source: row.t_source, self.target: row.t_target}, rows={self.source: row})
        return True

    def _pair_only(self, obs: ObservationSet) -> ObservationSet:
        """The observations between the two robots (another robot's camera or markers left out)."""
        pair = (self.source, self.target)
        keep = []
        for i, (o, m) in enumerate(zip(obs.observer, obs.marker)):
            try:
                if self.rig.observer(o)[0] not in pair:
                    continue
            except MutlocError:
                continue  # not a camera of the pair (as ever: left out)
            if m is not None:
                try:
                    if self.rig.owner(m) not in pair:
                        continue
                except MutlocError:
                    pass  # an unknown marker: the tracker names it
            keep.append(i)
        return obs if len(keep) == len(obs) else obs.take(np.array(keep, dtype=np.int64))


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


def track(rig: Any, streams: Mapping[str, Iterable[Frame]], source: str | None = None, target: str | None = None, *,
          tolerance: float = 0.005, pixel_sigma: float = 1.0, confidence: float = DEFAULT_CONFIDENCE,
          fps: float | None = None, annotate: str | Path | None = None,
          observations_out: str | Path | None = None, progress: bool = True, total: int | None = None,
          filter: str | FilterOptions = "cv", rerun: str | Path | None = None,
          sink: Callable[[TrackRow], None] | None = None) -> Trajectory:
    """Localize over two streams (``{robot: frames}``), or, for robots with several cameras, one stream per
    camera (``{"p/front": frames, "p/back": ..., "q/front": ...}``, keyed as observations are: SPEC "Robots
    with several cameras"; each camera's frames fused at their own time, see :func:`_track_cameras`).

    ``sink`` is called with every row, in input order, as soon as its report
    is final (after the smoother's lag; see
    :meth:`~mutloc.track.team.TeamTracker.finalize`): write outputs
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
    rig, source, target = prepare_pair(rig, streams, source, target, "stream", cameras=True)
    if any(rig.robot(r).is_body for r in (source, target)):
        return _track_cameras(rig, streams, source, target, tolerance=tolerance, pixel_sigma=pixel_sigma,
                              confidence=confidence, fps=fps, annotate=annotate, observations_out=observations_out,
                              progress=progress, total=total, filter=filter, rerun=rerun, sink=sink)
    tracker = PairTrack(rig, source, target, pixel_sigma=pixel_sigma, confidence=confidence,
                        options=_options(filter))
    rate = frame_rate(streams, fps)
    dets = {source: ObserverDetector(rig, source, target, rate or DEFAULT_FPS),
            target: ObserverDetector(rig, target, source, rate or DEFAULT_FPS)}
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

    emitter = RowEmitter(tracker.team, final)
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
                filtered = _detect_and_fuse(rig, tracker, dets, present, images, row, source, target,
                                            len(images) == 2, log, pixel_sigma, confidence)
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
        close_all(bar, writer, log, viz)
    return _noted(Trajectory(source, target, rows, rate), tracker)



def _detect_and_fuse(rig: Rig, tracker: PairTrack, dets: Mapping[str, ObserverDetector], frames: Mapping[str, Frame],
                     images: Mapping[str, np.ndarray], row: TrackRow, source: str, target: str, both: bool,
                     log: ObservationLogWriter | None, pixel_sigma: float, confidence: float) -> bool:
    """One record of :func:`track`: each image searched by its camera's detector, tags missed looked for
    where the track expects them (see .tag_look), then, with both robots' frames (``both``), where the
    record's own pose puts them, and partly hidden balls measured again where a verified pose puts them (see
    .second_look); the observations (pixels only, as the log holds them) logged and fused, the looks' notes
    added to the row's reason.  Returns what the tracker's step returned (the row was filtered)."""
    row.detections = {k: dets[k].detect(frames[k]) for k in images}
    row.detections, tracked = look_where_tracked(rig, images, row.detections,
                                                 lambda: tracker.team.predicted(row.t))
    notes = [text for _, text in tracked]
    if both:
        row.detections, again = look_again(rig, images, row.detections, source, target,
                                           pixel_sigma=pixel_sigma, confidence=confidence)
        notes += again
    row.observations = observations_of(row.detections, row.t).with_sigma_scale(None)
    if log is not None:
        log.write(row.t, row.observations)
    filtered = tracker.step(row)
    if notes:
        row.reason = "; ".join([row.reason, *notes] if row.reason else notes)
    return filtered

def _track_cameras(rig: Rig, streams: Mapping[str, Iterable[Frame]], source: str, target: str, *,
                   tolerance: float, pixel_sigma: float, confidence: float, fps: float | None,
                   annotate: str | Path | None, observations_out: str | Path | None, progress: bool,
                   total: int | None, filter: str | FilterOptions, rerun: str | Path | None,
                   sink: Callable[[TrackRow], None] | None) -> Trajectory:
    """:func:`track` for robots with several cameras: one stream per camera (``ROBOT/CAMERA``; a robot with one
    camera keyed ``ROBOT``), frames within ``tolerance`` of each other one record, any other frame a record of
    its own camera, fused at its own time (:func:`~mutloc.track.team.sync_streams`).  Each camera's image is
    searched for the other robot's markers through its own lens; rows as :func:`track`'s (``t_source`` /
    ``t_target``: the mean time of that robot's frames in the record), ``detections`` keyed by camera.  A
    camera without a stream is not used; a record with an unreadable frame is ``corrupt``."""
    robot_of = {k: r for k, r in image_keys(rig, streams, "stream").items() if r in (source, target)}
    tracker = PairTrack(rig, source, target, pixel_sigma=pixel_sigma, confidence=confidence,
                        options=_options(filter))
    rate = frame_rate(streams, fps)
    dets = {k: ObserverDetector(rig, k, target if r == source else source, rate or DEFAULT_FPS)
            for k, r in robot_of.items()}
    writer = Annotator(annotate, fps=rate or DEFAULT_FPS) if annotate else None
    log = ObservationLogWriter(observations_out) if observations_out else None
    viz = _rerun_writer(rerun, source, target)
    sizes: dict[str, tuple[int, int]] = {}
    last: dict[str, tuple[np.ndarray | None, float | None]] = {}  # each camera's latest image and its time

    def final(row: TrackRow, shown: dict) -> None:
        if viz is not None:
            _rerun_row(viz, row)
        if writer is not None:
            writer.write_team(shown, {source: row}, target, camera_sizes(rig, shown, sizes, list(robot_of)))
        if sink is not None:
            sink(row)

    emitter = RowEmitter(tracker.team, final)
    rows: list[TrackRow] = []
    groups = sync_streams({k: streams[k] for k in robot_of}, tolerance)
    bar = tqdm(groups, total=total, unit="frame", disable=not progress, desc="track")
    try:
        for group in bar:
            for k, fr in group.items():
                dets[k].feed(fr)
            t = float(np.mean([f.t for f in group.values()]))
            times = {r: float(np.mean([f.t for k, f in group.items() if robot_of[k] == r]))
                     for r in (source, target) if r in {robot_of[k] for k in group}}
            row = TrackRow(t, times.get(source), times.get(target), FrameStatus.SOLVED)
            images = {k: f.image for k, f in group.items() if f.image is not None}
            filtered = False
            if len(images) < len(group):
                # an unreadable image is reported as such, never guessed around (nor the record's other frames)
                row.status = FrameStatus.CORRUPT
                row.reason = "; ".join(f"{k}: {f.status}" for k, f in group.items() if f.image is None)
            else:
                filtered = _detect_and_fuse(rig, tracker, dets, group, images, row, source, target,
                                            len(times) == 2, log, pixel_sigma, confidence)
            if writer is not None:
                last.update({k: (img, group[k].t) for k, img in images.items()})
            rows.append(row)
            emitter.add(row, filtered, dict(last) if writer is not None else None)
            emitter.emit()
        emitter.emit(end=True)
    except KeyboardInterrupt:
        emitter.emit(end=True)  # every frame finished so far, reported as if the input ended here
        raise
    finally:
        close_all(bar, writer, log, viz)
    return _noted(Trajectory(source, target, rows, rate), tracker)


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
    tracker = PairTrack(rig, source, target, pixel_sigma=pixel_sigma, confidence=confidence,
                        options=_options(filter))
    viz = _rerun_writer(rerun, source, target)

    def final(row: TrackRow) -> None:
        if viz is not None:
            _rerun_row(viz, row)
        if sink is not None:
            sink(row)

    emitter = RowEmitter(tracker.team, lambda row, _: final(row))
    rows: list[TrackRow] = []
    try:
        for item in tqdm(frames, total=total, unit="frame", disable=not progress, desc="track"):
            if isinstance(item, ObservationSet):
                times = item.times
                t, obs = (float(times[0]) if len(times) else (rows[-1].t if rows else 0.0)), item
            else:
                t, obs = float(item[0]), item[1]
            row = TrackRow(t, t, t, FrameStatus.SOLVED, observations=obs)
            emitter.add(row, tracker.step(row))
            emitter.emit()
            rows.append(row)
        emitter.emit(end=True)
    except KeyboardInterrupt:
        emitter.emit(end=True)  # every record finished so far, reported as if the input ended here
        raise
    finally:
        if viz is not None:
            viz.close()
    return _noted(Trajectory(source, target, rows, None), tracker)


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


def _noted(traj: Trajectory, tracker: PairTrack) -> Trajectory:
    """The trajectory with the track's notes (the rig check's hint, when its window disagreed)."""
    note = tracker.team.rig_check.summary()
    if note:
        traj.notes.append(note)
    return traj
