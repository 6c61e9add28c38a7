"""``mutloc track``: a trajectory from two synchronized image streams."""

from __future__ import annotations

import argparse
from pathlib import Path

from ._common import positive_float, robot_value

ORDER = 30


def add_parser(subparsers: argparse._SubParsersAction) -> argparse.ArgumentParser:
    """Register ``track``."""
    p = subparsers.add_parser(
        "track",
        help="relative pose over time from two videos, image folders or a ROS bag",
        description="Pair two image streams by timestamp, detect the markers in each pair and localize; "
        "writes the trajectory as TUM and CSV (every frame with its status).",
    )
    p.add_argument("--rig", required=True, metavar="FILE")
    p.add_argument("--stream", required=True, action="append", type=robot_value, metavar="ROBOT=PATH",
                   help="a video file, a folder of images, or a ROS 1/2 bag (with --topic); one per robot")
    p.add_argument("--topic", action="append", type=robot_value, default=[], metavar="ROBOT=TOPIC",
                   help="image topic of a robot's camera in a bag")
    p.add_argument("--camera-info", action="append", type=robot_value, default=[], metavar="ROBOT=TOPIC",
                   help="take this robot's calibration from a camera_info topic of the bag")
    p.add_argument("--source", metavar="ROBOT")
    p.add_argument("--target", metavar="ROBOT")
    p.add_argument("--fps", type=positive_float, help="frame rate when the stream has no timestamps")
    p.add_argument("--tolerance", type=positive_float, default=0.005, metavar="S",
                   help="largest time difference of a pair of frames (default 0.005 s)")
    p.add_argument("--pixel-sigma", type=positive_float, default=1.0, metavar="PX")
    p.add_argument("--out", required=True, metavar="DIR", help="writes DIR/trajectory.tum and DIR/trajectory.csv")
    p.add_argument("--annotate", metavar="VIDEO", help="also write a side-by-side annotated video (mp4)")
    p.add_argument("--no-progress", action="store_true")
    return p


def run(args: argparse.Namespace) -> int:
    """Track and write the trajectory."""
    from ..core.rig import Rig, Robot
    from ..errors import InputError
    from ..io import load_rig
    from ..track.sources import bag_camera, open_source
    from ..track.tracker import track

    rig = load_rig(args.rig)
    streams: dict[str, str] = {}
    for robot, path in args.stream:
        if robot in streams:
            raise InputError(f"--stream given twice for robot {robot!r}")
        rig.robot(robot)
        streams[robot] = path
    topics = dict(args.topic)
    infos = dict(args.camera_info)
    if infos:
        robots = dict(rig.robots)
        for robot, topic in infos.items():
            cam = bag_camera(streams[robot], topic) if robot in streams else None
            if cam is None:
                raise InputError(f"no camera_info message for robot {robot!r} on {topic!r}")
            old = rig.robot(robot)
            robots[robot] = Robot(old.name, cam, old.markers)
        rig = Rig(robots)
    frames = {r: open_source(p, fps=args.fps, topic=topics.get(r)) for r, p in streams.items()}
    traj = track(rig, frames, args.source, args.target, tolerance=args.tolerance, pixel_sigma=args.pixel_sigma,
                 fps=args.fps, annotate=args.annotate, progress=not args.no_progress)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    traj.write_tum(out / "trajectory.tum")
    traj.write_csv(out / "trajectory.csv")
    print(f"{len(traj.solved)} of {len(traj.rows)} frames localized; wrote {out / 'trajectory.tum'} and "
          f"{out / 'trajectory.csv'}")
    return 0
