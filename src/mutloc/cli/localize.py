"""``mutloc localize``: relative pose from given pixel observations."""

from __future__ import annotations

import argparse

from ._common import output_path, positive_float

ORDER = 10


def add_parser(subparsers: argparse._SubParsersAction) -> argparse.ArgumentParser:
    """Register ``localize``."""
    p = subparsers.add_parser(
        "localize",
        help="pose from given pixel observations; prints the result JSON",
        description=(
            "Relative pose T_qp (x_q = R x_p + t) of two robots from the pixels where each "
            "robot's camera saw the other's markers. Prints the result JSON."
        ),
    )
    p.add_argument("--rig", required=True, metavar="FILE", help="rig file (YAML or JSON)")
    p.add_argument("--observations", required=True, metavar="FILE", help="observations file (JSON or YAML)")
    p.add_argument("--source", metavar="ROBOT", help="robot p (optional for a two-robot rig)")
    p.add_argument("--target", metavar="ROBOT", help="robot q (optional for a two-robot rig)")
    p.add_argument("--pixel-sigma", type=positive_float, default=1.0, metavar="PX",
                   help="detection noise in pixels for the covariance (default 1.0)")
    p.add_argument("--output", "-o", metavar="FILE", help="write the JSON here instead of stdout")
    return p


def run(args: argparse.Namespace) -> int:
    """Load rig and observations, solve, print/write the result JSON."""
    import mutloc
    from ..io import load_observations, load_rig, write_json

    rig = load_rig(args.rig)
    obs = load_observations(args.observations)
    est = mutloc.localize(rig, obs, source=args.source, target=args.target, pixel_sigma=args.pixel_sigma)
    write_json(est.to_dict(), output_path(args.output))
    return 0
