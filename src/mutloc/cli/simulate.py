"""``mutloc simulate``: render a synthetic scene or sequence with ground truth."""

from __future__ import annotations

import argparse
import math
import re

from ._common import PROGRESS, SEED, int_in_range, nonnegative_float, positive_float, robot_map, robot_value

ORDER = 70

# As mutloc.sim.world.MARKER_KINDS (not imported: keep `mutloc --help` light;
# tests/test_cli.py checks the two agree).
MARKER_KINDS = ("balls", "lights", "tags", "cylinders")
# As mutloc.sim.body_scenes.CAMERA_SETS and FACINGS (tests/test_simulate_cli.py checks they agree).
CAMERA_SETS = ("single", "back-to-back-fisheye")
FACINGS = ("toward", "away")


def _image_size(text: str) -> tuple[int, int]:
    m = re.fullmatch(r"\s*(\d+)\s*[xX,]\s*(\d+)\s*", text)
    if not m or int(m.group(1)) < 16 or int(m.group(2)) < 16:
        raise argparse.ArgumentTypeError(f"size must be WIDTHxHEIGHT (each >= 16), e.g. 960x540, got {text!r}")
    return int(m.group(1)), int(m.group(2))


def _finite_float(text: str) -> float:
    try:
        x = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None
    if not math.isfinite(x):
        raise argparse.ArgumentTypeError(f"must be finite, got {text!r}")
    return x


def add_parser(subparsers: argparse._SubParsersAction) -> argparse.ArgumentParser:
    """Register ``simulate``."""
    p = subparsers.add_parser(
        "simulate", parents=[SEED, PROGRESS],
        help="render a synthetic scene or sequence, with ground truth",
        description=(
            "Render two robots p and q facing each other in a textured room with the built-in "
            "ray caster. Writes rig.yaml, the images (p.png and q.png, or p/ and q/ folders for a "
            "sequence with frames.csv), truth.json (T_qp and exact marker pixels per frame) and, "
            "for sequences, truth.tum (pose of p in q's frame, TUM format) and odometry_NAME.tum (each moving "
            "robot's drifting odometry). --cameras back-to-back-fisheye: robots "
            "with two fisheye cameras each, one image per camera (p_front.png, p_back.png, ...), rig.yaml with "
            "cameras:, observations keyed p/front ...; --facing away puts them back to back."
        ),
    )
    p.add_argument("--out", required=True, metavar="DIR", help="output folder (created if missing)")
    p.add_argument("--markers", choices=MARKER_KINDS, default="balls",
                   help="marker kind on each robot (default balls)")
    p.add_argument("--distance", type=positive_float, default=2.0, metavar="M",
                   help="distance between the cameras in metres (default 2.0)")
    p.add_argument("--frames", type=int_in_range(1), default=1, metavar="N",
                   help="number of frames; more than 1 renders a sequence of p moving (default 1)")
    p.add_argument("--fps", type=positive_float, default=30.0, help="frame rate of a sequence (default 30)")
    p.add_argument("--camera-fps", action="append", type=robot_value, default=[], metavar="ROBOT=FPS",
                   help="this robot's camera captures at its own rate (a sequence; default --fps): cameras not "
                        "synchronized, each folder with its own frames.csv")
    p.add_argument("--camera-offset", action="append", type=robot_value, default=[], metavar="ROBOT=S",
                   help="this robot's camera captures its first frame S seconds after the start (less than one "
                        "of its frames; default 0)")
    p.add_argument("--noise", type=nonnegative_float, default=1.0, metavar="SIGMA",
                   help="sensor noise, standard deviation in grey levels (default 1.0)")
    p.add_argument("--jpeg", type=int_in_range(1, 100, 'JPEG quality'), metavar="Q",
                   help="pass each image through JPEG at quality Q (files stay PNG)")
    p.add_argument("--blur", type=nonnegative_float, default=0.0, metavar="PX",
                   help="horizontal motion blur length in pixels (default 0)")
    p.add_argument("--k1", type=_finite_float, default=None,
                   help="radial distortion k1 of both cameras (default 0; pinhole cameras only)")
    p.add_argument("--size", type=_image_size, default=None, metavar="WxH",
                   help="image size (default 960x540; 1280x800 for fisheyes)")
    p.add_argument("--focal", type=positive_float, default=None, metavar="PX",
                   help="focal length in pixels (default 800; pinhole cameras only)")
    p.add_argument("--cameras", choices=CAMERA_SETS, default="single",
                   help="cameras of each robot: single (one pinhole camera, the robot's frame is its optical "
                        "frame; default) or back-to-back-fisheye (robots with several cameras: two fisheyes of "
                        "about 200 degrees, front and back, 1280x800; the robots' frames are base_link bodies; "
                        "writes an image per camera, p_front.png ... or p_front/ ... folders, and rig.yaml with "
                        "cameras:; --markers balls, lights or cylinders above the body, or tags: one printed "
                        "tag on each of the body's four sides, their corners' pixels in truth.json)")
    p.add_argument("--facing", choices=FACINGS, default="toward",
                   help="toward: the robots face each other (default); away: back to back, so only the back "
                        "cameras see the other robot (needs --cameras back-to-back-fisheye)")
    p.add_argument("--no-room", action="store_true", help="robots on a black background, no room")
    p.add_argument("--robots", type=int_in_range(2, 64, "--robots"), default=2, metavar="N",
                   help="more than 2: a team of N robots r0..rN-1 in a room, with --markers balls (four coloured "
                        "balls each, every ball its own colour) or tags (two AprilTags each, distinct ids); writes "
                        "rig.yaml, truth.json (every robot's pose in r0's frame) and one image per robot "
                        "(r0.png ... and observations.json; with --frames a sequence: r0/ ... folders, frames.csv "
                        "and truth_NAME.tum per robot)")
    p.add_argument("--no-images", dest="images", action="store_false",
                   help="with --robots: geometry only (rig, observations, truth), no rendering")
    p.add_argument("--speed", type=positive_float, metavar="M/S",
                   help="with --robots: fast robots, each driving a small circle at about this speed (0.8-1.2 times)")
    p.add_argument("--turn-rate", type=positive_float, metavar="DEG/S",
                   help="with --robots: each robot's heading swings at about this peak rate (0.93-1.07 times)")
    o = p.add_argument_group("odometry and clocks (sequences of one-camera robots)",
                             "a sequence also writes odometry_NAME.tum for each robot that moves: its pose in its own "
                             "odometry frame, from the true motion with a seeded random-walk drift")
    o.add_argument("--odometry-drift", type=_drift, default=None, metavar="PCT,DEG_PER_M",
                   help="the odometry's drift after 1 m travelled: percent of the distance and degrees "
                        "(default 1,0.3; growing with the square root of the distance)")
    o.add_argument("--odometry-rate", type=positive_float, default=None, metavar="HZ",
                   help="odometry samples per second (default 50)")
    o.add_argument("--clock-offset", action="append", type=robot_value, default=[], metavar="ROBOT=S",
                   help="this robot's clock runs S seconds behind the reference's (q; r0 for a team): its "
                        "frames.csv (one per robot folder) and odometry are stamped on its clock; truth.json "
                        "records clock_offsets (S: what puts its stamps on the reference's clock)")
    return p


