"""``mutloc localize-images``: detect the markers in one image per robot, then localize."""

from __future__ import annotations

import argparse

from ._common import NOISE, OUTPUT, PAIR, RIG, TRUST, output_path, robot_map, robot_value

ORDER = 20


def add_parser(subparsers: argparse._SubParsersAction) -> argparse.ArgumentParser:
    """Register ``localize-images``."""
    p = subparsers.add_parser(
        "localize-images", parents=[RIG, PAIR, NOISE, TRUST, OUTPUT],
        help="detect markers in one image per robot, then localize; prints the result JSON",
        description="Detect each robot's view of the other robot's markers (coloured balls, printed "
        "tags or banded cylinders, as the rig says) and print the relative pose as the result JSON.",
    )
    p.add_argument("--image", required=True, action="append", type=robot_value, metavar="ROBOT=PATH",
                   help="the image of a robot's camera; give one per robot")
    p.add_argument("--detections-out", metavar="FILE", help="write what was detected (JSON)")
    return p


def run(args: argparse.Namespace) -> int:
    """Detect, localize, print."""
    from ..io import load_rig, write_json
    from ..track import localize_images

    res = localize_images(load_rig(args.rig), robot_map(args.image, "--image"), args.source, args.target,
                          pixel_sigma=args.pixel_sigma, confidence=args.confidence,
                          allow_unverified=args.allow_unverified)
    if args.detections_out:
        write_json(res.detections_dict(), args.detections_out)
    write_json(res.estimate.to_dict(), output_path(args.output))
    return 0
