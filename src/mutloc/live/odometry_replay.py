"""A robot's odometry played from TUM files as ``nav_msgs/msg/Odometry`` over
DDS, in real time: what a robot's odometry driver publishes, for ``mutloc
demo --live --odometry`` and tests (not a command of the CLI).

    python -m mutloc.live.odometry_replay --domain N [--loopback] --start-at T
        --odometry NAME=FILE.tum [--odometry NAME2=FILE2.tum ...] [--duration S]

Each file's sample at time ``t`` (seconds from the recording's start) goes
out at wall-clock time ``T + t`` on ``/NAME/odom``, stamped ``T + t`` (as a
driver stamps its samples), ``child_frame_id`` NAME, ``header.frame_id``
``NAME/odom``, its covariance all zeros (none given: the localizer uses
``--odometry-noise``).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

__all__ = ["odometry_topic", "main"]


def odometry_topic(robot: str) -> str:
    """``/NAME/odom``: where the replay publishes robot NAME's odometry."""
    return f"/{robot}/odom"


def main(argv: list[str] | None = None) -> int:
    from ..io.trajectory import read_tum
    from .dds import Bus, check_domain
    from .messages import odometry_message, ros_types

    ap = argparse.ArgumentParser(prog="python -m mutloc.live.odometry_replay", description=__doc__.split("\n\n")[0])
    ap.add_argument("--domain", required=True)
    ap.add_argument("--loopback", action="store_true")
    ap.add_argument("--start-at", type=float, required=True, metavar="T")
    ap.add_argument("--odometry", action="append", required=True, metavar="NAME=FILE")
    ap.add_argument("--duration", type=float, default=None, metavar="S")
    args = ap.parse_args(argv)
    plan = []
    for item in args.odometry:
        name, _, path = item.partition("=")
        times, poses = read_tum(Path(path))
        plan += [(float(t), name, poses[k]) for k, t in enumerate(times)]
    plan.sort(key=lambda x: x[0])
    bus = Bus(check_domain(args.domain), loopback=args.loopback)
    T = ros_types()
    writers = {n: bus.writer(odometry_topic(n), T.Odometry) for n in {n for _, n, _ in plan}}
    end = args.start_at + (args.duration if args.duration is not None else (plan[-1][0] if plan else 0.0) + 1.0)
    sent = 0
    try:
        for t, name, pose in plan:
            at = args.start_at + t
            if at > end:
                break
            while time.time() < at:
                time.sleep(min(0.002, max(0.0, at - time.time())))
            writers[name].write(odometry_message(at, pose, None, name, f"{name}/odom"))
            sent += 1
    except KeyboardInterrupt:
        pass
    finally:
        bus.close()
    print(f"odometry replay: {sent} messages sent", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
