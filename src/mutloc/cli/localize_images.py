"""``mutloc localize-images``: detect the markers in one image per robot, then localize."""

from __future__ import annotations

import argparse

from ..errors import MutlocError
from ._common import NOISE, OUTPUT, PAIR, RIG, TEAM, TRUST, output_path, robot_map, robot_value, team_mode

ORDER = 20


def add_parser(subparsers: argparse._SubParsersAction) -> argparse.ArgumentParser:
    """Register ``localize-images``."""
    p = subparsers.add_parser(
        "localize-images", parents=[RIG, PAIR, TEAM, NOISE, TRUST, OUTPUT],
        help="detect markers in one image per robot (or camera), then localize; prints the result JSON",
        description="Detect each robot's view of the other robot's markers (coloured balls, printed "
        "tags or banded cylinders, as the rig says) and print the relative pose as the result JSON. "
        "With more than two robots (and no --source/--target) or --reference: every image is searched for "
        "every other robot's markers and the team result JSON is printed.",
    )
    p.add_argument("--image", required=True, action="append", type=robot_value, metavar="ROBOT[/CAMERA]=PATH",
                   help="the image of a camera: ROBOT=PATH for a robot with one camera, ROBOT/CAMERA=PATH for each "
                   "camera of a robot with several (any lens); one per robot at least")
    p.add_argument("--detections-out", metavar="FILE", help="write what was detected (JSON, keyed by camera)")
    return p


def run(args: argparse.Namespace) -> int:
    """Detect, localize, print.  ``--detections-out`` is written also when
    no pose comes of the detections (then the error, exit 2)."""
    from ..io import load_rig, write_json

    rig = load_rig(args.rig)
    images = robot_map(args.image, "--image")
    try:
        if team_mode(rig, args):
            from ..team import localize_team_images, require_verified

            res = localize_team_images(rig, images, args.reference, pixel_sigma=args.pixel_sigma,
                                       confidence=args.confidence)
            _write_detections(args, res.detections)
            require_verified(res.estimate, args.allow_unverified)
        else:
            from ..track import localize_images

            res = localize_images(rig, images, args.source, args.target, pixel_sigma=args.pixel_sigma,
                                  confidence=args.confidence, allow_unverified=args.allow_unverified)
            _write_detections(args, res.detections)
    except MutlocError as exc:
        found = getattr(exc, "detections", None)
        if found is not None:
            _write_detections(args, found)
        raise
    write_json(res.estimate.to_dict(), output_path(args.output))
    return 0


def _write_detections(args: argparse.Namespace, detections: dict) -> None:
    if args.detections_out:
        from ..io import write_json
        from ..track.frames import FrameResult

        write_json(FrameResult(None, detections).detections_dict(), args.detections_out)  # type: ignore[arg-type]
