"""``mutloc track``: a trajectory from image streams (each frame at its own time) or an observation log."""

from __future__ import annotations

import argparse
from pathlib import Path

from ._common import (NOISE, ODOMETRY, PAIR, PROGRESS, RIG, TEAM, int_in_range, nonnegative_float, positive_float,
                      robot_map, robot_value, team_mode)

ORDER = 30


def add_parser(subparsers: argparse._SubParsersAction) -> argparse.ArgumentParser:
    """Register ``track``."""
    p = subparsers.add_parser(
        "track", parents=[RIG, PAIR, TEAM, NOISE, ODOMETRY, PROGRESS],
        help="relative pose over time from two videos, image folders, a ROS bag or an observation log",
        description="Detect the markers in every camera frame and fuse each at its own timestamp (frames of the "
        "robots within --tolerance make one record; cameras need not be synchronized), "
        "or localize every record of an observation log; writes the trajectory as TUM and CSV (every "
        "frame with its status and reason). With more than two robots (and no --source/--target) or "
        "--reference: one stream per robot, each frame localized jointly, and one trajectory_NAME.csv/.tum "
        "per robot in the reference's frame.",
    )
    src = p.add_mutually_exclusive_group(required=True)
    src.add_argument("--stream", action="append", type=robot_value, metavar="ROBOT=PATH",
                     help="a video file, a folder of images, or a ROS 1/2 bag (with --topic); one per robot, or, "
                          "for a robot with several cameras, one per camera (ROBOT/CAMERA=PATH; a camera without "
                          "one is not used)")
    src.add_argument("--observations", metavar="LOG", help="an observation log (JSON Lines) instead of images")
    p.add_argument("--observations-out", metavar="LOG",
                   help="also write every frame's detections as an observation log (JSON Lines)")
    p.add_argument("--topic", action="append", type=robot_value, default=[], metavar="ROBOT=TOPIC",
                   help="image topic of a robot's camera in a bag (ROBOT/CAMERA=TOPIC for a robot with several)")
    p.add_argument("--camera-info", action="append", type=robot_value, default=[], metavar="ROBOT=TOPIC",
                   help="take this robot's calibration from a camera_info topic of the bag")
    p.add_argument("--fps", type=positive_float, help="frame rate when the stream has no timestamps")
    p.add_argument("--tolerance", type=positive_float, default=0.005, metavar="S",
                   help="frames of the robots closer in time than this are one record (default 0.005 s); every other "
                        "frame is fused at its own time (cameras need not be synchronized)")
    p.add_argument("--out", required=True, metavar="DIR", help="writes DIR/trajectory.tum and DIR/trajectory.csv")
    p.add_argument("--annotate", metavar="VIDEO", help="also write an annotated video (mp4): the cameras side by side "
                   "(a team: tiled, one status line per robot) with the detections, statuses and poses")
    p.add_argument("--bag", metavar="DIR", help="also write the poses with covariance as a ROS 2 bag (a new folder): "
                   "geometry_msgs/PoseWithCovarianceStamped on /mutloc/SOURCE_in_TARGET and tf2_msgs/TFMessage on /tf")
    p.add_argument("--mcap", metavar="FILE", help="the same messages as an MCAP file")
    p.add_argument("--rerun", metavar="FILE.rrd", help="also write a Rerun recording: images with detections, the "
                   "robots' frames with covariance ellipsoids, the trajectory (open with: rerun FILE.rrd)")
    p.add_argument("--frames", choices=("camera", "base"), default="camera",
                   help="poses between the cameras' optical frames (default) or between the robots' base frames "
                        "(the rig's base_from_camera of both robots)")
    p.add_argument("--clock-offsets", choices=("estimate",), metavar="estimate",
                   help="estimate each robot's clock offset to the reference's from the observations of moving "
                        "robots (the whole log; with --stream, the streams' detections, a first pass over them), "
                        "correct every stamp of that robot (its frames', its odometry's), print them and write "
                        "DIR/clock_offsets.json")
    f = p.add_argument_group("filter (SPEC \"Filtered tracking\")")
    f.add_argument("--filter", choices=("cv", "none"), default="cv",
                   help="cv (default): constant-velocity filter on the relative pose, updated by every frame's "
                        "markers (even one or two); none: every frame on its own")
    f.add_argument("--smooth-lag", type=int_in_range(0, 300, "--smooth-lag"), default=None, metavar="N",
                   help="report each pose smoothed with the N frames after it (fixed-lag smoothing; what a "
                        "smoother would give N frames late; default 10); 0: the causal filter's pose at once")
    f.add_argument("--linear-noise", type=positive_float, default=1.0, metavar="A",
                   help="white-noise acceleration of the relative translation, m/s^2/sqrt(Hz) (default 1.0)")
    f.add_argument("--angular-noise", type=positive_float, default=0.5, metavar="A",
                   help="white-noise angular acceleration, rad/s^2/sqrt(Hz) (default 0.5)")
    f.add_argument("--reference-angular-noise", type=nonnegative_float, default=0.0, metavar="A",
                   help="the reference robot's own white-noise angular acceleration, rad/s^2/sqrt(Hz), carried to "
                        "every robot through its distance from the reference (default 0: not modelled). For fast-"
                        "turning teams: --angular-noise 2 --linear-noise 2 --reference-angular-noise 2 keep coasted "
                        "poses within their sigma at 1-1.5 m/s and 70-80 deg/s (docs/benchmarks.md)")
    return p


