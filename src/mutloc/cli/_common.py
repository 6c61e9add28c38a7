"""Argument types and the shared options of the subcommands.

Options that several commands take are declared once here, with their help
text, as argparse parent parsers (``parents=[RIG, PAIR, ...]``), so every
command spells and explains them the same way.
"""

from __future__ import annotations

import argparse
import math

__all__ = ["positive_float", "nonnegative_float", "output_path", "robot_value", "int_in_range", "unit_interval",
           "RIG", "PAIR", "NOISE", "TRUST", "OUTPUT", "PROGRESS", "SEED", "TEAM", "LIVE", "robot_map", "team_mode",
           "loopback_wanted", "live_domain", "ODOMETRY", "odometry_options", "odometry_noise", "ROS_PREFIX"]


def positive_float(text: str) -> float:
    """argparse type: a finite number > 0."""
    try:
        x = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None
    if not (math.isfinite(x) and x > 0):
        raise argparse.ArgumentTypeError(f"must be a finite number > 0, got {text!r}")
    return x


def nonnegative_float(text: str) -> float:
    """argparse type: a finite number >= 0."""
    try:
        x = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None
    if not (math.isfinite(x) and x >= 0):
        raise argparse.ArgumentTypeError(f"must be a finite number >= 0, got {text!r}")
    return x


def unit_interval(text: str) -> float:
    """argparse type: a number in (0, 1]."""
    try:
        x = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None
    if not 0.0 < x <= 1.0:
        raise argparse.ArgumentTypeError(f"must be in (0, 1], got {text!r}")
    return x


def output_path(text: str | None) -> str | None:
    """``None`` for stdout (no option or ``-``), else the path."""
    return None if text in (None, "-") else text


def robot_value(text: str) -> tuple[str, str]:
    """argparse type: ``ROBOT=VALUE`` (an image path, a stream, a topic)."""
    robot, sep, value = text.partition("=")
    if not sep or not robot or not value:
        raise argparse.ArgumentTypeError(f"expected ROBOT=VALUE, got {text!r}")
    return robot, value


def robot_map(pairs: list[tuple[str, str]], option: str) -> dict[str, str]:
    """``{robot: value}`` from repeated ``ROBOT=VALUE`` options; a robot given twice is an error."""
    from ..errors import InputError

    out: dict[str, str] = {}
    for robot, value in pairs:
        if robot in out:
            raise InputError(f"{option} given twice for robot {robot!r}")
        out[robot] = value
    return out


def int_in_range(lo: int, hi: int | None = None, what: str = "value"):
    """argparse type: an integer in ``lo..hi`` (no upper bound if ``hi`` is None)."""

    def parse(text: str) -> int:
        try:
            n = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"not an integer: {text!r}") from None
        if n < lo or (hi is not None and n > hi):
            bound = f"in {lo}..{hi}" if hi is not None else f">= {lo}"
            raise argparse.ArgumentTypeError(f"{what} must be {bound}, got {text!r}")
        return n

    return parse


def _parent() -> argparse.ArgumentParser:
    return argparse.ArgumentParser(add_help=False)


RIG = _parent()
RIG.add_argument("--rig", required=True, metavar="FILE",
                 help="rig file (YAML or JSON): each robot's camera and the markers it carries")

PAIR = _parent()
PAIR.add_argument("--source", metavar="ROBOT",
                  help="robot p, whose pose is estimated (optional for a two-robot rig: the first robot)")
PAIR.add_argument("--target", metavar="ROBOT",
                  help="robot q, in whose camera frame the pose is given (optional for a two-robot rig)")

TEAM = _parent()
TEAM.add_argument("--reference", metavar="ROBOT",
                  help="team mode: every robot's pose in this robot's frame (default: the rig's first robot); "
                       "a rig of more than two robots without --source/--target is always a team")


def team_mode(rig: object, args: argparse.Namespace) -> bool:
    """Whether to localize the whole team: ``--reference`` given, or a rig
    of more than two robots and no ``--source``/``--target``."""
    if args.reference is not None:
        if args.source is not None or args.target is not None:
            from ..errors import InputError

            raise InputError("--reference (a team) and --source/--target (a pair) exclude each other")
        return True
    return len(rig.robots) > 2 and args.source is None and args.target is None  # type: ignore[attr-defined]


NOISE = _parent()
NOISE.add_argument("--pixel-sigma", type=positive_float, default=1.0, metavar="PX",
                   help="detection noise in pixels, behind every covariance and consistency test (default 1.0)")
NOISE.add_argument("--confidence", type=unit_interval, default=0.99, metavar="P",
                   help="confidence of the chi-square test each estimate must pass (default 0.99; 1 disables it)")

TRUST = _parent()
TRUST.add_argument("--allow-unverified", action="store_true",
                   help="accept a pose from exactly three markers, which nothing can verify (several poses fit "
                        "exactly); without it such a pose is an error")

OUTPUT = _parent()
OUTPUT.add_argument("--output", "-o", metavar="FILE", help="write the result JSON here instead of stdout")

PROGRESS = _parent()
PROGRESS.add_argument("--no-progress", dest="progress", action="store_false", help="no progress bars")

SEED = _parent()
SEED.add_argument("--seed", type=int, default=0, help="random seed (default 0); same seed, same results")

LIVE = _parent()
LIVE.add_argument("--domain", metavar="N", default=None,
                  help="DDS domain id, as ROS 2's ROS_DOMAIN_ID (0-232; default: $ROS_DOMAIN_ID, else 0)")
LIVE.add_argument("--loopback", action="store_true",
                  help="keep DDS on this machine (loopback interface, no multicast; also MUTLOC_DDS_LOOPBACK=1): "
                       "for tests and demos")


