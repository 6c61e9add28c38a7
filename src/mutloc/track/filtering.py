"""How a track is filtered (:class:`FilterOptions`), shared by pairs and
teams -- a pair is a team of two, tracked by
:class:`mutloc.track.team.TeamTracker` (SPEC "Filtered tracking"): the
constant-velocity filter (``--filter cv``, the default) or every frame on
its own (``--filter none``), the motion noise, when a track restarts or is
lost, the smoother's lag and how far a start may bridge records of cameras
that are not synchronized; and a pair's observations in the filter's form
(:func:`pair_problem`)."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Mapping

import numpy as np

from ..core.estimate import PairProblem
from ..core.filter import MotionNoise
from ..core.odometry import Odometry
from ..core.observations import PairObservations
from ..core.rays import pair_rays
from ..errors import InputError, positive_number
from .solving import lost_reason

__all__ = ["DEFAULT_SMOOTH_LAG", "DEFAULT_START_WINDOW", "FILTERS", "FilterOptions", "MIN_START_DOF",
           "lost_reason", "pair_problem"]

#: ``--filter`` choices: the constant-velocity filter, or every frame on its own.
FILTERS = ("cv", "none")
#: Frames after each frame that inform its reported pose by default (1/3 s
#: at 30 fps): the inputs are recorded, and on the issue's sequences this
#: fixed-lag smoother halves the causal filter's error (README "Filtered tracking").
DEFAULT_SMOOTH_LAG = 10
#: Seconds of records a track may start from together (see FilterOptions).
DEFAULT_START_WINDOW = 0.15
#: Degrees of freedom a start from several records must leave for its test:
#: a wrong detection among them must be able to show.
MIN_START_DOF = 4


@dataclass(frozen=True)
class FilterOptions:
    """How a track is filtered (documented defaults).

    ``kind``: ``"cv"`` (constant velocity) or ``"none"``; ``noise``: the
    motion model's :class:`~mutloc.core.filter.MotionNoise`;
    ``reinit_after``: rejected frames in a row after which a frame solved
    on its own restarts the track; ``lost_sigma_t`` (m) and
    ``lost_sigma_r_deg``: a predicted 1-sigma beyond these loses the track;
    ``smooth_lag``: frames after each frame that also inform its reported
    pose (fixed-lag RTS smoothing; 0 = the causal filter's pose; None, the
    default: ``DEFAULT_SMOOTH_LAG`` with the filter, 0 without);
    ``measure_noise``: the gain uses the detections' measured noise when it
    is clearly below ``pixel_sigma`` (see
    :attr:`~mutloc.core.team_filter.TeamFilter.gain_sigma`);
    ``start_window`` (s): a track may also start from the records of the
    last ``start_window`` seconds together -- cameras that are not
    synchronized, each record one camera's frame -- their pose and velocity
    fitted with every observation at its own time (0: only from one record).
    ``odometry``: robots' own odometry (name ->
    :class:`~mutloc.core.odometry.Odometry`, stamps on the reference's
    clock), the motion between records where it covers them (needs the
    filter).
    """

    kind: str = "cv"
    noise: MotionNoise = field(default_factory=MotionNoise)
    reinit_after: int = 3
    lost_sigma_t: float = 0.5
    lost_sigma_r_deg: float = 20.0
    smooth_lag: int | None = None
    measure_noise: bool = True
    start_window: float = DEFAULT_START_WINDOW
    odometry: Mapping[str, Odometry] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if self.kind not in FILTERS:
            raise InputError(f"filter must be one of {', '.join(FILTERS)}, got {self.kind!r}")
        if self.smooth_lag is None:
            object.__setattr__(self, "smooth_lag", DEFAULT_SMOOTH_LAG if self.kind == "cv" else 0)
        if not (isinstance(self.reinit_after, int) and self.reinit_after >= 1):
            raise InputError(f"reinit_after must be an integer >= 1, got {self.reinit_after!r}")
        if not (isinstance(self.smooth_lag, int) and self.smooth_lag >= 0):
            raise InputError(f"smooth_lag must be an integer >= 0 (frames), got {self.smooth_lag!r}")
        if self.smooth_lag and self.kind != "cv":
            raise InputError("smoothing (--smooth-lag) needs the filter (--filter cv)")
        if not (isinstance(self.start_window, (int, float)) and 0.0 <= self.start_window < math.inf):
            raise InputError(f"start_window must be a number of seconds >= 0, got {self.start_window!r}")
        if self.odometry and self.kind != "cv":
            raise InputError("odometry (--odometry) is fused by the filter: it needs --filter cv")
        for name, odo in self.odometry.items():
            if not isinstance(odo, Odometry):
                raise InputError(f"odometry of {name!r} must be an Odometry, got {type(odo).__name__}")
        positive_number(self.lost_sigma_t, "lost_sigma_t")
        positive_number(self.lost_sigma_r_deg, "lost_sigma_r_deg")


def pair_problem(pair: PairObservations) -> PairProblem:
    """The named observations of a pair in the filter's form (labels "p saw M1"): pixels, or rays for robots
    with several cameras or any lens (each row through its own camera: :func:`mutloc.core.rays.pair_rays`)."""
    table = pair.table
    obs = pair.parent
    rows = pair.rows
    labels = [f"{obs.observer[r]} saw {obs.marker[r]}" for r in rows.tolist()]
    if table.mounts is not None:
        bearings, frames = pair_rays(table.mounts, [obs.observer[r] for r in rows.tolist()], obs.uv[rows],
                                     labels.__getitem__)
        return PairProblem.trusted(pair.side, np.ascontiguousarray(table.points[pair.points_index]), bearings, None,
                                   None, None, labels, pair.sigma_scale, frames)
    return PairProblem.trusted(pair.side, np.ascontiguousarray(table.points[pair.points_index]), None,
                               np.ascontiguousarray(obs.uv[rows]), table.K, table.dist, labels, pair.sigma_scale)
