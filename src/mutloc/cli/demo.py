"""``mutloc demo``: the main job end to end on built-in synthetic data."""

from __future__ import annotations

import argparse

ORDER = 90


def add_parser(subparsers: argparse._SubParsersAction) -> argparse.ArgumentParser:
    """Register ``demo``."""
    p = subparsers.add_parser("demo", help="the main job end to end on built-in synthetic data",
                              description="Solve a built-in synthetic two-robot scene and print the "
                              "estimated pose beside the truth.")
    p.add_argument("--out", default="demo-out", metavar="DIR", help="where to write the files (default demo-out)")
    p.add_argument("--seed", type=int, default=0, help="noise seed (default 0)")
    return p


def run(args: argparse.Namespace) -> int:
    """Run the demo and print its report."""
    from ..sim.demo import format_summary, run_demo

    print(format_summary(run_demo(args.out, seed=args.seed)))
    return 0