def _drift(text: str) -> tuple[float, float]:
    parts = text.split(",")
    try:
        pct, deg = (float(x) for x in parts)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected PCT,DEG_PER_M (two numbers), got {text!r}") from None
    if not all(math.isfinite(x) and x >= 0 for x in (pct, deg)):
        raise argparse.ArgumentTypeError(f"drift must be two finite numbers >= 0, got {text!r}")
    return pct, deg


def run(args: argparse.Namespace) -> int:
    """Render and write the files; prints a one-line summary."""
    from ..errors import InputError
    from ..sim.scenario import write_simulation, write_team_simulation

    odometry = {k: v for k, v in (("odometry_rate", args.odometry_rate), ("odometry_drift", args.odometry_drift))
                if v is not None}
    odometry["clock_offset"] = _numbers(args.clock_offset, "--clock-offset")
    if (len(odometry) > 1 or odometry["clock_offset"]) and (args.cameras != "single" or args.frames < 2):
        raise InputError("--odometry-drift/--odometry-rate/--clock-offset are for sequences (--frames 2 or more) "
                         "of one-camera robots (--cameras single)")
    if args.cameras != "single":
        if args.robots > 2:
            raise InputError(f"--cameras {args.cameras}: a pair only (not with --robots)")
        for given, option in ((args.k1, "--k1"), (args.focal, "--focal"), (args.speed, "--speed"),
                              (args.turn_rate, "--turn-rate")):
            if given is not None:
                raise InputError(f"{option} is for --cameras single, not {args.cameras}")
        if args.camera_fps or args.camera_offset:
            raise InputError(f"--camera-fps/--camera-offset are for --cameras single, not {args.cameras}")
        from ..sim.body_scenes import write_cameras_simulation

        print(write_cameras_simulation(args.out, cameras=args.cameras, facing=args.facing, markers=args.markers,
                                       distance=args.distance, frames=args.frames, fps=args.fps, seed=args.seed,
                                       noise=args.noise, jpeg=args.jpeg, blur=args.blur, size=args.size,
                                       room=not args.no_room, progress=args.progress))
        return 0
    if args.facing != "toward":
        raise InputError("--facing away: one camera per robot would see nothing; use --cameras back-to-back-fisheye")
    if args.size is None:
        args.size = (960, 540)
    if args.focal is None:
        args.focal = 800.0
    if args.k1 is None:
        args.k1 = 0.0
    if args.robots > 2:
        if args.markers not in ("balls", "tags"):
            raise InputError("--robots: a team carries balls or tags (--markers balls|tags)")
        print(write_team_simulation(args.out, robots=args.robots, markers=args.markers, frames=args.frames,
                                    fps=args.fps, seed=args.seed, noise=args.noise, jpeg=args.jpeg,
                                    size=args.size, focal=args.focal, k1=args.k1, room=not args.no_room,
                                    images=args.images, progress=args.progress,
                                    camera_fps=_numbers(args.camera_fps, "--camera-fps"),
                                    camera_offset=_numbers(args.camera_offset, "--camera-offset"),
                                    speed=args.speed, turn_rate=args.turn_rate, **odometry))
        return 0
    if args.speed is not None or args.turn_rate is not None:
        raise InputError("--speed/--turn-rate move a team: use them with --robots 3 or more")
    summary = write_simulation(
        args.out, markers=args.markers, distance=args.distance, frames=args.frames, fps=args.fps,
        seed=args.seed, noise=args.noise, jpeg=args.jpeg, blur=args.blur, k1=args.k1, size=args.size,
        focal=args.focal, room=not args.no_room, progress=args.progress,
        camera_fps=_numbers(args.camera_fps, "--camera-fps"), camera_offset=_numbers(args.camera_offset,
                                                                                       "--camera-offset"),
        **odometry,
    )
    print(summary)
    return 0


def _numbers(pairs: list[tuple[str, str]], option: str) -> dict[str, float]:
    """``{robot: number}`` from repeated ``ROBOT=NUMBER`` options (one line naming the option if not a number)."""
    from ..errors import InputError

    out = {}
    for robot, text in robot_map(pairs, option).items():
        try:
            out[robot] = float(text)
        except ValueError:
            raise InputError(f"{option} {robot}={text}: not a number") from None
    return out
