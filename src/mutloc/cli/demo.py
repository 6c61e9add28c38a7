"""``mutloc demo``: the main job end to end on built-in synthetic data."""

from __future__ import annotations

import argparse

from ._common import PROGRESS, int_in_range, positive_float

ORDER = 90


def add_parser(subparsers: argparse._SubParsersAction) -> argparse.ArgumentParser:
    """Register ``demo``."""
    p = subparsers.add_parser(
        "demo", parents=[PROGRESS], help="the main job end to end on built-in synthetic data",
        description="Render a two-robot scene pair and a short sequence with the built-in ray caster, "
        "detect the markers in the images, localize and track, and write a report (pose against the "
        "truth, a plot, annotated images) with every file it used.")
    p.add_argument("--out", default="demo-out", metavar="DIR", help="where to write the files (default demo-out)")
    p.add_argument("--seed", type=int, default=0, help="seed of the room and the sensor noise (default 0)")
    p.add_argument("--frames", type=int_in_range(1, None, "frames"), default=30, metavar="N",
                   help="frames of the sequence (default 30)")
    p.add_argument("--fps", type=positive_float, default=10.0, help="frame rate of the sequence (default 10)")
    live = p.add_argument_group("live (--live)")
    live.add_argument("--live", action="store_true",
                      help="instead: run two `mutloc node`s replaying rendered cameras in real time and a `mutloc "
                           "localizer`, over DDS on this machine's loopback interface, and report the poses a "
                           "subscriber receives, their error and latency (needs the live extra)")
    live.add_argument("--seconds", type=positive_float, default=10.0, metavar="S",
                      help="with --live: seconds of camera replayed (default 10)")
    live.add_argument("--odometry", action="store_true",
                      help="with --live: each moving robot's odometry too, simulated with drift (1 %% of the "
                           "distance, 0.3 deg/m, 50 Hz) and published as nav_msgs/msg/Odometry on /NAME/odom by a "
                           "separate process; the localizer subscribes to it (--odometry NAME=ros:/NAME/odom)")
    live.add_argument("--domain", type=int, default=None, metavar="N",
                      help="with --live: the DDS domain id (default: one from 100-199 chosen by the process id)")
    return p


def run(args: argparse.Namespace) -> int:
    """Run the demo and print its summary."""
    if args.odometry and not args.live:
        from ..errors import InputError

        raise InputError("--odometry is for the live demo: add --live")
    if args.live:
        from ..live.demo import format_live_summary, run_live_demo

        summary = run_live_demo(args.out, seconds=args.seconds, fps=args.fps, seed=args.seed, domain=args.domain,
                                progress=args.progress, odometry=args.odometry)
        print(format_live_summary(summary))
        return 0
    from ..sim.demo import format_summary, run_demo

    summary = run_demo(args.out, seed=args.seed, frames=args.frames, fps=args.fps, progress=args.progress)
    print(format_summary(summary))
    return 0