def run(args: argparse.Namespace) -> int:
    """Track and write the trajectory."""
    from ..io import load_rig
    from ..core.filter import MotionNoise
    from ..errors import InputError, RigError
    from ..track.filtering import FilterOptions
    from ..track.sources import rig_with_bag_cameras
    from ..track.tracker import track, track_log

    out = check_outputs(args)  # before the work; folders are created by the writers
    rig = load_rig(args.rig)
    if args.frames == "base" and not team_mode(rig, args):
        for robot in rig.default_pair(args.source, args.target):
            if rig.robot(robot).is_body:
                raise RigError(f"{args.rig}: robot {robot!r} has cameras: its poses already are in its robot frame "
                               "(leave out --frames base)")
            if rig.robot(robot).base_from_camera is None:
                raise RigError(f"{args.rig}: --frames base needs base_from_camera for robot {robot!r}")
    if args.observations and args.observations_out:
        raise InputError("--observations-out writes what is detected in images: with --observations the log "
                         "is already there")
    team = team_mode(rig, args)
    options = FilterOptions(args.filter, MotionNoise(angular=args.angular_noise, linear=args.linear_noise,
                                                         reference_angular=args.reference_angular_noise),
                            smooth_lag=args.smooth_lag, odometry=_odometry(args, rig, team))
    if args.observations and args.annotate:
        raise InputError("--annotate draws on the images: it needs --stream, not an observation log")
    log = LogUpToBadLine(args.observations) if args.observations else None
    records = iter(log) if log is not None else None
    if args.clock_offsets:
        records, options = _clock_offsets(args, rig, log, options, out, team)
    if team:
        return _run_team(args, rig, options, out, log, records)
    if args.observations:

        def work(sink):
            return track_log(rig, records, args.source, args.target,
                             pixel_sigma=args.pixel_sigma, confidence=args.confidence, progress=args.progress,
                             filter=options, rerun=args.rerun, sink=sink)
        return _written_as_it_runs(work, out, args, rig, log)
    paths, topics, infos = _stream_options(args, rig)
    if infos:
        rig = rig_with_bag_cameras(rig, paths, infos)

    def work(sink):
        return track(rig, _open_streams(args, paths, topics), args.source, args.target,
                     tolerance=args.tolerance, pixel_sigma=args.pixel_sigma, confidence=args.confidence,
                     fps=args.fps, annotate=args.annotate, observations_out=args.observations_out,
                     progress=args.progress, filter=options, rerun=args.rerun, sink=sink)
    return _written_as_it_runs(work, out, args, rig)


