"""Hindsight in the team tracker (:class:`~mutloc.track.team_tracker.TeamTracker`):
a tentative track's records reported again once a later record confirms it
("confirmed in hindsight", verified by a filter run backward in time), and
records of three a confirmed track took unverified taken back when a
record solved on its own contradicts them (an
:class:`~mutloc.track.lifecycle.UndoRequest`, :meth:`Hindsight._roll_back`).
"""

from __future__ import annotations

import math
from collections import deque
from typing import Mapping

import numpy as np

from ..api import Estimate
from ..core.consistency import same_pose
from ..core.pose import Pose
from ..core.team import MIN_TIES, TeamProblem, team_residuals_any
from ..core.team_filter import TeamFilter
from ..errors import MutlocError
from ..team import team_problem
from . import lifecycle
from .lifecycle import PoseCov, Track, TrackState, UndoRequest, ties_to_one
from .filtering import lost_reason
from .solving import CONFIRM_SPREAD
from .status import FrameStatus
from .rows import TrackRow
from .records import Tentative, join


class Hindsight:
    """Hindsight of :class:`~mutloc.track.team_tracker.TeamTracker` (a mixin: its state is the tracker's)."""

    # -- taking back records of three that a record solved on its own contradicts

    def _save(self) -> tuple:
        """The tracker's state (the filter, the tracks, the rig check) as an undo restores it."""
        return (self.filter.copy(), {r: tr.copy() for r, tr in self.tracks.items()}, tuple(self._recent),
                self.last_time, self.rig_check.copy())

    def _undoable(self, undo: lifecycle.Undo) -> bool:
        """Whether the state before the undo's first record is still kept."""
        sm = self.smoother
        k = undo.first - (sm.first if sm is not None else 0)
        return sm is not None and 0 <= k < len(self._unfinal) and self._unfinal[k].saved is not None

    def _roll_back(self, u: UndoRequest) -> None:
        """Undo robot ``u.robot``'s track since its first unverified record of
        three (a record solved on its own contradicts it): those records
        report it ``rejected`` (with the track's prediction without them),
        every record since is filtered again; the current record then goes again."""
        sm = self.smoother
        undo = self.tracks[u.robot].undo
        assert sm is not None and undo is not None
        redo = self._unfinal[undo.first - sm.first:]
        filt, tracks, recent, last, rig_check = redo[0].saved
        self.filter, self.tracks, self._recent, self.last_time = filt, tracks, deque(recent), last
        self.rig_check = rig_check.copy()
        sm.truncate(undo.first)
        del self._unfinal[undo.first - sm.first:]
        self._confirmations = [c for c in self._confirmations if c[3] < undo.first]
        note = (f"not confirmed: the record at {u.t:.3f} s, solved on its own, contradicts the track this record of "
                "three observations made")
        self._replaying = True  # records filtered again make nothing to undo
        try:
            for i, rec in enumerate(redo):
                for row in rec.rows.values():
                    row.status, row.reason, row.estimate = FrameStatus.SOLVED, "", None
                if undo.first + i in undo.records:
                    self._filter_record(rec, exclude=u.robot)
                    row = rec.rows[u.robot]
                    row.status, row.reason = FrameStatus.REJECTED, note
                    row.estimate = self._estimate(u.robot, None, [], None, None, None) \
                        if u.robot in self.tracks else None
                else:
                    self._filter_record(rec)
        finally:
            self._replaying = False

    # -- a tentative track's records, reported again once it is confirmed ------

    def _report_tentative(self, end: bool) -> None:
        """Report the records of each confirmed tentative track within the
        lag before the confirming record as the confirmed track does, going
        back from it while every record that ties the robot by three or more
        is verified by the records after it (:meth:`_backward`).  The record
        that started the track is checked the same way: unless verified, the
        records verified on their own report the backward track's pose."""
        sm = self.smoother
        n = len(sm)
        ripe = [c for c in self._confirmations if end or c[3] < n - sm.lag]
        self._confirmations = [c for c in self._confirmations if c not in ripe]
        for t, frames, start, _, r in ripe:
            rooted = start is not None and self._backward(r, start) is not None
            for p in reversed(frames):
                back = None
                if p.status == FrameStatus.SOLVED and not (rooted and p is start):
                    back = self._backward(r, p)
                    if back is None:
                        break
                elif not rooted:
                    continue
                note = f"confirmed in hindsight by the record at t = {t:.3f} s and the records after it"
                p.row.status, p.row.estimate = p.status, p.estimate
                p.row.reason = join(note, p.reason)
                if back is not None and not rooted:
                    p.row.estimate = back

    def _backward(self, r: str, p: Tentative) -> Estimate | None:
        """Robot ``r``'s estimate at record ``p`` from a filter run backward
        in time over the ``lag`` records after it (independent of ``p`` and
        of the records before), updated with ``p``'s observations of ``r`` --
        if it predicted every one of them within ``CONFIRM_SPREAD`` pixel
        sigmas and agrees with all of them, and predicts the pose the forward
        track predicted within their joint uncertainty; else None.  It starts
        from the last of those records whose joint solve places ``r``."""
        sm = self.smoother
        later = self._unfinal[p.k + 1 - sm.first:p.k + 1 + sm.lag - sm.first]
        f = TeamFilter(self.filter.robots, self.reference, self.options.noise, self.pixel_sigma, self.confidence,
                       measure_noise=self.options.measure_noise)
        started = False
        for rec in reversed(later):
            if rec.obs is None or len(rec.obs) == 0:
                continue
            try:
                problem, _, _ = team_problem(self.rig, rec.obs)
            except MutlocError:
                continue
            if not started:
                if ties_to_one(problem, f.index(r)) < MIN_TIES:
                    continue
                team, _, _ = self._solve(rec.obs, self.reference)
                if team is None or r not in team.poses:
                    continue
                f.reset(-rec.t, {x: team.poses[x] for x in team.robots}, team.joint_covariance)
                started = True
                continue
            f.predict(-rec.t)
            if lost_reason(PoseCov(f.covariance(r)), self.options):
                return None
            rows = self._rows_among(problem, f)
            if len(rows):
                f.update(problem.take(rows))
        if not started or p.row.observations is None:
            return None
        try:
            problem, names, markers = team_problem(self.rig, p.row.observations)
        except MutlocError:
            return None
        f.predict(-p.row.t)
        i = f.index(r)
        mine = np.flatnonzero((problem.cam == i) | (problem.own == i))
        rows = self._rows_among(problem, f)
        if len(mine) == 0 or not np.isin(mine, rows).all():
            return None
        if max(self._spread_px(problem, j, f) for j in mine.tolist()) > CONFIRM_SPREAD * self.pixel_sigma:
            return None
        if not same_pose(f.pose(r), f.covariance(r), p.prior[0], p.prior[1], self.confidence):
            return None
        upd = f.update(problem.take(mine))
        if not (upd.accepted and len(upd.used) == len(mine)):
            return None
        pose, cov = f.pose(r), f.covariance(r)
        rms = float(np.sqrt(np.mean(upd.residuals_px ** 2))) if len(upd.residuals_px) else 0.0
        return Estimate(source=r, target=self.reference, pose=pose, covariance=cov, pixel_sigma=self.pixel_sigma,
                        reprojection_rms_px=rms, markers_used=sorted({markers[j] for j in mine.tolist()}),
                        candidates=Pose.concatenate([pose]), consistency=upd.test,
                        extra={"velocity": (-f.velocity(r)).tolist(), "filter": "cv", "smooth_lag": sm.lag,
                               "smoother": "backward"})

    def _rows_among(self, problem: TeamProblem, f: TeamFilter) -> np.ndarray:
        """The observations between robots ``f`` tracks (or its reference)."""
        ok = np.zeros(problem.n_robots, dtype=bool)
        ok[f.tracked] = True
        ok[f.index(self.reference)] = True
        return np.flatnonzero(ok[problem.cam] & ok[problem.own])

    def _tentative(self, r: str, tr: Track, row: TrackRow, status: FrameStatus, reason: str,
                   prior: tuple | None, n: int) -> None:
        """A record of a tentative track (not yet confirmed) reports what the
        record shows on its own: ``unverified`` with three or more
        observations of the robot; with fewer, a track bridged over records
        reports ``partial`` (``predicted``), one started on three nothing
        (``too_few``).  What a confirmed track would have reported is kept:
        once confirmed, the records within the lag may report it (see
        :meth:`_report_tentative`)."""
        f = self.filter
        if self.smoother is not None:
            tr.frames.append(Tentative(self._k, row, status, row.estimate, reason,
                                        prior if prior is not None else (f.pose(r), f.covariance(r))))
        bridged = tr.state == TrackState.BRIDGED
        note = "tentative track not yet confirmed " + ("(started from records solved together)" if bridged
                                                        else "(started on three observations)")
        if n >= MIN_TIES:
            row.status = FrameStatus.UNVERIFIED
        elif tr.state == TrackState.BRIDGED:
            row.status = status
        else:
            row.status, row.estimate = FrameStatus.TOO_FEW, None
        row.reason = join(row.reason if n else join(row.reason, reason), note)

    def _confirmed(self, t: float, r: str, tr: Track) -> None:
        """Robot ``r``'s tentative track is confirmed now: its records within
        the lag may be reported again once the lag records after this one came."""
        if self.smoother is None:
            return
        near = [p for p in tr.frames if self._k - p.k <= self.options.smooth_lag and p.estimate is not None]
        start = next((p for p in tr.frames if p.start), None)
        if near:
            self._confirmations.append((t, near, start, self._k, r))
        tr.frames = []

    def _confirms(self, tr: Track, problem: TeamProblem, names: list[str], markers: list[str], rows: np.ndarray,
                  spread: Mapping[int, float], dropped: bool) -> tuple[bool, str]:
        """Whether a later record's accepted observations (``rows``) of a
        tentative track confirm it (:func:`~mutloc.track.lifecycle.confirms`), and the row's note."""
        n = int(rows.sum())
        idx = np.flatnonzero(rows).tolist()
        new = [j for j in idx if (names[problem.cam[j]], markers[j]) not in tr.start] if tr.strict else []
        ok, worst = lifecycle.confirms(tr, n, new, spread, dropped, self.pixel_sigma)
        if not tr.strict:
            return ok, f"track confirmed by {n} observations"
        if not ok:
            return False, ""
        seen = ", ".join(sorted({markers[j] for j in idx}))
        start = ", ".join(sorted({m for _, m in tr.start}))
        return True, (f"track confirmed: {seen} agree with the track started on {start} "
                      f"(new observations predicted within {worst:.1f} px)")

    def _spread_px(self, problem: TeamProblem, j: int, f: TeamFilter | None = None) -> float:
        """1-sigma (px, largest axis) of where the filter predicts observation
        ``j`` (its observer's and the marker owner's pose covariance, with
        their correlation, through the projection's Jacobians; ``f``: another filter)."""
        f = self.filter if f is None else f
        one = problem.take(np.array([j]))
        res = np.empty(2)
        Ja, Jb = np.empty((1, 2, 6)), np.empty((1, 2, 6))
        if not team_residuals_any(one.cam, one.own, one.points, one.uv, one.wt, one.K, one.dist, one.fr, f.R, f.t, res,
                                  Ja, Jb, True):
            return math.inf
        terms = [(f.robots[int(one.cam[0])], Ja[0]), (f.robots[int(one.own[0])], Jb[0])]
        if any(name != self.reference and not f.is_tracked(name) for name, _ in terms):
            return math.inf
        S = f.pose_sandwich(terms)
        return float(math.sqrt(max(np.linalg.eigvalsh(S).max(), 0.0)))
