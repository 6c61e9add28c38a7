"""``mutloc localize``: relative pose from given pixel observations."""

from __future__ import annotations

import argparse

from ._common import NOISE, OUTPUT, PAIR, RIG, TRUST, output_path

ORDER = 10


def add_parser(subparsers: argparse._SubParsersAction) -> argparse.ArgumentParser:
    """Register ``localize``."""
    p = subparsers.add_parser(
        "localize", parents=[RIG, PAIR, NOISE, TRUST, OUTPUT],
        help="pose from given pixel observations; prints the result JSON",
        description=(
            "Relative pose T_qp (x_q = R x_p + t) of two robots from the pixels where each "
            "robot's camera saw the other's markers. Prints the result JSON."
        ),
    )
    p.add_argument("--observations", required=True, metavar="FILE", help="observations file (JSON or YAML)")
    return p


def run(args: argparse.Namespace) -> int:
    """Load rig and observations, solve, print/write the result JSON."""
    from ..api import localize
    from ..io import load_observations, load_rig, write_json

    est = localize(load_rig(args.rig), load_observations(args.observations), args.source, args.target,
                   pixel_sigma=args.pixel_sigma, confidence=args.confidence, allow_unverified=args.allow_unverified)
    write_json(est.to_dict(), output_path(args.output))
    return 0
