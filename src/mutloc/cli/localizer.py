"""``mutloc localizer``: every robot's observations in over DDS, poses out (SPEC "Live operation")."""

from __future__ import annotations

import argparse

from ._common import LIVE, NOISE, ODOMETRY, RIG, live_domain, loopback_wanted, nonnegative_float, positive_float

ORDER = 36


def add_parser(subparsers: argparse._SubParsersAction) -> argparse.ArgumentParser:
    """Register ``localizer``."""
    p = subparsers.add_parser(
        "localizer", parents=[RIG, LIVE, NOISE, ODOMETRY],
        help="live: fuse every robot's observations (from mutloc node, over DDS) and publish the poses",
        description="Subscribes to /mutloc/NAME/observations of every robot of the rig, fuses each message at its "
        "own capture time and publishes /mutloc/NAME_in_REF (geometry_msgs/PoseWithCovarianceStamped), /tf and "
        "/diagnostics (ROS 2 topics over DDS; no ROS installation needed). Messages of another rig, malformed, "
        "stamped in the future, duplicated or too late are counted in /diagnostics, never fused. --odometry "
        "NAME=ros:/TOPIC subscribes to a robot's nav_msgs/msg/Odometry too: the motion between two of its poses moves "
        "the robot between observations (bad odometry refused and counted in /diagnostics; --out writes what was "
        "used to DIR/odometry_NAME.tum for the replay).",
    )
    p.add_argument("--reference", metavar="NAME",
                   help="the frame of the poses (default: with two robots the second robot of the rig, as track; "
                        "with more, the first)")
    p.add_argument("--out", metavar="DIR",
                   help="also write what track writes (trajectory files) and the observations received "
                        "(DIR/log.jsonl: replay with mutloc track --observations DIR/log.jsonl)")
    p.add_argument("--max-coast", type=positive_float, default=1.0, metavar="S",
                   help="a robot's pose is published while the observations of the last S seconds tie it to the "
                        "reference (three distinct camera-marker observations per link; default 1); a robot without "
                        "observations for S seconds is STALE")
    p.add_argument("--max-clock-skew", type=nonnegative_float, default=0.05, metavar="S",
                   help="observations stamped more than S seconds in the future are refused (default 0.05)")
    p.add_argument("--reorder", type=nonnegative_float, default=0.03, metavar="S",
                   help="a message waits at most S seconds for earlier ones of the other robots (default 0.03); "
                        "one stamped before a record already fused is dropped as late")
    p.add_argument("--tolerance", type=nonnegative_float, default=0.005, metavar="S",
                   help="messages of different robots stamped within S seconds make one record at their mean time, "
                        "as track pairs two cameras' frames (default 0.005; 0: every message its own record)")
    p.add_argument("--max-lag", type=nonnegative_float, default=0.1, metavar="S",
                   help="falling behind: a message more than S seconds behind its capture is shed (not fused, "
                        "counted) when a newer one of the same camera is waiting; each camera's newest is always "
                        "fused (default 0.1)")
    p.add_argument("--clock-offsets", choices=("estimate",), metavar="estimate",
                   help="estimate each robot's clock offset to the reference's from the observations of moving "
                        "robots (in the localizer's slack, over windows of recent observations), correct every "
                        "stamp of that robot by it before fusing (and before --max-clock-skew), report it in "
                        "/diagnostics (clock_offset_s, clock_offset_sigma_s) and, with --out, DIR/clock_offsets.json")
    p.add_argument("--duration", type=positive_float, metavar="S", help="stop after S seconds (default: Ctrl-C)")
    return p


def run(args: argparse.Namespace) -> int:
    """Run the localizer until --duration or Ctrl-C."""
    import sys

    from ..live.localizer import run_localizer

    domain = live_domain(args)
    odometry, noise = _odometry(args)
    try:
        result = run_localizer(args.rig, reference=args.reference, domain=domain, out=args.out,
                               max_coast=args.max_coast, max_clock_skew=args.max_clock_skew, reorder=args.reorder,
                               tolerance=args.tolerance, max_lag=args.max_lag,
                               pixel_sigma=args.pixel_sigma, confidence=args.confidence, loopback=loopback_wanted(args),
                               duration=args.duration, ready=lambda loc: _started(loc, domain),
                               odometry=odometry, odometry_noise=noise,
                               clock_offsets=args.clock_offsets == "estimate",
                               notify=lambda line: print(f"localizer: {line}", file=sys.stderr, flush=True))
    except KeyboardInterrupt as exc:
        done = exc.args[0] if exc.args else None
        if done is None:
            raise
        print(f"interrupted: {done.summary()}", file=sys.stderr)
        return 130
    print(result.summary())
    return 0


def _odometry(args: argparse.Namespace) -> tuple[dict, object]:
    """``--odometry`` (``{robot: topic}`` for ros:/TOPIC, an Odometry for a TUM file) and ``--odometry-noise``."""
    from ..api import load_rig
    from ._common import odometry_noise, odometry_options

    if not args.odometry:
        return {}, None
    return odometry_options(args, load_rig(args.rig), live=True), odometry_noise(args.odometry_noise)


def _started(loc, domain: int) -> None:
    import sys

    topics = ", ".join(f"/mutloc/{r}_in_{loc.reference}" for r in loc.tracked)
    static = ", /tf_static" if any(r.is_body for r in loc.rig.robots.values()) else ""  # (the cameras' mounts)
    odo = "" if loc.odometry is None else "; odometry from " + ", ".join(
        f"{r} {t}" for r, t in loc.odometry.topics.items())
    print(f"localizer: rig_id {loc.rig_id}, domain {domain}; publishing {topics}, /tf{static}, /diagnostics "
          f"(Ctrl-C stops){odo}", file=sys.stderr, flush=True)