def _clock_offsets(args: argparse.Namespace, rig, log: "LogUpToBadLine | None", options, out: Path, team: bool):
    """``--clock-offsets estimate``: each robot's offset estimated from the whole log (read here; with
    ``--stream``, the streams' detections, a first pass over them: :func:`_stream_records`), printed and
    written to ``DIR/clock_offsets.json``; returns the records with every robot's stamps corrected and the
    options with its odometry's (see :mod:`mutloc.track.clocks`); with ``--stream``, every robot's frames
    are then read again with their stamps corrected (``args.clock_shift``, see :func:`_open_streams`)."""
    from dataclasses import replace

    from ..errors import InputError
    from ..track.clocks import estimate_clock_offsets, shift_records, write_clock_offsets
    from ..track.frames import expanded_rig

    if args.filter != "cv":
        raise InputError("--clock-offsets estimate runs the filter: it needs --filter cv")
    reference = (args.reference if args.reference is not None else next(iter(rig.robots))) if team \
        else rig.default_pair(args.source, args.target)[1]
    full = expanded_rig(rig)
    records = list(log) if log is not None else _stream_records(args, rig, options, team)
    found = estimate_clock_offsets(full, records, reference, options=options, pixel_sigma=args.pixel_sigma,
                                   confidence=args.confidence)
    for robot, c in found.items():
        print(c.text(robot))
    write_clock_offsets(out, found)
    offsets = {r: c.offset_s for r, c in found.items() if c.offset_s is not None}
    args.clock_shift = offsets
    return iter(shift_records(full, records, offsets)), replace(options, clock_offsets=offsets)


def _stream_records(args: argparse.Namespace, rig, options, team: bool) -> list:
    """``--stream`` with ``--clock-offsets estimate``: the streams' detections, a pass over them as
    ``--observations-out`` writes them (a temporary log, nothing else written), as records."""
    import tempfile

    from ..io.logs import iter_observation_log
    from ..track.sources import rig_with_bag_cameras
    from ..track.team import require_streams, track_team
    from ..track.tracker import track

    paths, topics, infos = _stream_options(args, rig)
    if team:
        require_streams(rig, paths)
    if infos:
        rig = rig_with_bag_cameras(rig, paths, infos)
    with tempfile.TemporaryDirectory() as tmp:
        log = Path(tmp) / "detections.jsonl"
        common = dict(tolerance=args.tolerance, pixel_sigma=args.pixel_sigma, confidence=args.confidence,
                      fps=args.fps, observations_out=log, progress=args.progress, filter=options)
        if team:
            track_team(rig, _open_streams(args, paths, topics), args.reference, **common)
        else:
            track(rig, _open_streams(args, paths, topics), args.source, args.target, **common)
        return list(iter_observation_log(log))


def _open_streams(args: argparse.Namespace, paths: dict, topics: dict) -> dict:
    """The streams of ``--stream``, each robot's frames' stamps corrected by ``args.clock_shift`` (its
    estimated clock offset; absent: as recorded)."""
    from dataclasses import replace

    from ..track.sources import Stream, open_streams

    def shifted(stream: Stream, off: float) -> Stream:
        return Stream((replace(f, t=f.t + off) for f in stream), stream.fps, stream.name)

    streams = open_streams(paths, fps=args.fps, topics=topics)
    shift = getattr(args, "clock_shift", None) or {}
    return {key: shifted(s, shift[key.split("/")[0]]) if shift.get(key.split("/")[0]) else s
            for key, s in streams.items()}


def _odometry(args: argparse.Namespace, rig, team: bool) -> dict:
    """``--odometry`` by robot (a pair's robots only), each source's rejected
    samples said on stderr (one line per robot); one-line OdometryError for a
    source that cannot be used."""
    import sys

    from ._common import odometry_options
    from ..errors import OdometryError

    odometry = odometry_options(args, rig)
    if odometry and args.filter != "cv":
        raise OdometryError("--odometry is fused by the filter: it needs --filter cv")
    if not team:
        pair = rig.default_pair(args.source, args.target)
        for robot in odometry:
            if robot not in pair:
                raise OdometryError(f"--odometry {robot}=...: robot {robot!r} is not tracked (the pair is "
                                    f"{pair[0]} and {pair[1]})")
    for robot, odo in odometry.items():
        rejected = ", ".join(f"{n} {kind.replace('_', ' ')}" for kind, n in odo.counts.items() if n)
        if rejected:
            print(f"note: odometry of {robot} ({odo.source}): samples rejected: {rejected}", file=sys.stderr)
    args.odometry_loaded = odometry
    return odometry


