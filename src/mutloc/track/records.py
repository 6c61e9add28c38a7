"""A record in the team tracker and the rows it makes
(:class:`~mutloc.track.team_tracker.TeamTracker`): the record kept until
final, each robot's row built from what the record did to its track (or,
without the filter, from the record's joint estimate alone).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Mapping

import numpy as np

from ..api import Estimate, rejected_text
from ..core.observations import ObservationSet
from ..core.pose import Pose
from ..core.team import MIN_TIES, TeamProblem, residual_norms
from ..core.team_filter import TeamFilter
from ..errors import MutlocError
from ..team import TeamEstimate
from . import lifecycle
from .status import FrameStatus
from .rows import TrackRow


@dataclass
class Record:
    """One input record and its rows, kept until final (a confirmation may
    report them again, :meth:`TeamTracker._report_tentative`)."""

    t: float
    obs: ObservationSet | None
    times: Mapping[str, float | None] | None
    problems: Mapping[str, tuple[FrameStatus, str]] | None
    rows: dict[str, TrackRow]
    #: The tracker's state before it, where an undo may go back to it (see ``_save``).
    saved: tuple | None = None


@dataclass
class Tentative:
    """A record of a tentative track as a confirmed track would report it:
    its number and row, status, estimate and reason, and the robot's pose
    and covariance the filter predicted before it (``start``: it started the track)."""

    k: int
    row: TrackRow
    status: FrameStatus
    estimate: Estimate | None
    reason: str
    prior: tuple
    start: bool = False


def robot_estimate(team: TeamEstimate, r: str, pose: Pose, cov: np.ndarray, extra: dict | None = None) -> Estimate:
    markers = sorted({m for pair, ms in team.markers_between.items() if r in pair for m in ms})
    return Estimate(source=r, target=team.reference, pose=pose, covariance=np.array(cov, float),
                    pixel_sigma=team.pixel_sigma, reprojection_rms_px=team.reprojection_rms_px, markers_used=markers,
                    candidates=Pose.concatenate([pose]), consistency=team.consistency, extra=dict(extra or {}))


def reprojection(problem: TeamProblem, f: TeamFilter) -> np.ndarray:
    """Each observation's reprojection error (px) at the filter's poses."""
    return residual_norms(problem, f.R, f.t)


def dropped_note(team: TeamEstimate) -> str:
    if not team.rejected:
        return ""
    return "joint estimate dropped " + rejected_text(team.rejected)


def join(a: str, b: str) -> str:
    return f"{a}; {b}" if a and b else (a or b)


class Rows:
    """The rows of :class:`~mutloc.track.team_tracker.TeamTracker` (a mixin: its state is the tracker's)."""

    @staticmethod
    def _input_problems(rec: Record) -> None:
        for r, row in rec.rows.items():
            if rec.problems and r in rec.problems:
                status, note = rec.problems[r]
                if row.estimate is None:
                    row.status = status
                    row.reason = join(note, row.reason)
                else:
                    row.reason = join(row.reason, f"{note} (localized from the others' views)")

    def _per_record(self, obs: ObservationSet | None, rows: dict[str, TrackRow]) -> None:
        if obs is None:
            for row in rows.values():
                row.status, row.reason = FrameStatus.UNPAIRED, "no frame"
            return
        team, status, reason = self._solve(obs, self.reference)
        self._own_solve = self._solve_test  # the record fitted on its own: the rig check's (see TeamTracker)
        for r, row in rows.items():
            if team is not None and r in team.poses:
                row.estimate = robot_estimate(team, r, team.poses[r], team.covariance(r))
                row.status = FrameStatus.UNVERIFIED if r in team.unverified else FrameStatus.SOLVED
                row.reason = dropped_note(team)
            else:
                row.status, row.reason = self._not_localized(r, team, status, reason, obs)

    def _not_localized(self, r: str, team: TeamEstimate | None, status: FrameStatus, reason: str,
                       obs: ObservationSet | None) -> tuple[FrameStatus, str]:
        """Status and reason of a robot without a joint pose this record."""
        n = 0
        if obs is not None:
            owner, observer = self.rig.owner, self.rig.observer
            try:
                n = sum(1 for o, m in zip(obs.observer, obs.marker)
                        if m is not None and (observer(o)[0] == r or owner(m) == r))
            except MutlocError:
                n = -1
        if n == 0:
            return FrameStatus.TOO_FEW, "no markers seen"
        if team is None:
            return (FrameStatus.FAILED if status == FrameStatus.SOLVED else status), reason
        if n < MIN_TIES:
            return FrameStatus.TOO_FEW, (f"{n} observation{'s' if n != 1 else ''} involve it: too few to tie it to "
                                         f"{self.reference!r} (three are needed)")
        return FrameStatus.TOO_FEW, f"its {n} observations do not tie it to {self.reference!r}"

    def _fill_rows(self, t: float, rows: dict[str, TrackRow], problem: TeamProblem, names: list[str],
                   markers: list[str], touch: Mapping[str, np.ndarray], used: np.ndarray,
                   notes: dict[str, list[str]], started: Mapping[str, str], rejected: set[str], why_rejected: str,
                   confirmed: Mapping[str, str], failed: Mapping[str, tuple[FrameStatus, str]], test: Any,
                   prior: Mapping[str, tuple]) -> None:
        """Every robot's row of a filtered record: its status, reason and
        estimate from what the record did to its track (``used``: the
        observations the filter took; ``notes``: per robot, for its reason)."""
        f = self.filter
        held = self._held(problem, used)
        res = reprojection(problem.take(np.flatnonzero(used)), self.filter) if used.any() else None
        if res is not None:
            full = np.zeros(len(used))
            full[used] = res
            res = full
        cams = {names[c] for c in problem.cam[used].tolist()}
        for r in held & set(self.tracks):
            tr = self.tracks[r]
            lifecycle.held_by_others(tr, cams)
        for r, row in rows.items():
            if notes[r]:
                row.reason = join(row.reason, "; ".join(notes[r]))
            mine = touch[r]
            if r in started:
                tr = self.tracks[r]
                row.status = (FrameStatus.SOLVED if not tr.strict else
                              FrameStatus.UNVERIFIED if int((used & mine).sum()) >= MIN_TIES else FrameStatus.PARTIAL)
                row.reason = join(row.reason, started[r])
                row.estimate = self._estimate(r, problem, markers, used, mine, test, res)
                if tr.strict and self.smoother is not None:
                    n = int((used & mine).sum())
                    on = ", ".join(sorted({markers[j] for j in np.flatnonzero(used & mine).tolist()}))
                    tr.frames.append(Tentative(self._k, row, FrameStatus.SOLVED if n >= MIN_TIES else
                                                FrameStatus.PARTIAL, row.estimate, f"started the track on {on}",
                                                (f.pose(r), f.covariance(r)), start=True))
            elif r in self.tracks and r in rejected:
                row.status = FrameStatus.REJECTED
                row.reason = join(row.reason, why_rejected)
                row.estimate = self._estimate(r, problem, markers, np.zeros_like(used), mine, None)
            elif r in self.tracks and (used & mine).any():
                n = int((used & mine).sum())
                tr = self.tracks[r]
                if r in confirmed:
                    row.reason = join(row.reason, confirmed[r])
                    self._confirmed(t, r, tr)
                if r in held:
                    status, why = FrameStatus.SOLVED, ""
                else:
                    status, why = FrameStatus.PARTIAL, f"{n} observation(s) tie it to the team: updated through the filter"
                row.estimate = self._estimate(r, problem, markers, used, mine, test, res)
                if tr.strict:
                    # a tentative track reports nothing of its own yet (see _tentative)
                    self._tentative(r, tr, row, status, join(row.reason, why), prior.get(r), n)
                else:
                    row.status, row.reason = status, join(row.reason, why)
            elif r in self.tracks:
                self._unobserved(r, row, "no markers seen" if not mine.any() else "observations not used")
            elif r in rejected:  # (its track dropped)
                row.status = FrameStatus.REJECTED
                row.reason = join(row.reason, why_rejected)
            elif r in failed:
                row.status, why = failed[r]
                row.reason = join(row.reason, why)
            else:
                n = int(mine.sum())
                row.status = FrameStatus.TOO_FEW
                row.reason = join(row.reason, "no markers seen" if n == 0 else
                                   f"{n} observation{'s' if n != 1 else ''} involve it: too few to start its track "
                                   "(three are needed)")

    def _held(self, problem: TeamProblem, used: np.ndarray) -> set[str]:
        """Robots the record's used observations tie to the reference on
        their own: a chain of robots each pair tied by three or more."""
        n = problem.n_robots
        C = np.zeros((n, n), dtype=np.int64)
        np.add.at(C, (problem.cam[used], problem.own[used]), 1)
        C = C + C.T
        ref = self.filter.index(self.reference)
        seen, todo = {ref}, [ref]
        while todo:
            a = todo.pop()
            for b in np.flatnonzero(C[a] >= MIN_TIES).tolist():
                if b not in seen:
                    seen.add(b)
                    todo.append(b)
        return {self.filter.robots[i] for i in seen} - {self.reference}

    def _unobserved(self, r: str, row: TrackRow, why: str) -> None:
        """A row without observations of ``r``: the prediction of a robot tracked, else nothing."""
        tr = self.tracks.get(r)
        if tr is None:
            row.status = FrameStatus.TOO_FEW
            row.reason = join(row.reason, why)
            return
        tr.supported = False
        row.estimate = self._estimate(r, None, [], None, None, None)
        if tr.strict:
            self._tentative(r, tr, row, FrameStatus.PREDICTED, why, None, 0)
            return
        row.status = FrameStatus.PREDICTED
        row.reason = join(row.reason, why)

    def _estimate(self, r: str, problem: TeamProblem | None, markers: list[str], used: np.ndarray | None,
                  mine: np.ndarray | None, test: Any, res: np.ndarray | None = None) -> Estimate:
        """Robot ``r``'s row estimate now (``res``: every observation's
        reprojection error at the filter's poses, when already computed)."""
        f = self.filter
        pose, vel = f.pose(r), f.velocity(r)
        names, rms = [], 0.0
        if problem is not None and used is not None and mine is not None and (used & mine).any():
            rows = np.flatnonzero(used & mine)
            names = sorted({markers[j] for j in rows.tolist()})
            err = res[rows] if res is not None else reprojection(problem.take(rows), f)
            rms = float(np.sqrt(np.mean(err ** 2)))
        return Estimate(source=r, target=self.reference, pose=pose, covariance=f.covariance(r),
                        pixel_sigma=self.pixel_sigma, reprojection_rms_px=rms, markers_used=names,
                        candidates=Pose.concatenate([pose]), consistency=test,
                        extra={"velocity": vel.tolist(), "filter": "cv"})