def loopback_wanted(args: argparse.Namespace) -> bool:
    """``--loopback`` given, or ``MUTLOC_DDS_LOOPBACK`` set to 1/true/yes."""
    import os

    return bool(args.loopback) or os.environ.get("MUTLOC_DDS_LOOPBACK", "").strip().lower() in ("1", "true", "yes")


def live_domain(args: argparse.Namespace) -> int:
    """``--domain``, else ``$ROS_DOMAIN_ID``, else 0 (checked: one line when it is not a domain id)."""
    import os

    from ..errors import InputError
    from ..live.dds import check_domain

    if args.domain is not None:
        return check_domain(args.domain)
    env = os.environ.get("ROS_DOMAIN_ID", "").strip()
    if not env:
        return 0
    try:
        return check_domain(env)
    except InputError:
        raise InputError(f"ROS_DOMAIN_ID must be an integer from 0 to 232, got {env!r}") from None


ODOMETRY = _parent()
ODOMETRY.add_argument("--odometry", action="append", type=robot_value, default=[], metavar="NAME=SOURCE",
                      help="robot NAME's odometry, the pose of its robot frame in its own odometry frame on its own "
                           "clock (repeatable): a TUM file (time tx ty tz qx qy qz qw), bag:/TOPIC (a "
                           "nav_msgs/msg/Odometry topic of the robot's bag) or, live, ros:/TOPIC; only the motion "
                           "between two of its poses is used")
ODOMETRY.add_argument("--odometry-noise", metavar="KEY=V[,KEY=V...]", default=None,
                      help="the odometry's noise where its messages give no covariance, a random walk per axis: "
                           "distance (m after 1 m travelled, default 0.02), deg_per_m (degrees after 1 m, "
                           "default 1), turn (rad after 1 rad turned, default 0.02), floor_m (m after 1 s, "
                           "default 0.001), floor_deg (degrees after 1 s, default 0.05)")

#: SOURCE prefix of a live odometry topic (received over DDS).
ROS_PREFIX = "ros:"


def odometry_noise(text: str | None):
    """The :class:`~mutloc.core.odometry.OdometryNoise` of ``--odometry-noise``
    (the defaults for the keys not given); OdometryError naming a bad key or value."""
    import dataclasses

    from ..core.odometry import OdometryNoise
    from ..errors import OdometryError

    if text is None:
        return OdometryNoise()
    keys = [f.name for f in dataclasses.fields(OdometryNoise)]
    given: dict[str, float] = {}
    for part in text.split(","):
        key, sep, value = part.strip().partition("=")
        key = key.strip().replace("-", "_")
        if not sep or key not in keys:
            raise OdometryError(f"--odometry-noise {part.strip()!r}: expected KEY=VALUE with KEY one of "
                                f"{', '.join(keys)}")
        if key in given:
            raise OdometryError(f"--odometry-noise: {key} given twice")
        try:
            given[key] = float(value)
        except ValueError:
            raise OdometryError(f"--odometry-noise {key}={value.strip()}: not a number") from None
    return OdometryNoise(**given)


def _robot_bag(args: argparse.Namespace, robot: str) -> str | None:
    """The bag of ``robot``'s stream (its cameras' streams given with a --topic), if any."""
    from ..errors import OdometryError

    streams = getattr(args, "stream", None) or []
    topics = {k for k, _ in getattr(args, "topic", None) or []}
    bags = sorted({path for key, path in streams if key.split("/", 1)[0] == robot and key in topics})
    if len(bags) > 1:
        raise OdometryError(f"--odometry {robot}=bag:...: robot {robot!r} has several bags ({', '.join(bags)}); "
                            f"give its odometry as a TUM file")
    return bags[0] if bags else None


def odometry_options(args: argparse.Namespace, rig: object, live: bool = False) -> dict:
    """``--odometry`` per robot: ``{robot: Odometry}`` of each TUM file or bag
    topic (``bag:/TOPIC``: a topic of the robot's bag, its ``--stream`` with
    ``--topic``), and, ``live``, ``{robot: TOPIC}`` for ``ros:/TOPIC`` (received
    over DDS).  One-line InputError/OdometryError for a robot the rig does not
    have, a robot given twice, a source of the wrong kind or one that cannot
    be read."""
    from ..errors import OdometryError
    from ..track.odometry import BAG_PREFIX, load_odometry

    noise = odometry_noise(getattr(args, "odometry_noise", None))
    names = list(rig.robots)  # type: ignore[attr-defined]
    out: dict = {}
    for robot, source in robot_map(getattr(args, "odometry", None) or [], "--odometry").items():
        if robot not in names:
            raise OdometryError(f"--odometry {robot}={source}: no robot {robot!r} in the rig "
                                f"(robots: {', '.join(names)})")
        if source.startswith(ROS_PREFIX):
            topic = source[len(ROS_PREFIX):]
            if not live:
                raise OdometryError(f"--odometry {robot}={source}: a live topic (ros:/TOPIC) is for the localizer; "
                                    f"give a TUM file or bag:/TOPIC")
            if not topic.startswith("/") or len(topic) < 2:
                raise OdometryError(f"--odometry {robot}={source}: a live topic is ros:/TOPIC")
            out[robot] = topic
            continue
        if live and source.startswith(BAG_PREFIX):
            raise OdometryError(f"--odometry {robot}={source}: live, there is no bag; give ros:/TOPIC or a TUM file")
        bag = _robot_bag(args, robot) if source.startswith(BAG_PREFIX) else None
        try:
            out[robot] = load_odometry(source, robot, bag=bag, noise=noise)
        except OdometryError as exc:
            raise OdometryError(f"--odometry {robot}: {exc}") from None
    return out
