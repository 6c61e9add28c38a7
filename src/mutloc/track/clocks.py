"""Each robot's clock offset to the reference's, estimated from a log
(SPEC "The robots' own motion and clocks": ``--clock-offsets estimate``).

An observation is stamped by its observer's clock; the offset of a robot
is what is *added* to its stamps to put them on the reference's clock.
:func:`shift_records` moves every observation a robot made by its offset
(a record's observations split by observer, regrouped by time).

:func:`estimate_clock_offsets` estimates them by profile likelihood: the
team tracker (:class:`~mutloc.track.team_tracker.TeamTracker`, the causal
filter, no smoother) re-run over the records with one robot's stamps
shifted by a candidate offset; the cost is the sum over the filter's
updates of the innovation's -2 log-likelihood up to a constant -- its
Mahalanobis distance plus ``log det S`` (the shift moves the predictions'
time steps, so ``S`` depends on it; by the determinant lemma ``log det S
= log det P_prior - log det P_post + 2m log sigma^2``, the joint state's
covariances before and after the update).  An update the gate rejects
counts its gate's threshold, an observation it drops the 2-dof one: a
wrong offset cannot win by losing observations.  Minimised by a coarse
grid over ``+-search`` s, then golden section in the best cell; with
several robots, coordinate passes.  The sigma is from the cost's
curvature at the minimum (``sigma^2 = 2 / cost''``, by central
differences).  A robot whose track moves less than ``min_motion``
relative to the reference (its noise alone fits some offset), whose curvature is not positive, whose minimum
lies at the search's edge, or whose sigma exceeds ``max_sigma`` (robots
that barely move relative to each other) cannot be determined yet: its
offset is None with the reason.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, Iterable, Mapping

import numpy as np

from ..core.consistency import DEFAULT_CONFIDENCE, chi2_quantile
from ..core.observations import ObservationSet
from ..core.rig import Rig
from ..errors import InputError, MutlocError
from .filtering import FilterOptions
from .team_tracker import TeamTracker

__all__ = ["ClockOffset", "OffsetCost", "shift_records", "estimate_clock_offsets", "clock_offsets_json", "write_clock_offsets",
           "DEFAULT_SEARCH",
           "DEFAULT_MAX_SIGMA",
           "DEFAULT_MIN_MOTION"]

#: Offsets searched (s, either way).
DEFAULT_SEARCH = 0.2
#: A sigma beyond this (s): the offset cannot be determined (yet).
DEFAULT_MAX_SIGMA = 0.02
#: A robot that moves less than this relative to the reference (metres, degrees) over the log: its offset
#: cannot be determined (a track's noise alone fits some offset).
DEFAULT_MIN_MOTION = (0.05, 5.0)
_GOLDEN = (math.sqrt(5.0) - 1.0) / 2.0


@dataclass(frozen=True)
class ClockOffset:
    """A robot's estimated clock offset (s, added to its stamps) and its 1-sigma; None with ``reason`` when it
    cannot be determined yet."""

    offset_s: float | None
    sigma_s: float | None
    reason: str = ""

    def to_dict(self) -> dict[str, Any]:
        out: dict[str, Any] = {"offset_s": self.offset_s, "sigma_s": self.sigma_s}
        if self.offset_s is None:
            out["reason"] = self.reason
        return out

    def text(self, robot: str) -> str:
        if self.offset_s is None:
            return f"clock offset of {robot}: cannot be determined yet ({self.reason})"
        return (f"clock offset of {robot}: {self.offset_s * 1000:+.1f} ms +- {self.sigma_s * 1000:.1f} ms "
                f"(added to its stamps)")


def clock_offsets_json(offsets: Mapping[str, ClockOffset]) -> dict[str, dict[str, Any]]:
    """``DIR/clock_offsets.json``'s content: ``{robot: {"offset_s": ..., "sigma_s": ...}}`` (null and a
    ``reason`` for a robot not determined)."""
    return {r: c.to_dict() for r, c in offsets.items()}


def write_clock_offsets(out: str | Path, offsets: Mapping[str, ClockOffset]) -> Path:
    """``OUT/clock_offsets.json`` (:func:`clock_offsets_json`), the folder made if need be; returns its path."""
    path = Path(out) / "clock_offsets.json"
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(clock_offsets_json(offsets), indent=1) + "\n", encoding="utf-8")
    return path


def _robot_of(rig: Rig, key: str) -> str:
    try:
        return rig.observer(key)[0]
    except MutlocError:
        return key


def shift_records(rig: Rig, records: Iterable[tuple[float, ObservationSet | None]],
                  offsets: Mapping[str, float]) -> list[tuple[float, ObservationSet | None]]:
    """The records with each robot's observations (those it made: its stamps) at ``t + offsets[robot]``:
    a record's observations split by observer robot, every piece at its time, pieces at one time one record,
    in time order (records without observations stay at their time).  All offsets 0: the records as given."""
    pieces: list[tuple[float, int, ObservationSet | None]] = []
    for k, (t, obs) in enumerate(records):
        t = float(t)
        if obs is None or len(obs) == 0:
            pieces.append((t, k, obs))
            continue
        robots = np.array([_robot_of(rig, o) for o in obs.observer])
        for r in dict.fromkeys(robots.tolist()):
            off = float(offsets.get(r, 0.0))
            part = obs.take(np.flatnonzero(robots == r))
            pieces.append((t + off, k, part.with_time(t + off) if off else part))
    pieces.sort(key=lambda p: (p[0], p[1]))
    out: list[tuple[float, ObservationSet | None]] = []
    group: list[ObservationSet] = []
    for i, (t, _, obs) in enumerate(pieces):
        if obs is None or len(obs) == 0:
            out.append((t, obs))
            continue
        group.append(obs)
        if i + 1 == len(pieces) or pieces[i + 1][0] != t or pieces[i + 1][2] is None or not len(pieces[i + 1][2]):
            out.append((t, group[0] if len(group) == 1 else ObservationSet.concatenate(group)))
            group = []
    return out


class OffsetCost:
    """The -2 log-likelihood of the records under given offsets (see the module docstring)."""

    def __init__(self, rig: Rig, reference: str, records: list, options: FilterOptions, pixel_sigma: float,
                 confidence: float) -> None:
        self.rig, self.reference, self.records = rig, reference, records
        self.options = replace(options, kind="cv", smooth_lag=0, measure_noise=False)
        self.pixel_sigma, self.confidence = pixel_sigma, confidence
        self.drop_cost = chi2_quantile(confidence, 2) if confidence < 1.0 else 25.0
        self.calls = 0
        self.motion: dict[str, tuple[float, float]] = {}  #: the last run's (see _motion)

    def __call__(self, offsets: Mapping[str, float]) -> float:
        steps = self.steps(offsets)
        while True:
            try:
                next(steps)
            except StopIteration as done:
                return done.value

    def steps(self, offsets: Mapping[str, float]):
        """The cost as a generator: yields after each record (so that a caller can do it in slices), returns
        the cost (``total = yield from cost.steps(offsets)``)."""
        self.calls += 1
        tracker = TeamTracker(self.rig, self.reference, pixel_sigma=self.pixel_sigma, confidence=self.confidence,
                              options=replace(self.options, clock_offsets=dict(offsets)))
        f = tracker.filter
        update = f.update
        total = [0.0]
        log_s2 = 2.0 * math.log(self.pixel_sigma)

        def counted(problem):
            before = f.P.copy()
            upd = update(problem)
            if upd.accepted:
                cost = upd.test.chi2 + self.drop_cost * len(upd.dropped)
                if f.P.shape == before.shape and before.size:
                    s0, ld0 = np.linalg.slogdet(before)
                    s1, ld1 = np.linalg.slogdet(f.P)
                    if s0 > 0 and s1 > 0:
                        cost += ld0 - ld1 + upd.test.dof * log_s2
                total[0] += cost
            else:
                dof = max(upd.test.dof, 2)
                total[0] += chi2_quantile(self.confidence, dof) if self.confidence < 1.0 else self.drop_cost * dof / 2
            return upd

        f.update = counted  # this run's filter only
        poses: dict[str, list] = {}
        for t, obs in shift_records(self.rig, self.records, offsets):
            tracker.step(t, obs)
            for r in tracker.tracks:
                if f.is_tracked(r):
                    poses.setdefault(r, []).append(f.pose(r))
            yield
        self.motion = {r: _motion(p) for r, p in poses.items()}
        return total[0]


def _motion(poses: list) -> tuple[float, float]:
    """How far a robot moved relative to the reference over its track: the 90th percentile of its poses'
    distance (m) and angle (degrees) from their middle one (the track's start, still settling, left out)."""
    mid = poses[len(poses) // 2]
    dist = [float(np.linalg.norm(p.t - mid.t)) for p in poses]
    ang = [math.degrees(math.acos(float(np.clip((np.trace(mid.R.T @ p.R) - 1.0) / 2.0, -1.0, 1.0)))) for p in poses]
    return float(np.percentile(dist, 90)), float(np.percentile(ang, 90))


def _golden(fn, a: float, b: float, tol: float) -> tuple[float, float]:
    c, d = b - _GOLDEN * (b - a), a + _GOLDEN * (b - a)
    fc, fd = fn(c), fn(d)
    while b - a > tol:
        if fc < fd:
            b, d, fd = d, c, fc
            c = b - _GOLDEN * (b - a)
            fc = fn(c)
        else:
            a, c, fc = c, d, fd
            d = a + _GOLDEN * (b - a)
            fd = fn(d)
    return (c, fc) if fc < fd else (d, fd)


def estimate_clock_offsets(rig: Rig, records: Iterable[tuple[float, ObservationSet | None]], reference: str, *,
                           options: FilterOptions | None = None, pixel_sigma: float = 1.0,
                           confidence: float = DEFAULT_CONFIDENCE, search: float = DEFAULT_SEARCH,
                           grid: int = 9, tol: float = 0.001, step: float = 0.01,
                           max_sigma: float = DEFAULT_MAX_SIGMA, min_motion: tuple[float, float] = DEFAULT_MIN_MOTION,
                           passes: int | None = None) -> dict[str, ClockOffset]:
    """Each robot's (not the reference's) clock offset from ``records`` (``(time, ObservationSet)``, each
    observation on its observer's clock; see the module docstring).  ``rig``: the expanded rig the tracker
    takes; ``search``: offsets within +-search s; ``grid``: the coarse grid's points; ``tol``: the golden
    section's final bracket (s); ``step``: the central differences' step (s); ``passes``: coordinate passes
    (default 1 for two robots, 2 for more); ``min_motion``: (metres, degrees) a robot's track must move
    relative to the reference (either), else its offset cannot be determined.  Raises InputError for bad parameters."""
    if reference not in rig.robots:
        raise InputError(f"unknown reference robot {reference!r} (rig has {sorted(rig.robots)})")
    if not (search > 0 and math.isfinite(search)) or grid < 3 or not (0 < tol < search) or not (0 < step < search):
        raise InputError("clock offsets: search, grid (>= 3), tol and step must be positive and tol, step < search")
    records = list(records)
    robots = [r for r in rig.robots if r != reference]
    cost = OffsetCost(rig, reference, records, options or FilterOptions(), pixel_sigma, confidence)
    offsets = {r: 0.0 for r in robots}
    edge: dict[str, bool] = {}
    for _ in range(passes or (1 if len(robots) == 1 else 2)):
        for r in robots:
            def fn(x: float, r: str = r) -> float:
                return cost({**offsets, r: x})
            xs = np.linspace(-search, search, grid)
            cs = [fn(float(x)) for x in xs]
            k = int(np.argmin(cs))
            edge[r] = k in (0, grid - 1)
            lo, hi = float(xs[max(k - 1, 0)]), float(xs[min(k + 1, grid - 1)])
            offsets[r], _ = _golden(fn, lo, hi, tol)
    out: dict[str, ClockOffset] = {}
    for r in robots:
        x = offsets[r]
        cp, cm = cost({**offsets, r: x + step}), cost({**offsets, r: x - step})
        c0 = cost(offsets)
        curv = (cp - 2.0 * c0 + cm) / step**2
        moved, turned = cost.motion.get(r, (0.0, 0.0))
        if moved < min_motion[0] and turned < min_motion[1]:
            out[r] = ClockOffset(None, None, f"the robots barely move relative to each other ({moved * 100:.1f} cm, "
                                              f"{turned:.1f} deg)")
        elif edge[r] and (x <= -search + step or x >= search - step):
            out[r] = ClockOffset(None, None, f"the best offset lies at the search's edge (+-{search:g} s)")
        elif not curv > 0:
            out[r] = ClockOffset(None, None, "the observations do not depend on it (the robots barely move)")
        elif math.sqrt(2.0 / curv) > max_sigma:
            out[r] = ClockOffset(None, None, f"sigma {math.sqrt(2.0 / curv) * 1000:.0f} ms above "
                                              f"{max_sigma * 1000:.0f} ms (the robots barely move)")
        else:
            out[r] = ClockOffset(float(x), math.sqrt(2.0 / curv))
    return out
