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
from typing import Callable

import numpy as np

from ..core.geometry import so3_exp
from ..core.pose import Pose
from ..errors import InputError

__all__ = ["drifting_odometry", "odometry_times", "DEFAULT_DRIFT", "DEFAULT_RATE"]

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
                      deg_per_m: float = DEFAULT_DRIFT[1], seed: int = 0) -> Pose:
    """The odometry poses (a stack) at ``times`` of a robot whose true pose
    at time t (in any fixed frame) is ``pose(t)``; see the module's text."""
    for v, what in ((drift_pct, "odometry drift percent"), (deg_per_m, "odometry drift degrees per metre")):
        if not (math.isfinite(v) and v >= 0):
            raise InputError(f"{what} must be a finite number >= 0, got {v!r}")
    rng = np.random.default_rng([int(seed) & 0xFFFFFFFF, 5150])
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
