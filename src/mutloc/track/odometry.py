"""Reading a robot's odometry (SPEC "The robots' own motion and clocks").

A source is a TUM file (``time tx ty tz qx qy qz qw``: the robot frame's pose
in its odometry frame, read by :func:`mutloc.io.trajectory.read_tum`) or a
``nav_msgs/msg/Odometry`` topic of a ROS 1 or ROS 2 bag (``bag:/p/odom``: a
topic of the robot's own bag, the one being tracked).  Each gives a
:class:`mutloc.core.odometry.Odometry`; its bad samples are rejected and
counted there.  What cannot be used at all is an
:class:`~mutloc.errors.OdometryError` of one line naming the file or topic
and the line or stamp: a malformed TUM line, a missing topic or one of
another type, a message whose ``child_frame_id`` is set and is not the
robot's frame, too few usable samples.
"""

from __future__ import annotations

import warnings
from pathlib import Path
from typing import Any

import numpy as np

from ..core.odometry import Odometry, OdometryNoise
from ..core.pose import Pose
from ..errors import FileFormatError, OdometryError

__all__ = ["BAG_PREFIX", "read_tum_odometry", "read_bag_odometry", "load_odometry"]

#: SOURCE prefix of a topic of the robot's bag.
BAG_PREFIX = "bag:"


def read_tum_odometry(path: str | Path, *, noise: OdometryNoise | None = None, **bounds: Any) -> Odometry:
    """The odometry of a TUM file (``bounds``: :class:`Odometry`'s ``max_speed``,
    ``max_turn_rate``, ``max_gap``).  A line that is not 8 finite numbers with a
    unit quaternion is refused with its line number; a last line cut by a kill
    (no end of line, cut inside a number) is dropped with a warning."""
    from ..io.trajectory import read_tum

    p = Path(path).expanduser()
    if p.is_dir():
        raise OdometryError(f"{p}: a folder, not a TUM odometry file")
    try:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            times, poses = read_tum(p)
    except FileFormatError as exc:
        raise OdometryError(str(exc)) from None
    for w in caught:
        warnings.warn(str(w.message), stacklevel=2)
    return Odometry(times, poses, source=str(p), noise=noise, **bounds)


def _frame(name: str) -> str:
    return name.strip().strip("/")


def read_bag_odometry(bag: str | Path, topic: str, robot: str, *, noise: OdometryNoise | None = None,
                      **bounds: Any) -> Odometry:
    """The ``nav_msgs/msg/Odometry`` messages of ``topic`` in a ROS 1 or ROS 2
    bag, stamped by their header (the record time where that is zero), with
    their covariances (all zeros: none given, :class:`OdometryNoise` used).
    ``child_frame_id``, where set, must be ``robot`` (the pose is the robot
    frame's).  A message that cannot be decoded is rejected as invalid."""
    from ..io.ros import ODOMETRY_TYPE, odometry_sample
    from .sources import open_bag

    p = Path(bag)
    where = f"{p}:{topic}"
    reader = open_bag(p)
    times, Rs, ts, covs = [], [], [], []
    try:
        conns = [c for c in reader.connections if c.topic == topic]
        if not conns:
            have = sorted({c.topic for c in reader.connections if c.msgtype == ODOMETRY_TYPE})
            raise OdometryError(f"{p}: no topic {topic!r} (odometry topics: {', '.join(have) or 'none'})")
        other = sorted({c.msgtype for c in conns if c.msgtype != ODOMETRY_TYPE})
        if other:
            raise OdometryError(f"{where}: a {other[0]} topic, not {ODOMETRY_TYPE}")
        for conn, record, raw in reader.messages(connections=conns):
            try:
                t, pose, cov, child = odometry_sample(reader.deserialize(raw, conn.msgtype))
            except Exception:  # noqa: BLE001 -- a corrupt message is a rejected sample, not the end
                t, pose, cov, child = record * 1e-9, Pose(np.full((3, 3), np.nan), np.zeros(3)), np.zeros((6, 6)), ""
            if t == 0.0:
                t = record * 1e-9
            if _frame(child) and _frame(child) != robot:
                raise OdometryError(f"{where}: child_frame_id {child!r} at stamp {t:.9f} is not robot {robot!r}'s "
                                    f"frame (the odometry must give the pose of the robot frame, {robot!r})")
            times.append(t)
            Rs.append(pose.R)
            ts.append(pose.t)
            covs.append(cov)
    finally:
        reader.close()
    if not times:
        raise OdometryError(f"{where}: no messages")
    return Odometry(np.array(times), Pose(np.array(Rs), np.array(ts)), np.array(covs), source=where, noise=noise,
                    **bounds)


def load_odometry(source: str, robot: str, *, bag: str | Path | None = None, noise: OdometryNoise | None = None,
                  **bounds: Any) -> Odometry:
    """Robot ``robot``'s odometry from ``source``: ``bag:/TOPIC`` (a topic of
    ``bag``, the robot's bag) or a TUM file."""
    if source.startswith(BAG_PREFIX):
        topic = source[len(BAG_PREFIX):]
        if not topic.startswith("/") or len(topic) < 2:
            raise OdometryError(f"odometry of {robot!r}: {source!r}: a bag topic is bag:/TOPIC")
        if bag is None:
            raise OdometryError(f"odometry of {robot!r}: {source!r} names a topic of the robot's bag, and "
                                f"{robot!r} has none (its stream is not a ROS bag)")
        return read_bag_odometry(bag, topic, robot, noise=noise, **bounds)
    return read_tum_odometry(source, noise=noise, **bounds)
