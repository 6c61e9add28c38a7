"""``mutloc calibrate-markers``: re-estimate the markers' positions from a log of mutual observations."""

from __future__ import annotations

import argparse

from ._common import NOISE, RIG, positive_float

ORDER = 45


def add_parser(subparsers: argparse._SubParsersAction) -> argparse.ArgumentParser:
    """Register ``calibrate-markers``."""
    p = subparsers.add_parser(
        "calibrate-markers", parents=[RIG, NOISE],
        help="re-estimate the markers' positions from a log of mutual observations",
        description=(
            "Bundle adjustment over every frame's relative pose(s) and every marker of an observation log "
            "(SPEC 'Observation logs'; any number of robots, robots with several cameras of any lens keyed "
            "ROBOT/CAMERA, each observation fitted through its camera's pose and lens, the cameras kept as given; "
            "what track --observations-out writes: a tag's "
            "corners NAME#0..3 calibrate the tag as a rigid body, centre and rotation; a cylinder's bands NAME#bK "
            "its axis). Writes the rig with each marker's new position and position_sigma (1 sigma per axis, "
            "metres, scale held, for the detection noise --pixel-sigma; --measured-noise: for the noise the "
            "fit's residuals show), for tags also tag.rotation and tag.rotation_sigma (radians), and prints, per "
            "marker, the old and new position and the change, and which combinations the log determines only "
            "weakly. --confidence is the chi-square test that names outlier observations."
        ),
    )
    p.add_argument("--observations", required=True, metavar="LOG", help="observation log (JSON Lines)")
    p.add_argument("--scale", action="append", metavar="A:B=D", default=None,
                   help="hold markers A and B (of one robot) D metres apart (repeatable); default: the two "
                        "markers farthest apart on the rig's first robot, at their given distance")
    p.add_argument("--prior-sigma", type=positive_float, metavar="M",
                   help="how well the rig's positions were measured (metres, 1 sigma per axis): they then count as "
                        "a measurement and hold what the log determines only weakly (default: the log alone)")
    p.add_argument("--weak-sigma", type=positive_float, metavar="M", default=None,
                   help="without --prior-sigma, the combinations the log determines worse than M metres (1 sigma) "
                        "are taken from the given rig, good to M along them (default 0.01)")
    p.add_argument("--log-alone", action="store_true",
                   help="no combination held near the given rig: the log alone (refused where it cannot "
                        "determine the markers)")
    p.add_argument("--measured-noise", action="store_true",
                   help="report the sigmas for the detection noise the fit's residuals show (when clearly below "
                        "--pixel-sigma) instead of --pixel-sigma; the outlier test keeps --pixel-sigma")
    p.add_argument("--out", required=True, metavar="NEW_RIG", help="the calibrated rig (YAML, or JSON if .json)")
    p.add_argument("--report", metavar="FILE", help="also write the full result (JSON) here")
    return p


def run(args: argparse.Namespace) -> int:
    """Calibrate, write the new rig, print the per-marker table."""
    from ..calibration import WEAK_PRIOR_SIGMA_M, calibrate_markers
    from ..errors import InputError
    from ..io import load_rig, save_rig, write_json

    if args.log_alone and args.weak_sigma is not None:
        raise InputError("--log-alone and --weak-sigma contradict each other: give one")
    weak = None if args.log_alone else (args.weak_sigma or WEAK_PRIOR_SIGMA_M)
    result = calibrate_markers(load_rig(args.rig), args.observations, scale=args.scale,
                               pixel_sigma=args.pixel_sigma, prior_sigma=args.prior_sigma,
                               confidence=args.confidence, weak_sigma=weak, measure_noise=args.measured_noise)
    save_rig(result.rig, args.out)
    if args.report:
        write_json(result.to_dict(), args.report)
    print(result.summary())
    print(f"wrote {args.out}")
    return 0
