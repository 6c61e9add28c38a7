"""Each robot's clock offset estimated while the observations come in (SPEC "The robots' own motion and
clocks": ``localizer --clock-offsets estimate``).

The offline estimator (:mod:`mutloc.track.clocks`) re-runs the team tracker over the whole log some twenty
times; live, the same profile likelihood is evaluated over short windows of recent observations, in
slices of one record, when the caller has nothing else to do:

- the observations are collected as they were stamped (each on its observer's clock) into a window of
  ``window`` seconds (of stamps); a new window starts ``period`` seconds after the last one started
  and only once the last one is evaluated (messages in between are not kept: memory and work bounded);
- a window is evaluated per robot (the others at their current offsets) with the offline cost
  (:class:`~mutloc.track.clocks.OffsetCost`, the causal team tracker's -2 log-likelihood): while no offset
  of the robot is known, first a coarse grid over ``+-search`` s; then three points ``step`` s apart
  around the best (or the current estimate) and the parabola through them, its vertex the window's
  offset and its curvature the window's sigma (``sigma^2 = 2 / cost''``, times :data:`SIGMA_SCALE`:
  discrete events -- an update the gate rejects, a track restarted -- make a short window's cost
  rough, and its curvature alone about half the windows' measured spread), re-centred on the vertex
  (at most ``2 step`` at a time) while the vertex lies outside the three points;
- the window's result counts when the robot moved enough relative to the reference within it
  (``min_motion``, looked at first: one run at the current offset, no search when it did not), the
  curvature is positive and the sigma below ``max_sigma``; the robot's estimate is
  the mean of its last ``keep`` counted windows (disjoint windows: independent data; the last ones only,
  so that it follows a clock that drifts slowly), its sigma the larger of the windows' own (their rms
  over sqrt n) and their spread's (their standard deviation over sqrt n).  A robot with no counted window cannot be determined
  yet (the reason of its last window).

The cost of a window is (points evaluated) x (records in it) tracker steps, per robot but the
reference: three points (sometimes six) of a four-second window every ``period`` (10) s, one step per
message (the localizer's records merge messages of one instant); the first window of a robot, with the
coarse grid, four times that.  Measured (bench/clock_offsets_live.py): over the first 32 s of two robots
at 30 fps, 3-5 ms of CPU per message against the localizer's own 0.7-1.2 ms.  :meth:`OnlineClockOffsets.work` does
it in slices of one record until a deadline, so a caller that runs it only in slack is never made to
fall behind by it.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Callable, Generator
from typing import Any

import numpy as np

from ..core.consistency import DEFAULT_CONFIDENCE
from ..core.observations import ObservationSet
from ..core.rig import Rig
from ..errors import InputError
from .clocks import (
    DEFAULT_MAX_SIGMA,
    DEFAULT_MIN_MOTION,
    DEFAULT_SEARCH,
    ClockOffset,
    OffsetCost,
    shift_records,
)
from .filtering import FilterOptions

__all__ = ["KEEP", "PERIOD", "SIGMA_SCALE", "WINDOW", "OnlineClockOffsets"]

#: Seconds of stamps in one window (2 s windows were measured 4-7 ms off on some scenes, 4 s within 1 ms:
#: docs/benchmarks.md).
WINDOW = 4.0
#: Seconds (of stamps) from one window's start to the next's.
PERIOD = 10.0
#: Counted windows a robot's estimate is the mean of.
KEEP = 10
#: A window's sigma is its cost's curvature's times this: over 2 s windows that sigma is about half the
#: spread of the windows' offsets (measured: bench/clock_offsets_live.py, docs/benchmarks.md).
SIGMA_SCALE = 2.0
#: Coordinate passes over a team's robots in a window while one of them is not yet known.
TEAM_PASSES = 4
_UNDETERMINED = "no window evaluated yet"


class OnlineClockOffsets:
    """The clock offsets of ``rig``'s robots (the expanded rig, as the tracker takes it) to ``reference``'s,
    estimated over windows of the observations given to :meth:`add` (see the module docstring).

    ``window``, ``period`` (s of stamps), ``keep`` (windows), ``search``, ``grid``, ``step`` (s),
    ``max_sigma`` (s), ``min_motion`` (m, degrees): as the module docstring says; ``options``,
    ``pixel_sigma``, ``confidence``: the tracker's."""

    def __init__(self, rig: Rig, reference: str, *, options: FilterOptions | None = None, pixel_sigma: float = 1.0,
                 confidence: float = DEFAULT_CONFIDENCE, window: float = WINDOW, period: float = PERIOD,
                 keep: int = KEEP, search: float = DEFAULT_SEARCH, grid: int = 9, step: float = 0.01,
                 max_sigma: float = DEFAULT_MAX_SIGMA,
                 min_motion: tuple[float, float] = DEFAULT_MIN_MOTION) -> None:
        if reference not in rig.robots:
            raise InputError(f"unknown reference robot {reference!r} (rig has {sorted(rig.robots)})")
        for what, x in (("window", window), ("period", period), ("search", search), ("step", step),
                        ("max_sigma", max_sigma)):
            if isinstance(x, bool) or not isinstance(x, (int, float)) or not (math.isfinite(x) and x > 0):
                raise InputError(f"clock offsets: {what} must be a positive number of seconds, got {x!r}")
        if period < window or step >= search or grid < 3 or keep < 1:
            raise InputError("clock offsets: need period >= window, step < search, grid >= 3 and keep >= 1")
        self.rig, self.reference = rig, reference
        self.robots = [r for r in rig.robots if r != reference]
        self.options = options or FilterOptions()
        self.pixel_sigma, self.confidence = pixel_sigma, confidence
        self.window, self.period, self.search, self.grid, self.step = window, period, search, grid, step
        self.max_sigma, self.min_motion = max_sigma, min_motion
        #: Per robot, its counted windows' ``(offset, sigma)``, newest last.
        self.windows: dict[str, deque] = {r: deque(maxlen=keep) for r in self.robots}
        #: Per robot, why its last window did not count ("" when it did).
        self.reasons: dict[str, str] = {r: _UNDETERMINED for r in self.robots}
        self.evaluated = 0  #: windows evaluated
        self.steps = 0  #: tracker steps taken (records x points)
        self._collecting: list[tuple[float, ObservationSet]] = []
        self._start: float | None = None  # stamp at which the window being collected started
        self._next: float = -math.inf  # stamp from which the next window may start
        self._job: Generator[None, None, None] | None = None

    # -- observations in ------------------------------------------------------

    def add(self, t: float, obs: ObservationSet | None) -> None:
        """An observation message (or record) as stamped: ``t`` on its observers' clocks, uncorrected."""
        if obs is None or not len(obs) or self._job is not None:
            return  # (a window being evaluated: nothing collected meanwhile)
        t = float(t)
        if self._start is None:
            if t < self._next:
                return
            self._start = t
        self._collecting.append((t, obs))
        if t - self._start >= self.window:
            records = sorted(self._collecting, key=lambda r: r[0])
            self._collecting, self._next, self._start = [], self._start + self.period, None
            self._job = self._evaluate(records)

    # -- the work -------------------------------------------------------------

    def pending(self) -> bool:
        """Whether a window waits to be evaluated (:meth:`work`)."""
        return self._job is not None

    def work(self, clock: Callable[[], float] | None = None, until: float = math.inf) -> int:
        """Evaluate the pending window, one tracker step at a time, while ``clock()`` is before ``until``
        (no clock: to its end); returns the steps taken."""
        done = 0
        while self._job is not None and (clock is None or clock() < until):
            try:
                next(self._job)
                done += 1
            except StopIteration:
                self._job = None
        self.steps += done
        return done

    def _evaluate(self, records: list[tuple[float, ObservationSet]]) -> Generator[None, None, None]:
        """Each robot's window offset, the others at their current offsets -- or, in a team with a robot
        not yet known, :data:`TEAM_PASSES` coordinate passes, each robot's at the others' of the pass
        before (as the offline estimator's passes: a robot's offset biases the others')."""
        cost = OffsetCost(self.rig, self.reference, records, self.options, self.pixel_sigma, self.confidence)
        trial = {o: self.offset(o) for o in self.robots}
        known = {o: bool(self.windows[o]) for o in self.robots}
        passes = TEAM_PASSES if len(self.robots) > 1 and not all(known.values()) else 1
        found: dict[str, tuple[float, float] | None] = {}
        for k in range(passes):
            for r in self.robots:
                if k > 0 and found[r] is None:
                    continue  # (undetermined in the first pass: not again)
                found[r] = yield from self._robot(cost, r, trial, search=k == 0 and not known[r])
                if found[r] is not None:
                    trial[r] = found[r][0]
        for r, got in found.items():
            if got is not None:
                self.windows[r].append(got)
                self.reasons[r] = ""
        self.evaluated += 1

    def _robot(self, cost: OffsetCost, r: str, base: dict[str, float],
               search: bool) -> Generator[None, None, tuple[float, float] | None]:
        """Robot ``r``'s offset in this window and its sigma, the others at ``base``; None (its reason
        set) when the window does not determine it.  ``search``: the coarse grid first."""
        values: dict[float, float] = {}
        motion: dict[float, tuple[float, float]] = {}

        def at(x: float):
            x = round(x, 9)
            if x not in values:
                values[x] = yield from cost.steps({**base, r: x})
                motion[x] = cost.motion.get(r, (0.0, 0.0))
            return values[x]

        h = self.step
        yield from at(base[r])  # first whether it moved in this window at all (one run, not a search)
        moved, turned = motion[round(base[r], 9)]
        if moved < self.min_motion[0] and turned < self.min_motion[1]:
            self.reasons[r] = (f"the robots barely move relative to each other ({moved * 100:.1f} cm, "
                               f"{turned:.1f} deg in the last window)")
            return None
        if not search:
            centre = base[r]
        else:
            xs = np.linspace(-self.search, self.search, self.grid)
            cs = []
            for x in xs:
                cs.append((yield from at(float(x))))
            k = int(np.argmin(cs))
            if k in (0, self.grid - 1):
                self.reasons[r] = f"the best offset lies at the search's edge (+-{self.search:g} s)"
                return None
            centre = float(xs[k])
        for _ in range(4):
            c0 = yield from at(centre)
            cm = yield from at(centre - h)
            cp = yield from at(centre + h)
            curv = (cp - 2.0 * c0 + cm) / h**2
            if not curv > 0:
                self.reasons[r] = "the observations do not depend on it (the robots barely move)"
                return None
            vertex = centre - h * (cp - cm) / (2.0 * (cp - 2.0 * c0 + cm))
            if abs(vertex - centre) <= h:
                break
            centre = float(np.clip(vertex, centre - 2 * h, centre + 2 * h))
            if abs(centre) > self.search:
                self.reasons[r] = f"the best offset lies beyond the search (+-{self.search:g} s)"
                return None
        sigma = SIGMA_SCALE * math.sqrt(2.0 / curv)
        if sigma > self.max_sigma:
            self.reasons[r] = (f"sigma {sigma * 1000:.0f} ms above {self.max_sigma * 1000:.0f} ms (the robots "
                               "barely move)")
            return None
        return float(vertex), sigma

    # -- the estimates --------------------------------------------------------

    def estimate(self, robot: str) -> ClockOffset:
        """``robot``'s offset (s, added to its stamps) and sigma; None with the reason while it cannot be
        determined yet; the reference's is 0."""
        if robot == self.reference:
            return ClockOffset(0.0, 0.0)
        got = self.windows.get(robot)
        if not got:
            return ClockOffset(None, None, self.reasons.get(robot, f"unknown robot {robot!r}"))
        x = np.array([o for o, _ in got])
        # each window's sigma is from its cost's curvature, which discrete events (an update the gate
        # rejects, a track restarted) make rough over a short window: the windows weigh alike, and the
        # sigma is the larger of theirs and their spread's (over sqrt(n))
        n = len(x)
        sigma = math.sqrt(float(np.mean([s**2 for _, s in got])) / n)
        if n > 1:
            sigma = max(sigma, float(np.std(x, ddof=1)) / math.sqrt(n))
        return ClockOffset(float(x.mean()), sigma)

    def estimates(self) -> dict[str, ClockOffset]:
        """Every robot's but the reference's (what ``clock_offsets.json`` holds)."""
        return {r: self.estimate(r) for r in self.robots}

    def offset(self, robot: str) -> float:
        """The correction added to ``robot``'s stamps now: its estimate, 0 while undetermined."""
        got = self.estimate(robot) if robot in self.windows else None
        return 0.0 if got is None or got.offset_s is None else got.offset_s

    def shifted(self, records: list[tuple[float, Any]]) -> list[tuple[float, Any]]:
        """``records`` (each observation on its observer's clock) with every robot's stamps corrected now."""
        return shift_records(self.rig, records, {r: self.offset(r) for r in self.robots})
