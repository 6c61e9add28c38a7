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
    return p


def run(args: argparse.Namespace) -> int:
    """Run the demo and print its summary."""
    from ..sim.demo import format_summary, run_demo

    summary = run_demo(args.out, seed=args.seed, frames=args.frames, fps=args.fps, progress=args.progress)
    print(format_summary(summary))
    return 0
