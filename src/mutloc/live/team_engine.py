"""The team tracker as the live localizer runs it (:class:`TeamEngine`: each
record fused into one row per robot, the rows made final for the files as
the smoother allows), and :func:`warm_up`: throwaway trackers run before the
first message so that the compiled kernels are loaded then."""

from __future__ import annotations

import math
from dataclasses import replace
from typing import Any, Callable

from ..core.consistency import DEFAULT_CONFIDENCE
from ..core.observations import ObservationSet
from ..core.pose import Pose
from ..core.rig import Rig
from ..errors import MutlocError
from ..track.filtering import FilterOptions
from ..track.rows import TrackRow

__all__ = ["TeamEngine", "warm_up"]


class TeamEngine:
    """The team tracker (two robots: a team of two), each record one row per robot (as ``track_team_log``)."""

    def __init__(self, rig: Rig, reference: str, pixel_sigma: float, confidence: float, options: FilterOptions,
                 sink: Callable[[TrackRow, str], None] | None) -> None:
        from ..track.team import TeamTracker
        from ..track.team import RowEmitter

        self.tracker = TeamTracker(rig, reference, pixel_sigma=pixel_sigma, confidence=confidence, options=options)
        self.robots, self.reference = list(self.tracker.robots), reference

        def final(record: dict[str, TrackRow], _: Any) -> None:
            if sink is not None:
                for r, row in record.items():
                    sink(row, r)

        # rows handed to ``sink`` once final (after the smoother's lag), as track_team_log does
        self._emitter = RowEmitter(self.tracker, final)

    def step(self, t: float, obs: ObservationSet, smooth: bool = True) -> dict[str, TrackRow]:
        """The record's rows, their poses the causal filter's (published at once).  ``smooth``: the
        smoother makes final up to two of the records it may (this one's turn and one deferred);
        False: none (deferred, see :meth:`backlog`)."""
        rows = self.tracker.step(t, obs)
        live = {r: replace(row) for r, row in rows.items()}  # the smoother may revise the rows later
        self._emitter.add(rows, True)
        if smooth or self.tracker.history is None:
            self.smooth(2)
        return live

    def backlog(self) -> int:
        """Records past the smoother's lag not yet made final: their smoothing deferred (0 without it)."""
        sm = self.tracker.history
        return 0 if sm is None else max(0, len(sm) - sm.first - sm.lag - 1)

    def smooth(self, most: int, smooth: bool = True) -> int:
        """Make final at most ``most`` records, smoothed (``smooth`` False: as the causal filter gave
        them); returns how many were."""
        sm = self.tracker.history
        if sm is None:
            self._emitter.emit()
            return 0
        first = sm.first
        self._emitter.emit(most=most, smooth=smooth)
        return sm.first - first

    def involved(self, observer: str, obs: ObservationSet) -> list[str]:
        """The robots a record is about: its observer and the robots whose markers it saw."""
        owner = self.tracker.rig.owner
        seen = {observer, *(owner(m) for m in set(obs.marker) if m is not None)}
        return [r for r in self.robots if r in seen]

    def finish(self) -> None:
        self._emitter.emit(end=True)


def warm_up(rig: Rig, names: list[str], reference: str) -> None:
    """Run throwaway trackers on synthetic records (the first two robots
    2 m apart, facing each other): each camera's frames at its own time
    (a start from several records), and both cameras' frames together (a
    start from one record's joint solve), so that the compiled kernels
    are loaded before the first message rather than while messages wait
    (about a second in a new process; the joint solve's alone 90 ms).
    The chi-square quantiles' library (scipy.stats) is imported here too:
    a team's first joint solve of three robots or more needs it, and its
    import took 4 s of a loaded machine inside a record, every message
    waiting."""
    from ..core.consistency import chi2_quantile

    chi2_quantile(DEFAULT_CONFIDENCE, 6)
    a, b = names[0], names[1]
    if rig.robot(a).is_body or rig.robot(b).is_body:
        T = Pose.from_rotvec([0.0, 0.0, math.pi], [2.0, 0.0, 0.0])  # bodies (z up): a ahead of b, facing it
    else:
        T = Pose.from_rotvec([0.0, math.pi, 0.0], [0.0, 0.0, 2.0])  # T_ba: a in front of b, facing it
    seen = {}
    for observer, other, to_obs in ((a, b, T.inverse()), (b, a, T)):
        robot, markers = rig.robot(other), list(rig.robot(other).markers)
        # the observer's camera that looks most towards the other robot
        cam, mount = max(rig.robot(observer).mounts.items(),
                         key=lambda cm: float(cm[1].pose.R[:, 2] @ to_obs.t))
        X = mount.pose.inverse().apply(to_obs.apply(robot.marker_positions(markers)))
        key = rig.robot(observer).observer_key(cam)
        try:
            uv = mount.camera.project(X)
            seen[observer] = ObservationSet([key] * len(markers), markers, uv)
        except (MutlocError, ValueError, FloatingPointError):
            return  # a rig this pose does not suit: the first messages pay instead
    both = ObservationSet.concatenate([seen[a], seen[b]])
    for first in (False, True):
        engine = TeamEngine(rig, reference, 1.0, DEFAULT_CONFIDENCE, FilterOptions(), None)
        try:
            if first:
                engine.step(-1 / 60, both.with_time(-1 / 60))
            for k in range(12):
                observer = (a, b)[k % 2]
                engine.step(k / 60, ObservationSet.from_dict(seen[observer].to_dict(), time=k / 60))
            engine.step(0.25, both.with_time(0.25))
            engine.finish()
        except (MutlocError, ValueError, FloatingPointError):
            pass  # a rig this pose does not suit: the first messages pay instead
