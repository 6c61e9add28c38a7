"""``mutloc localize``: relative pose from given pixel observations."""

from __future__ import annotations

import argparse

from ._common import NOISE, OUTPUT, PAIR, RIG, TEAM, TRUST, output_path, team_mode

ORDER = 10


def add_parser(subparsers: argparse._SubParsersAction) -> argparse.ArgumentParser:
    """Register ``localize``."""
    p = subparsers.add_parser(
        "localize", parents=[RIG, PAIR, TEAM, NOISE, TRUST, OUTPUT],
        help="pose from given pixel observations; prints the result JSON",
        description=(
            "Relative pose T_qp (x_q = R x_p + t) of two robots from the pixels where each "
            "robot's camera saw the other's markers. Prints the result JSON. With more than two robots "
            "(and no --source/--target) or --reference, every robot's pose in the reference's frame, "
            "estimated jointly from all observations: prints the team result JSON."
        ),
    )
    p.add_argument("--observations", required=True, metavar="FILE", help="observations file (JSON or YAML)")
    return p


def run(args: argparse.Namespace) -> int:
    """Load rig and observations, solve, print/write the result JSON."""
    from ..api import localize
    from ..io import load_observations, load_rig, write_json

    rig = load_rig(args.rig)
    if team_mode(rig, args):
        from ..team import localize_team, require_verified

        team = localize_team(rig, load_observations(args.observations), args.reference,
                             pixel_sigma=args.pixel_sigma, confidence=args.confidence)
        require_verified(team, args.allow_unverified)
        write_json(team.to_dict(), output_path(args.output))
        return 0
    est = localize(rig, load_observations(args.observations), args.source, args.target,
                   pixel_sigma=args.pixel_sigma, confidence=args.confidence, allow_unverified=args.allow_unverified)
    write_json(est.to_dict(), output_path(args.output))
    return 0