def _odometry_unused(args: argparse.Namespace, times: list[float]) -> None:
    """A note on stderr for each robot's odometry whose stamps the records'
    times never fall in (it moved no prediction: another clock?)."""
    import sys

    if not times or not getattr(args, "odometry_loaded", None):
        return
    lo, hi = min(times), max(times)
    for robot, odo in args.odometry_loaded.items():
        if odo.end < lo or odo.start > hi:
            print(f"note: odometry of {robot} ({odo.source}) not used: its stamps {odo.start:.3f}-{odo.end:.3f} s "
                  f"miss the records' {lo:.3f}-{hi:.3f} s (on another clock?)", file=sys.stderr)


def _stream_options(args: argparse.Namespace, rig) -> tuple[dict, dict, dict]:
    """``--stream``, ``--topic`` and ``--camera-info`` by camera key (``ROBOT``, or ``ROBOT/CAMERA`` for a robot
    with several cameras), checked in one line each: an unknown robot or camera, a robot with several cameras
    named alone, a topic or camera_info for a camera without a stream.  A camera of a robot with several
    that has no stream is not used (said on stderr)."""
    import sys

    from ..errors import InputError
    from ..track.frames import image_keys
    from ..track.team import unused_cameras

    paths = robot_map(args.stream, "--stream")
    keys = image_keys(rig, paths, "stream")
    topics = robot_map(args.topic, "--topic")
    infos = robot_map(args.camera_info, "--camera-info")
    for option, given in (("--topic", topics), ("--camera-info", infos)):
        for k in given:
            if k not in paths:
                raise InputError(f"{option} {k}=...: no --stream {k}=... (a bag's topics are named per stream)")
    unused = unused_cameras(rig, keys)
    if unused:
        print(f"note: no --stream for camera{'s' if len(unused) > 1 else ''} {', '.join(unused)}: not used",
              file=sys.stderr)
    return paths, topics, infos


def check_outputs(args: argparse.Namespace) -> Path:
    """Every output path checked before the work, one line for the first
    wrong one (a file where a folder is wanted or the reverse, --bag/--mcap
    that exist, a place nothing can be written to, one path given for two
    outputs); returns --out."""
    from ..errors import InputError
    from ..io import writable_path

    seen: dict = {}
    out = None
    for option, path, folder, new in (("--out", args.out, True, False), ("--bag", args.bag, True, True),
                                      ("--mcap", args.mcap, False, True), ("--rerun", args.rerun, False, False),
                                      ("--annotate", args.annotate, False, False),
                                      ("--observations-out", args.observations_out, False, False)):
        if path is None:
            continue
        p = writable_path(path, option, folder=folder, new=new)
        key = p.resolve()
        if key in seen:
            raise InputError(f"{seen[key]} and {option} name the same path {path}")
        seen[key] = option
        out = p if option == "--out" else out
    return out


class LogUpToBadLine:
    """The records of an observation log up to its first bad line (iterate
    once).  A bad line ends the log there: the records before it are
    tracked and written, then :meth:`raise_if_cut` raises its error (one
    line naming the file and line, and what was written).  A log bad before
    its first record raises at once."""

    def __init__(self, path: str) -> None:
        self.path = path
        self.error: Exception | None = None
        self.records = 0

    def __iter__(self):
        from ..errors import MutlocError
        from ..io.logs import iter_observation_log

        try:
            for record in iter_observation_log(self.path):
                self.records += 1
                yield record
        except MutlocError as exc:
            if not self.records:
                raise
            self.error = exc

    def raise_if_cut(self, wrote: str) -> None:
        if self.error is not None:
            raise type(self.error)(f"{self.error}; the {self.records} records before it were tracked ({wrote})")


