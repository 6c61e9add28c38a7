"""Simulated odometry: a robot's true motion with a seeded random-walk drift.

What ``mutloc simulate`` writes as ``odometry_NAME.tum``: the robot frame's
pose in an odometry frame that starts at its first true pose, sampled at
``rate`` Hz, each sample interval's true motion disturbed by an independent
error (rotation vector on the left, then translation, in the robot frame at
the interval's start -- the SPEC's convention) of per-axis variance
``(drift_pct / 100)**2 * d`` (m^2) and ``radians(deg_per_m)**2 * d``
(rad^2) for the ``d`` metres travelled in it: a random walk of about
``drift_pct`` % of the distance (and ``deg_per_m`` degrees) after one metre,
growing with the square root of the distance.  This is the model
:class:`mutloc.core.odometry.OdometryNoise` states (``distance`` = the
fraction, ``turn`` 0), so a test can check the increments' covariance
against it.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Callable

import numpy as np

from ..core.geometry import so3_exp
from ..core.pose import Pose
from ..errors import InputError
from ..io.trajectory import write_tum

__all__ = ["drifting_odometry", "odometry_times", "write_odometry", "check_clock_offsets", "DEFAULT_DRIFT",
           "DEFAULT_RATE"]

#: ``mutloc simulate``'s default drift: 1 % of the distance and 0.3 degrees per metre.
DEFAULT_DRIFT = (1.0, 0.3)
#: ``mutloc simulate``'s default odometry rate (Hz).
DEFAULT_RATE = 50.0


def odometry_times(start: float, end: float, rate: float) -> np.ndarray:
    """Stamps at ``rate`` Hz from ``start`` through at least ``end``."""
    if not (math.isfinite(rate) and rate > 0):
        raise InputError(f"odometry rate must be a finite number > 0, got {rate!r}")
    n = int(math.ceil((end - start) * rate - 1e-9)) + 1
    return start + np.arange(max(n, 2)) / rate


def drifting_odometry(pose: Callable[[float], Pose], times: np.ndarray, *, drift_pct: float = DEFAULT_DRIFT[0],
                      deg_per_m: float = DEFAULT_DRIFT[1], seed: int = 0, stream: int = 0) -> Pose:
    """The odometry poses (a stack) at ``times`` of a robot whose true pose
    at time t (in any fixed frame) is ``pose(t)``; see the module's text.
    ``seed`` and ``stream`` (e.g. the robot's index) seed the drift."""
    for v, what in ((drift_pct, "odometry drift percent"), (deg_per_m, "odometry drift degrees per metre")):
        if not (math.isfinite(v) and v >= 0):
            raise InputError(f"{what} must be a finite number >= 0, got {v!r}")
    rng = np.random.default_rng([int(seed) & 0xFFFFFFFF, 5150, int(stream)])
    truth = [pose(float(t)) for t in times]
    lin, ang = drift_pct / 100.0, math.radians(deg_per_m)
    R, t = np.eye(3), np.zeros(3)
    Rs, ts = [R], [t]
    for k in range(len(times) - 1):
        d = truth[k].inverse() @ truth[k + 1]
        dist = float(np.linalg.norm(d.t))
        dR = so3_exp(rng.normal(0.0, ang * math.sqrt(dist), 3)) @ d.R
        dt = d.t + rng.normal(0.0, lin * math.sqrt(dist), 3)
        t = R @ dt + t
        R = R @ dR
        Rs.append(R)
        ts.append(t)
    return Pose(np.array(Rs), np.array(ts))


def check_clock_offsets(clock_offset: dict[str, float] | None, names: list[str] | tuple[str, ...],
                        reference: str) -> dict[str, float]:
    """``clock_offset`` checked: robots of ``names`` but not ``reference`` (whose clock is the reference's),
    finite seconds."""
    out = {}
    for robot, s in (clock_offset or {}).items():
        if robot not in names:
            raise InputError(f"clock offset: unknown robot {robot!r} (the simulated robots are {', '.join(names)})")
        if robot == reference:
            raise InputError(f"clock offset of {robot}: {robot} is the reference, whose clock the others' "
                             f"offsets are to")
        if not math.isfinite(float(s)):
            raise InputError(f"clock offset of {robot} must be a finite number of seconds, got {s!r}")
        out[robot] = float(s)
    return out


def write_odometry(out_dir: Path, poses: dict[str, Callable[[float], Pose]], end: float, *, rate: float,
                   drift: tuple[float, float], seed: int, clock_offset: dict[str, float]) -> list[str]:
    """``odometry_NAME.tum`` for each robot of ``poses`` (its true pose over
    time) that moves over ``[0, end]``: its drifting odometry at ``rate`` Hz
    (see the module's text), stamped on its own clock (true time minus its
    ``clock_offset``, the offset that puts its stamps on the reference's
    clock).  Returns the names of the files written."""
    times = odometry_times(0.0, end, rate)
    written = []
    for k, (name, fn) in enumerate(poses.items()):
        truth = [fn(float(t)) for t in times]
        if max(max(p.translation_error(truth[0]), np.abs(p.R - truth[0].R).max()) for p in truth) < 1e-9:
            continue  # standing still: no odometry to speak of
        known = dict(zip(times.tolist(), truth))
        odo = drifting_odometry(lambda t: known[t], times, drift_pct=drift[0], deg_per_m=drift[1], seed=seed,
                                stream=k)
        off = clock_offset.get(name, 0.0)
        fname = f"odometry_{name}.tum"
        write_tum(out_dir / fname, times - off, odo,
                  comment=f"timestamp tx ty tz qx qy qz qw  (simulated odometry of {name}: its frame in its "
                          f"odometry frame, on its own clock (offset {off:g} s to the reference's), {rate:g} Hz, "
                          f"random-walk drift {drift[0]:g} % and {drift[1]:g} deg after 1 m)")
        written.append(fname)
    return written
