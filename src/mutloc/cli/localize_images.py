"""``mutloc localize-images``: detect the markers in one image per robot, then localize."""

from __future__ import annotations

import argparse

from ._common import output_path, positive_float, robot_value

ORDER = 20


def add_parser(subparsers: argparse._SubParsersAction) -> argparse.ArgumentParser:
    """Register ``localize-images``."""
    p = subparsers.add_parser(
        "localize-images",
        help="detect markers in one image per robot, then localize; prints the result JSON",
        description="Detect each robot's view of the other robot's markers (coloured balls, printed "
        "tags or banded cylinders, as the rig says) and print the relative pose as the result JSON.",
    )
    p.add_argument("--rig", required=True, metavar="FILE", help="rig file (YAML or JSON)")
    p.add_argument("--image", required=True, action="append", type=robot_value, metavar="ROBOT=PATH",
                   help="the image of a robot's camera; give one per robot")
    p.add_argument("--source", metavar="ROBOT")
    p.add_argument("--target", metavar="ROBOT")
    p.add_argument("--pixel-sigma", type=positive_float, default=1.0, metavar="PX")
    p.add_argument("--detections-out", metavar="FILE", help="write what was detected (JSON)")
    p.add_argument("--output", "-o", metavar="FILE", help="write the result JSON here instead of stdout")
    return p


def run(args: argparse.Namespace) -> int:
    """Detect, localize, print."""
    from ..errors import InputError
    from ..io import load_rig, write_json
    from ..track import localize_images

    images: dict[str, str] = {}
    for robot, path in args.image:
        if robot in images:
            raise InputError(f"--image given twice for robot {robot!r}")
        images[robot] = path
    rig = load_rig(args.rig)
    res = localize_images(rig, images, args.source, args.target, pixel_sigma=args.pixel_sigma)
    if args.detections_out:
        write_json(res.detections_dict(), args.detections_out)
    write_json(res.estimate.to_dict(), output_path(args.output))
    return 0