def _written_as_it_runs(work, out, args, rig, log: LogUpToBadLine | None = None) -> int:
    """Run ``work(sink)`` (a pair's track) with every output file appended
    row by row as the rows become final; Ctrl-C stops it with every frame
    finished so far written, and says so (exit 130); a bad line of ``log``
    ends it with the records before it written, then its error."""
    import sys

    from ..track.outputs import TrackOutputs

    pair = rig.default_pair(args.source, args.target)
    before = _side_files(args)
    with TrackOutputs(out, *pair, bag=args.bag, mcap=args.mcap,
                      base_frames=rig if args.frames == "base" else None) as outputs:
        try:
            traj = work(outputs.write)
        except KeyboardInterrupt:
            outputs.close()
            print(f"interrupted: {outputs.rows} frames finished; {_wrote(outputs, args, before)}", file=sys.stderr)
            return 130
    if log is not None:
        log.raise_if_cut(_wrote(outputs, args, before))
    print(f"{traj.summary()}; {_wrote(outputs, args, before)}")
    _odometry_unused(args, [row.t for row in traj.rows])
    for note in traj.notes:
        print(note)
    return 0


def _side_files(args) -> dict[str, int | None]:
    """Each of --rerun, --annotate, --observations-out given: its modification time (None: no such file)."""
    import os

    stamps: dict[str, int | None] = {}
    for p in (args.rerun, args.annotate, args.observations_out):
        if p:
            try:
                stamps[str(p)] = os.stat(p).st_mtime_ns
            except OSError:
                stamps[str(p)] = None
    return stamps


def _wrote(outputs, args, before: dict[str, int | None]) -> str:
    """``wrote FILE, ...``: the files this run wrote (the side files new or
    changed since ``before``), or ``no files written`` (stopped before the
    first row)."""
    after = _side_files(args)
    files = [str(p) for p in outputs.written] + [p for p, t in after.items() if t is not None and t != before[p]]
    return f"wrote {', '.join(files)}" if files else "no files written"


def _run_team(args, rig, options, out, log: "LogUpToBadLine | None", records) -> int:
    """A team: one stream per robot (or a log), one trajectory per robot,
    every file appended row by row as the track runs (Ctrl-C: exit 130 with
    every row so far written, and said)."""
    import sys

    from ..track.outputs import TrackOutputs
    from ..track.sources import rig_with_bag_cameras
    from ..track.team import require_streams, track_team, track_team_log
    from ..track.tracker import BaseFrames

    reference = args.reference if args.reference is not None else next(iter(rig.robots))
    robots = [r for r in rig.robots if r != reference]
    base = rig if args.frames == "base" else None
    if base is not None:
        for r in robots:
            BaseFrames(rig, r, reference)  # refused here (one line) before the work, not after it
    viz = None
    if args.rerun:
        from ..io.rrd import RerunWriter

        viz = RerunWriter(args.rerun, None, reference)
    before = _side_files(args)
    with TrackOutputs(out, robots, reference, bag=args.bag, mcap=args.mcap, base_frames=base) as outputs:
        to_base = outputs.to_base

        def sink(row, robot):
            outputs.write(row, robot)
            if viz is not None:
                shown = to_base[robot](row) if to_base is not None else row
                e = shown.estimate
                viz.frame(row.t, str(row.status), row.reason, None if e is None else e.pose,
                          None if e is None else e.covariance, robot=robot)

        try:
            if args.observations:
                traj = track_team_log(rig, records, args.reference,
                                      pixel_sigma=args.pixel_sigma, confidence=args.confidence,
                                      progress=args.progress, filter=options, sink=sink)
            else:
                paths, topics, infos = _stream_options(args, rig)
                require_streams(rig, paths)
                if infos:
                    rig = rig_with_bag_cameras(rig, paths, infos)
                traj = track_team(rig, _open_streams(args, paths, topics),
                                  args.reference, tolerance=args.tolerance, pixel_sigma=args.pixel_sigma,
                                  confidence=args.confidence, fps=args.fps, observations_out=args.observations_out,
                                  progress=args.progress, filter=options, annotate=args.annotate, sink=sink)
        except KeyboardInterrupt:
            outputs.close()
            if viz is not None:
                viz.close()
            print(f"interrupted: {outputs.rows} robot rows finished; {_wrote(outputs, args, before)}",
                  file=sys.stderr)
            return 130
        finally:
            if viz is not None:
                viz.close()
    if log is not None:
        log.raise_if_cut(_wrote(outputs, args, before))
    print(f"reference {traj.reference}; {traj.summary()}; {_wrote(outputs, args, before)}")
    _odometry_unused(args, [row.t for tr in traj.tracks.values() for row in tr.rows])
    for note in traj.notes:
        print(note)
    return 0
